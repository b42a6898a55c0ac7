"""Command-line entry point: argument parsing and composition of the stages, nothing else.

Each sub-command lives in its own module of this package exposing ``add_parser(subparsers)``
and ``run(args) -> int``. A :class:`~curvslice.errors.CurvsliceError` (bad input, bad settings)
is printed as one line on stderr with exit code 2, and so is a missing third-party package (with the
``pip install`` that fixes it); Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from curvslice import __version__
from curvslice.errors import CurvsliceError, missing_package

#: Sub-command modules of ``curvslice.cli``, in the order ``--help`` lists them.
COMMANDS = ("slice", "verify", "convert", "level", "drape", "view", "bench", "sweep")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The argument parser; with ``only``, just that sub-command's module is imported (the
    command modules pull in heavy libraries: pinocchio, meshcat, ezdxf…)."""
    parser = argparse.ArgumentParser(
        prog="curvslice",
        description="Support-free multi-axis 3D printing with robot arms (curved layers, "
        "Fermat-spiral tool-paths, pose-continuous robot programs).",
    )
    parser.add_argument("--version", action="version", version=f"curvslice {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS if only is None else (only,):
        module = importlib.import_module(f"curvslice.cli.{name.replace('-', '_')}")
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    first = next((a for a in argv if not a.startswith("-")), None)
    try:
        parser = build_parser(first if first in COMMANDS else None)
    except ImportError as exc:  # a command module's third-party import
        print(f"curvslice: error: {missing_package(exc)}", file=sys.stderr)
        return 2
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except ImportError as exc:
        if (exc.name or "").split(".")[0] == "curvslice":
            raise  # our own packaging bug: keep the traceback
        print(f"curvslice {args.command}: error: {missing_package(exc)}", file=sys.stderr)
        return 2
    except CurvsliceError as exc:
        print(f"curvslice {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"curvslice {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
