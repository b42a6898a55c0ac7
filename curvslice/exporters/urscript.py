"""URScript programs for Universal Robots arms (joint-space trajectories and Cartesian paths).

Joint-space programs carry the motion stage's timed trajectory (thesis §3.5.3, §4.3): every row
is one ``servoj`` lasting exactly its time step, and a new ``segment`` (a disconnection,
Fig. 3.11b) is reached by a timed ``movej`` with the extruder off. Long programs are split into
several files of at most ``max_lines`` lines, each a complete ``def ...: end`` program the
controller runs in order. Bookkeeping comments (``# t_start``, ``# segment``) let the reader
restore absolute times and segment ids exactly.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from curvslice.errors import CurvsliceError
from curvslice.exporters import clean_outdir, joint_program, relative_times

_JOINT_MOVE = re.compile(r"^\s*(servoj|movej)\(\[([^\]]*)\](?:.*?\bt=([-+0-9.eE]+))?")
_DIGITAL_OUT = re.compile(r"^\s*set_standard_digital_out\((\d+),\s*(True|False)\)")
_COMMENT_NUMBER = re.compile(r"^\s*#\s*(t_start|segment)\s+([-+0-9.eE]+)")

#: Lines a joint-program file spends outside its rows: def, part comment, output reset, end.
_JOINT_OVERHEAD = 4


def _row_header(i: int, seg: np.ndarray, ext: np.ndarray, digital_out: int, t: np.ndarray, new_file: bool) -> list[str]:
    """Bookkeeping and extruder lines written before the move to row ``i``."""
    head = [f"  # t_start {float(t[i])!r}"] if new_file else []
    if new_file or seg[i] != seg[i - 1]:
        head.append(f"  # segment {seg[i]}")
    if new_file or ext[i] != ext[i - 1]:
        head.append(f"  set_standard_digital_out({digital_out}, {bool(ext[i])})")
    return head


def write_urscript_joints(
    outdir: Path,
    q: np.ndarray,
    t: np.ndarray,
    *,
    segment: np.ndarray | None = None,
    extruding: np.ndarray | None = None,
    max_lines: int = 20000,
    name: str = "curvslice",
    digital_out: int = 0,
    approach_speed: float = 0.5,
) -> list[Path]:
    """Write ``name_001.script …`` (≤ ``max_lines`` lines each) and return their paths in run order.

    ``q`` (N,6) rad at absolute times ``t`` (N,) s; ``segment`` starts a new smooth motion where
    it changes (reached by ``movej``); ``extruding[i]`` switches standard digital output
    ``digital_out`` while moving to row i. The first row is approached at ``approach_speed``
    rad/s; every later row takes exactly ``t[i] - t[i-1]`` seconds.
    """
    q, t, seg, ext = joint_program(q, t, segment, extruding)
    if max_lines < 8:
        raise CurvsliceError(f"max_lines={max_lines} leaves no room for motion lines (need at least 8)")
    dt = relative_times(t)
    outdir = Path(outdir)
    clean_outdir(outdir, f"{name}_[0-9][0-9][0-9].script")
    files: list[list[str]] = []
    body: list[str] = []
    for i in range(len(q)):
        joints = ", ".join(f"{v:.9f}" for v in q[i])
        if i == 0:
            move = f"  movej([{joints}], a=1.0, v={approach_speed:g})"
        elif seg[i] != seg[i - 1]:
            move = f"  movej([{joints}], t={dt[i]:.9f})"
        else:
            move = f"  servoj([{joints}], t={dt[i]:.9f}, lookahead_time=0.1, gain=300)"
        head = _row_header(i, seg, ext, digital_out, t, new_file=not body)
        if body and len(body) + len(head) + 1 > max_lines - _JOINT_OVERHEAD:
            files.append(body)
            body = []
            head = _row_header(i, seg, ext, digital_out, t, new_file=True)
        body += head + [move]
    files.append(body)
    paths = []
    for part, body in enumerate(files, start=1):
        lines = [f"def {name}_{part:03d}():", f"  # curvslice joint program part {part} of {len(files)}", *body]
        if part == len(files):
            lines.append(f"  set_standard_digital_out({digital_out}, False)")
        lines.append("end")
        path = outdir / f"{name}_{part:03d}.script"
        path.write_text("\n".join(lines) + "\n")
        paths.append(path)
    return paths


def read_urscript_joints(paths: Sequence[Path]) -> dict[str, np.ndarray]:
    """Read files of :func:`write_urscript_joints` (in run order) back to ``q, t, segment, extruding``."""
    q, t, seg, ext = [], [], [], []
    for path in paths:
        t_file, rel = None, None
        segment, state = 0, False
        for line in Path(path).read_text().splitlines():
            if m := _COMMENT_NUMBER.match(line):
                if m[1] == "t_start":
                    t_file = float(m[2])
                else:
                    segment = int(m[2])
            elif m := _DIGITAL_OUT.match(line):
                state = m[2] == "True"
            elif m := _JOINT_MOVE.match(line):
                if t_file is None:
                    raise CurvsliceError(f"{path}: motion before the '# t_start' header; not a curvslice joint program")
                rel = 0.0 if rel is None else rel + float(m[3])
                q.append([float(v) for v in m[2].split(",")])
                t.append(t_file + rel)
                seg.append(segment)
                ext.append(state)
    if not q:
        raise CurvsliceError("no joint motion found in the URScript files")
    return {
        "q": np.asarray(q, dtype=np.float64),
        "t": np.asarray(t, dtype=np.float64),
        "segment": np.asarray(seg, dtype=np.int64),
        "extruding": np.asarray(ext, dtype=bool),
    }
