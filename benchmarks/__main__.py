"""``python -m benchmarks [--quick]``: the same suite as ``curvslice bench``."""

import argparse
import sys

from benchmarks.run import add_arguments, execute
from curvslice.errors import CurvsliceError

parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
add_arguments(parser)
try:
    sys.exit(execute(parser.parse_args()))
except CurvsliceError as exc:
    print(f"benchmarks: error: {exc}", file=sys.stderr)
    sys.exit(2)
