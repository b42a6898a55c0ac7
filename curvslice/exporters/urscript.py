"""URScript programs for Universal Robots arms (joint-space trajectories and Cartesian paths).

Joint-space programs carry the motion stage's timed trajectory (thesis §3.5.3, §4.3): every row
is one ``servoj`` lasting exactly its time step, and a new ``segment`` (a disconnection,
Fig. 3.11b) is reached by a timed ``movej``. Cartesian programs (``curvslice convert``) are
blended ``movel`` moves at the G-code speed. Long programs are split into several files of at
most ``max_lines`` lines, each a complete ``def …: end`` program the controller runs in order;
every file restates the output states it starts with. Bookkeeping comments (``# t_start``,
``# segment``, ``# E…``, ``# event …``) let the readers restore what the writer was given.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from curvslice.cell.cells import UrIO
from curvslice.errors import CurvsliceError
from curvslice.exporters import (
    check_robot_path,
    clean_outdir,
    event_text,
    fixed,
    joint_program,
    output_switches,
    parse_event_text,
    read_joint_rows,
    relative_times,
)
from curvslice.robot_path import Event, RobotPath

_NUM = r"[-+0-9.eE]+"
_JOINT_MOVE = re.compile(rf"^\s*(servoj|movej)\(\[([^\]]*)\](?:.*?\bt=({_NUM}))?")
_POSE_MOVE = re.compile(rf"^\s*(movel|movej)\(p\[([^\]]*)\].*?\bv=({_NUM})[^#]*(?:#\s*E({_NUM}))?")
_DIGITAL_OUT = re.compile(r"^\s*set_standard_digital_out\((\d+),\s*(True|False)\)")
_SLEEP = re.compile(rf"^\s*sleep\(({_NUM})\)")
_COMMENT = re.compile(r"^\s*#\s?(.*)$")
_COMMENT_NUMBER = re.compile(rf"^\s*#\s*(t_start|segment)\s+({_NUM})")

#: Lines a file spends outside its rows: def, part comment, final output reset, end.
_FILE_OVERHEAD = 4


#: The script files a split program writes (glob): an earlier, longer split's extras are stale.
SPLIT_FILES = "{name}_[0-9][0-9][0-9].script"


def _check_name(name: str) -> str:
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,40}", name):
        raise CurvsliceError(f"program name {name!r} is not a URScript identifier (letters, digits, _)")
    return name


def _write_parts(
    outdir: Path, name: str, n: int, block: Callable[[int, bool], list[str]], footer: list[str], max_lines: int
) -> list[Path]:
    """Pack row blocks greedily into ``name_001.script …`` of at most ``max_lines`` lines each.

    ``block(i, new_file)`` returns the lines for row i; ``new_file`` asks it to restate state.
    """
    if max_lines < 4 + _FILE_OVERHEAD:
        raise CurvsliceError(f"max_lines={max_lines} leaves no room for motion lines (need at least 8)")
    outdir = Path(outdir)
    clean_outdir(outdir, SPLIT_FILES.format(name=name))
    files: list[list[str]] = []
    body: list[str] = []
    for i in range(n):
        lines = block(i, not body)
        if body and len(body) + len(lines) > max_lines - _FILE_OVERHEAD:
            files.append(body)
            lines = block(i, True)
            body = []
        if len(lines) > max_lines - _FILE_OVERHEAD:
            raise CurvsliceError(f"max_lines={max_lines} is too small for the {len(lines)} lines of row {i}")
        body += lines
    files.append(body)
    paths = []
    for part, body in enumerate(files, start=1):
        lines = [f"def {name}_{part:03d}():", f"  # curvslice program part {part} of {len(files)}", *body]
        lines += footer if part == len(files) else []
        lines.append("end")
        path = outdir / f"{name}_{part:03d}.script"
        path.write_text("\n".join(lines) + "\n")
        paths.append(path)
    return paths


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
    dt = relative_times(t)
    # every row's numbers formatted at once from Python floats (3x faster than numpy scalars)
    row_joints = [", ".join(["{:.9f}"] * 6).format(*row) for row in np.asarray(q, float).tolist()]
    row_dt = [f"{v:.9f}" for v in np.asarray(dt, float).tolist()]

    def block(i: int, new_file: bool) -> list[str]:
        lines = [f"  # t_start {float(t[i])!r}"] if new_file else []
        if new_file or seg[i] != seg[i - 1]:
            lines.append(f"  # segment {seg[i]}")
        if new_file or ext[i] != ext[i - 1]:
            lines.append(f"  set_standard_digital_out({digital_out}, {bool(ext[i])})")
        joints = row_joints[i]
        if i == 0:
            lines.append(f"  movej([{joints}], a=1.0, v={approach_speed:g})")
        elif seg[i] != seg[i - 1]:
            lines.append(f"  movej([{joints}], t={row_dt[i]})")
        else:
            lines.append(f"  servoj([{joints}], t={row_dt[i]}, lookahead_time=0.1, gain=300)")
        return lines

    footer = [f"  set_standard_digital_out({digital_out}, False)"]
    return _write_parts(outdir, _check_name(name), len(q), block, footer, max_lines)


def read_urscript_joints(paths: Sequence[Path]) -> dict[str, np.ndarray]:
    """Read files of :func:`write_urscript_joints` (in run order) back to ``q, t, segment, extruding``."""

    def move(line: str) -> tuple[list[float], float | None] | None:
        m = _JOINT_MOVE.match(line)
        return None if m is None else ([float(v) for v in m[2].split(",")], m[3])

    def output(line: str) -> bool | None:
        m = _DIGITAL_OUT.match(line)
        return None if m is None else m[2] == "True"

    files = [(Path(p), Path(p).read_text(), move) for p in paths]
    return read_joint_rows(files, _COMMENT_NUMBER, output)


def write_urscript(
    outdir: Path, robot: RobotPath, io: UrIO, *, name: str = "curvslice", max_lines: int = 20000
) -> list[Path]:
    """A Cartesian program: ``movel`` per row (``movej`` for G28 homing), speed in m/s, blended by
    ``io.blend`` except where an output switches next (there r=0, a full stop at the point).

    The extruder output follows ``robot.extruding``; ``io.retract_output`` (if set) is high while
    the filament is retracted. Dwell (G4) becomes ``sleep``; other events become comments.
    """
    check_robot_path(robot, "URScript writer")
    outputs = [(io.extruder_output, robot.extruding)]
    if io.retract_output is not None:
        outputs.append((io.retract_output, robot.retracted))
    events = robot.events_at()
    dwell_next = np.zeros(len(robot), bool)
    dwell_next[:-1] = [any(ev.code == "G4" for ev in events.get(i + 1, [])) for i in range(len(robot) - 1)]
    stop = output_switches(*(state for _, state in outputs)) | dwell_next
    rotvec = Rotation.from_quat(np.roll(robot.quaternions, -1, axis=1)).as_rotvec()
    pose = np.hstack([robot.positions / 1000.0, rotvec])

    def event_lines(i: int) -> list[str]:
        return [f"  sleep({fixed(ev.params['seconds'], 3)})" if ev.code == "G4" else f"  # {event_text(ev)}"
                for ev in events.get(i, [])]

    def block(i: int, new_file: bool) -> list[str]:
        lines = event_lines(i)
        for port, state in outputs:
            if new_file or state[i] != state[i - 1]:
                lines.append(f"  set_standard_digital_out({port}, {bool(state[i])})")
        p = ", ".join(f"{v:.6f}" for v in pose[i])
        blend = 0.0 if stop[i] or i == len(robot) - 1 else io.blend / 1000.0
        move = "movej" if robot.home[i] else "movel"
        lines.append(
            f"  {move}(p[{p}], a={io.acceleration / 1000.0:g}, v={robot.speed[i] / 1000.0:.6f}, r={blend:g})"
            f"  # E{fixed(robot.extrusion[i], 6)}"
        )
        return lines

    footer = event_lines(len(robot)) + [f"  set_standard_digital_out({port}, False)" for port, _ in outputs]
    return _write_parts(outdir, _check_name(name), len(robot), block, footer, max_lines)


def read_urscript(paths: Sequence[Path], io: UrIO = UrIO()) -> dict[str, object]:
    """Read files of :func:`write_urscript`: ``positions`` (N,3) mm, ``quaternions`` (N,4),
    ``speed`` mm/s, ``extrusion`` mm, ``extruding``/``retracted`` output states, ``home``, ``events``."""
    pose, speed, extrusion, home, ext, ret, events = [], [], [], [], [], [], []
    state: dict[int, bool] = {}
    for path in paths:
        for line in Path(path).read_text().splitlines():
            if m := _POSE_MOVE.match(line):
                pose.append([float(v) for v in m[2].split(",")])
                speed.append(float(m[3]) * 1000.0)
                extrusion.append(float(m[4]) if m[4] else 0.0)
                home.append(m[1] == "movej")
                ext.append(state.get(io.extruder_output, False))
                ret.append(state.get(io.retract_output, False) if io.retract_output is not None else False)
            elif m := _DIGITAL_OUT.match(line):
                state[int(m[1])] = m[2] == "True"
            elif m := _SLEEP.match(line):
                events.append(Event(len(pose), 0, "G4", {"seconds": float(m[1])}, ""))
            elif (m := _COMMENT.match(line)) and (ev := parse_event_text(m[1], len(pose))):
                events.append(ev)
    pose_arr = np.asarray(pose, float).reshape(-1, 6)
    xyzw = Rotation.from_rotvec(pose_arr[:, 3:]).as_quat() if len(pose_arr) else np.zeros((0, 4))
    return {
        "positions": pose_arr[:, :3] * 1000.0,
        "quaternions": np.roll(xyzw, 1, axis=1),
        "speed": np.asarray(speed, float),
        "extrusion": np.asarray(extrusion, float),
        "extruding": np.asarray(ext, bool),
        "retracted": np.asarray(ret, bool),
        "home": np.asarray(home, bool),
        "events": events,
    }
