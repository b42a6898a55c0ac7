#!/bin/bash
while pgrep -f "runset.sh /work/data/cover5/code_base /work/data/cover5/base fertility" >/dev/null; do sleep 10; done
./runset.sh /work/data/cover5/code_base /work/data/cover5/base kitten_2 kitten_0.8 homer_0.8 kitten_1 kitten_1.6 fandisk_0.8 bunny_1
