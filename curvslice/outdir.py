"""Atomic outputs: a slice folder, or the file set of a command, appears whole or not at all.

Everything is written into a hidden temporary (``.NAME.partial-PID`` beside a folder, or
``OUT/.curvslice.partial-PID`` for a file set) that is moved into place only when the command
succeeded; on an error, Ctrl-C, SIGTERM or SIGHUP (the CLI turns both into an interrupt) it is
removed. A lock file held for the whole run makes a second run on the same output fail at once
instead of silently replacing the first. An existing folder is replaced only with ``force`` and
only if it is a curvslice output (has ``report.json``); no output may replace an input.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import signal
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from curvslice.errors import CurvsliceError

_SIGNALS = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}


@contextmanager
def output_lock(lock: Path, what: Path) -> Iterator[None]:
    """Hold an exclusive lock file ``lock`` for the block (removed afterwards); a lock held by another
    run is an error naming ``what``."""
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            held = os.stat(lock).st_ino == os.fstat(fd).st_ino  # not a file the previous holder just removed
        except (BlockingIOError, FileNotFoundError):
            held = False
        if not held:
            raise CurvsliceError(f"another curvslice run is writing {what}; wait for it or choose another --out")
        try:
            yield
        finally:
            lock.unlink(missing_ok=True)
    finally:
        os.close(fd)


@contextmanager
def _signals_blocked() -> Iterator[None]:
    """Defer SIGINT / SIGTERM / SIGHUP while a set of renames runs, so it is not cut in half."""
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _refuse_inputs(outputs: Iterable[Path], protect: Iterable[Path]) -> None:
    inputs = {Path(p).resolve() for p in protect}
    for out in outputs:
        if out.resolve() in inputs:
            raise CurvsliceError(f"the output {out} would overwrite the input of the same name; "
                                 "choose another --out or --name")


@contextmanager
def atomic_files(out: str | Path, protect: Iterable[Path] = (), stale: Iterable[str] = ()) -> Iterator[Path]:
    """Yield a temporary folder inside ``out``; when the block succeeds its files move into ``out``.

    Files matching the ``stale`` globs in ``out`` (an earlier, longer split) are removed at the same
    time; an output landing on one of ``protect`` (the command's inputs) is refused before anything
    moves. Nothing of the set is left behind on an error or a signal.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CurvsliceError(f"--out {out} is a file, not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CurvsliceError(f"cannot create --out {out} ({exc.strerror})") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise CurvsliceError(f"--out {out} is not writable")
    with output_lock(out / ".curvslice.lock", out):
        tmp = out / f".curvslice.partial-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        try:
            yield tmp
            written = sorted(p.relative_to(tmp) for p in tmp.rglob("*") if p.is_file())
            _refuse_inputs((out / rel for rel in written), protect)
            with _signals_blocked():
                for pattern in stale:
                    for old in out.glob(pattern):
                        if old.relative_to(out) not in written:
                            old.unlink()
                for rel in written:
                    (out / rel).parent.mkdir(parents=True, exist_ok=True)
                    os.replace(tmp / rel, out / rel)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


@contextmanager
def atomic_folder(target: str | Path, force: bool = False, protect: tuple[Path, ...] = ()) -> Iterator[Path]:
    """Yield a fresh temporary folder that becomes ``target`` when the block ends without error."""
    target = Path(target).resolve()
    for p in protect:
        p = Path(p).resolve()
        if p == target or target in p.parents:
            raise CurvsliceError(f"--out {target} would overwrite the input {p}; choose another output folder")
    if target.exists():
        if not force:
            raise CurvsliceError(f"{target} already exists; pass --force to replace it or choose another --out")
        if not target.is_dir() or not (target / "report.json").exists():
            raise CurvsliceError(f"{target} exists and is not a curvslice output folder; refusing to replace it")
    if not target.parent.exists():
        raise CurvsliceError(f"the parent folder of --out ({target.parent}) does not exist")
    if not os.access(target.parent, os.W_OK | os.X_OK):
        raise CurvsliceError(f"cannot write --out {target}: its parent folder is not writable")
    with output_lock(target.parent / f".{target.name}.lock", target):
        tmp = target.parent / f".{target.name}.partial-{os.getpid()}"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        try:
            yield tmp
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        with _signals_blocked():
            if target.exists():
                if not force:  # appeared while this run worked (a run that did not take the lock)
                    shutil.rmtree(tmp, ignore_errors=True)
                    raise CurvsliceError(f"{target} appeared while this run worked; pass --force to replace it")
                old = target.parent / f".{target.name}.old-{os.getpid()}"
                os.replace(target, old)
                os.replace(tmp, target)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(tmp, target)
