"""Command-line entry point: argument parsing and composition of the stages, nothing else.

Each sub-command lives in its own module of this package exposing ``add_parser(subparsers)``
and ``run(args) -> int``. A bad option or a :class:`~curvslice.errors.CurvsliceError` (bad input,
bad settings) is printed as one line on stderr with exit code 2, and so is a missing third-party
package (with the ``pip install`` that fixes it); Ctrl-C, SIGTERM and SIGHUP interrupt the command
(its partial outputs are removed) and exit with 128 + the signal number.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from curvslice import __version__
from curvslice.errors import CurvsliceError, missing_package

#: Sub-command modules of ``curvslice.cli``, in the order ``--help`` lists them.
COMMANDS = ("slice", "verify", "convert", "level", "drape", "view", "bench", "sweep", "decompose", "workcell")


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (the option, the value, what was expected)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class Interrupted(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised like Ctrl-C so every cleanup on the way out runs."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _raise_interrupted(signum: int, frame) -> None:
    raise Interrupted(signum)


@contextmanager
def _signals_interrupt() -> Iterator[None]:
    if threading.current_thread() is not threading.main_thread():  # only the main thread may set handlers
        yield
        return
    old = {s: signal.signal(s, _raise_interrupted) for s in (signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The argument parser; with ``only``, just that sub-command's module is imported (the
    command modules pull in heavy libraries: pinocchio, meshcat, ezdxf…)."""
    parser = _Parser(
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


def _joined_negative_axes(argv: list[str]) -> list[str]:
    """``--up -y`` as ``--up=-y``: argparse reads a value starting with a dash as the next option (and failed
    with "expected one argument"), so a part's negative axis could only be given in the ``=`` form."""
    out: list[str] = []
    for a in argv:
        if out and out[-1] == "--up" and a in ("-x", "-y", "-z"):
            out[-1] = f"--up={a}"
        else:
            out.append(a)
    return out


def main(argv: list[str] | None = None) -> int:
    argv = _joined_negative_axes(sys.argv[1:] if argv is None else list(argv))
    first = next((a for a in argv if not a.startswith("-")), None)
    try:
        parser = build_parser(first if first in COMMANDS else None)
    except ImportError as exc:  # a command module's third-party import
        print(f"curvslice: error: {missing_package(exc)}", file=sys.stderr)
        return 2
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # a bad option (one line already printed) or --help: the exit code, not a raise
        return int(exc.code or 0)
    try:
        with _signals_interrupt():
            return int(args.run(args) or 0)
    except ImportError as exc:
        if (exc.name or "").split(".")[0] == "curvslice":
            raise  # our own packaging bug: keep the traceback
        print(f"curvslice {args.command}: error: {missing_package(exc)}", file=sys.stderr)
        return 2
    except CurvsliceError as exc:
        print(f"curvslice {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
        print(f"curvslice {args.command}: interrupted ({signal.Signals(signum).name})", file=sys.stderr)
        return 128 + signum


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
