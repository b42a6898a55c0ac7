"""Writers (and readers) of robot programs and tool-path files.

One module per target language: ``gcode6`` (the thesis appendix's extended G-code with
``nX nY nZ``), ``urscript`` (Universal Robots), ``rapid`` (ABB, seeds 000/004), ``vplus``
(Adept, seed 003) and ``arduino`` (the AccelStepper extruder sketch of seed 003). Every writer
has a reader so a program can be checked by reading it back. This package module holds the
small helpers the writers share: argument checks, number formatting and file splitting.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from curvslice.errors import CurvsliceError
from curvslice.robot_path import Event, RobotPath
from curvslice.validate import require_finite


_EVENT_TEXT = re.compile(r"^event\s+(\S+)((?:\s+[A-Za-z]+=[-+0-9.eE]+)*)\s*(?:\|\s?(.*))?$")


def event_text(event: Event) -> str:
    """One-line form of an event for a program comment: ``event M104 S=215 | free text``."""
    params = "".join(f" {k}={v!r}" for k, v in event.params.items())
    return f"event {event.code}{params}" + (f" | {event.text}" if event.text else "")


def parse_event_text(text: str, index: int) -> Event | None:
    """Inverse of :func:`event_text` (``None`` when ``text`` is not an event comment)."""
    m = _EVENT_TEXT.match(text.strip())
    if not m:
        return None
    params = {k: float(v) for k, v in (w.split("=") for w in m[2].split())}
    return Event(index, 0, m[1], params, m[3] or "")


def check_robot_path(robot: RobotPath, where: str) -> None:
    """Refuse a path a controller must not run: no moves, NaN / inf anywhere, or a speed <= 0 mm/s."""
    if len(robot) == 0:
        raise CurvsliceError(f"{where}: the path has no moves; nothing to write")
    require_finite(where, positions=robot.positions, quaternions=robot.quaternions, speed=robot.speed,
                   extrusion=robot.extrusion)
    if np.any(robot.speed <= 0):
        row = int(np.argmax(robot.speed <= 0))
        raise CurvsliceError(f"{where}: speed {robot.speed[row]:g} mm/s at row {row} is not positive")


def output_switches(*states: np.ndarray) -> np.ndarray:
    """(N,) bool: the move *after* row i needs some output in ``states`` to change.

    A writer ends such a move with a full stop so the switch happens at the point.
    """
    n = len(states[0])
    switch = np.zeros(n, bool)
    for s in states:
        s = np.asarray(s)
        switch[:-1] |= s[1:] != s[:-1]
    return switch


def fixed(value: float, digits: int) -> str:
    """``value`` rounded to ``digits`` decimals without trailing zeros, keeping one (``10.0``)."""
    text = f"{float(value):.{digits}f}".rstrip("0")
    text = text + "0" if text.endswith(".") else text
    return "0.0" if text in ("-0.0", "-0") else text


def compact(value: float, digits: int) -> str:
    """``value`` rounded to ``digits`` decimals without trailing zeros or dot (``180``, ``0.5``)."""
    text = fixed(value, digits)
    return text[:-2] if text.endswith(".0") else text


def chunks(n: int, per_chunk: int) -> list[range]:
    """Consecutive index ranges covering ``range(n)`` with at most ``per_chunk`` items each."""
    if per_chunk < 1:
        raise CurvsliceError(f"file split size must be at least 1 (got {per_chunk})")
    return [range(s, min(s + per_chunk, n)) for s in range(0, n, per_chunk)]


def joint_program(
    q: np.ndarray, t: np.ndarray, segment: np.ndarray | None, extruding: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Validated joint-space program arrays: q (N,6) rad, t (N,) s increasing, segment, extruding.

    ``segment`` defaults to one motion (all 0), ``extruding`` to all False.
    """
    q = np.asarray(q, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 6 or len(q) == 0:
        raise CurvsliceError(f"joint program needs q of shape (N, 6) with N >= 1, got {q.shape}")
    if t.shape != (len(q),):
        raise CurvsliceError(f"joint program needs one time per row: t has shape {t.shape}, q {q.shape}")
    if not (np.isfinite(q).all() and np.isfinite(t).all()):
        raise CurvsliceError("joint program contains NaN or infinite joint angles or times")
    if np.any(np.diff(t) <= 0):
        bad = int(np.argmax(np.diff(t) <= 0)) + 1
        raise CurvsliceError(f"joint program times must increase strictly (row {bad}: t={t[bad]} after {t[bad - 1]})")
    seg = np.zeros(len(q), np.int64) if segment is None else np.asarray(segment).astype(np.int64)
    ext = np.zeros(len(q), bool) if extruding is None else np.asarray(extruding).astype(bool)
    if seg.shape != (len(q),) or ext.shape != (len(q),):
        raise CurvsliceError("segment and extruding must have one entry per joint-program row")
    return q, t, seg, ext


def relative_times(t: np.ndarray) -> np.ndarray:
    """Per-row durations (s, 9 decimals) whose running sum restores ``t - t[0]`` to 1e-9 s.

    Rounding the *absolute* offsets before differencing keeps rounding errors from
    accumulating over long programs. The first entry is 0.
    """
    r = np.round(t - t[0], 9)
    return np.diff(r, prepend=r[0])


def clean_outdir(outdir: Path, pattern: str) -> None:
    """Create ``outdir`` and delete stale files of an earlier split (``pattern`` glob)."""
    outdir.mkdir(parents=True, exist_ok=True)
    for old in outdir.glob(pattern):
        old.unlink()


#: A joint-program line parser: the row's joint values and duration (None on a file's first row).
MoveParser = Callable[[str], "tuple[list[float], float | None] | None"]


def read_joint_rows(
    files: list[tuple[Path, str, MoveParser]], comment: re.Pattern, output: Callable[[str], bool | None]
) -> dict[str, np.ndarray]:
    """Rows of joint programs written with ``t_start`` / ``segment`` bookkeeping comments.

    ``files`` are (path, text, move parser) in run order; ``comment`` matches the bookkeeping
    comments (groups: key, value); ``output`` returns the extruder state a line sets, or None.
    A file's first row takes the file's ``t_start``; later rows add their durations to it.
    """
    q, t, seg, ext = [], [], [], []
    for path, text, move in files:
        t_file, rel = None, None
        segment, state = 0, False
        for line in text.splitlines():
            if m := comment.match(line):
                if m[1] == "t_start":
                    t_file = float(m[2])
                else:
                    segment = int(m[2])
            elif (switch := output(line)) is not None:
                state = switch
            elif (row := move(line)) is not None:
                if t_file is None:
                    raise CurvsliceError(f"{path}: motion before the 't_start' header; not a curvslice joint program")
                rel = 0.0 if rel is None else rel + float(row[1])
                q.append(row[0])
                t.append(t_file + rel)
                seg.append(segment)
                ext.append(state)
    if not q:
        raise CurvsliceError("no joint motion found in the program files")
    return {
        "q": np.asarray(q, dtype=np.float64),
        "t": np.asarray(t, dtype=np.float64),
        "segment": np.asarray(seg, dtype=np.int64),
        "extruding": np.asarray(ext, dtype=bool),
    }
