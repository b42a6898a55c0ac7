"""Atomic output folders: a slice folder appears whole or not at all.

Everything is written into a hidden sibling ``.NAME.partial-PID`` that is renamed into place only
when every stage succeeded; on an error or Ctrl-C it is removed. An existing folder is replaced
only with ``force`` and only if it is a curvslice output (has ``report.json``); a folder holding
the input model is never replaced.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from curvslice.errors import CurvsliceError


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
    tmp = target.parent / f".{target.name}.partial-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if target.exists():
        old = target.parent / f".{target.name}.old-{os.getpid()}"
        os.replace(target, old)
        os.replace(tmp, target)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, target)
