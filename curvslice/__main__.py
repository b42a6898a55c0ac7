import sys

from curvslice.cli import main

sys.exit(main())
