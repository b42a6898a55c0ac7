"""ABB RAPID programs (joint-space trajectories and Cartesian robtarget paths; seeds 000 and 004).

Large programs are split into modules of at most ``max_targets`` targets (seed 004, §2.3.1:
the controller heap holds ~15,000 coordinates, so modules of ≤ 7,000 let two fit at once) and
a main module loads, runs and unloads them in order with late-bound calls (seed 004, Fig. 30).
Moves blend through zones; ``fine`` (a full stop) is used only where an output must switch at
an exact point and at the end of each module (seed 004, §2.4.4: ``fine`` everywhere stops the
robot at every point).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from curvslice.cell.cells import RapidIO
from curvslice.errors import CurvsliceError
from curvslice.exporters import (
    chunks,
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
from curvslice.validate import require_finite

_IDENT = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,19}")
_NUM = r"[-+0-9.eE]+"
_JOINTTARGET = re.compile(r"CONST\s+jointtarget\s+(\w+)\s*:=\s*\[\[([^\]]*)\]")
_MOVEABSJ = re.compile(rf"^\s*MoveAbsJ\s+(\w+)\s*,\s*\w+(?:\\T:=({_NUM}))?")
_SETDO = re.compile(r"^\s*SetDO\s+(\w+)\s*,\s*([01])\s*;")
_SETDO_ANY = re.compile(r"SetDO\s+(\w+)\s*,\s*([01])\s*;")
_COMMENT_NUMBER = re.compile(rf"^\s*!\s*(t_start|segment)\s+({_NUM})")
_LOAD = re.compile(r'Load\s+\\Dynamic\s*,\s*"[^"]*?([^"/:]+)\.mod"', re.IGNORECASE)
_ROBTARGET = re.compile(r"CONST\s+robtarget\s+(\w+)\s*:=\s*\[\[([^\]]*)\]\s*,\s*\[([^\]]*)\]")
_SPEEDDATA = re.compile(rf"CONST\s+speeddata\s+(\w+)\s*:=\s*\[({_NUM})")
_MOVE = re.compile(rf"^\s*(MoveL|MoveJ)\s+(\w+)\s*,\s*(\w+)\s*,[^;]*;\s*(?:!\s*E({_NUM}))?")
_WAITTIME = re.compile(rf"^\s*WaitTime\s+(?:\\InPos\s*,\s*)?({_NUM})")
_COMMENT = re.compile(r"^\s*!\s?(.*)$")
_NINES = "[9E9,9E9,9E9,9E9,9E9,9E9]"


def check_identifier(name: str) -> str:
    """``name`` if it can prefix RAPID module/routine names (letter first, ≤ 20 characters)."""
    if not _IDENT.fullmatch(name):
        raise CurvsliceError(
            f"program name {name!r} is not usable in RAPID: use a letter then letters, digits or _ (≤ 20 characters)"
        )
    return name


#: The module files a split program writes (glob): an earlier, longer split's extras are stale.
SPLIT_FILES = "{name}_mod*.mod"


def write_main_module(
    outdir: Path, name: str, parts: int, load_dir: str, reset: list[str], declarations: Sequence[str] = ()
) -> Path:
    """The main module: global data, reset outputs, then Load \\Dynamic, call and UnLoad each part."""
    lines = [f"MODULE {name}_main", *(f"  {d}" for d in declarations)]
    lines += ["  PROC main()", "    ConfJ \\Off;", "    ConfL \\Off;"]
    lines += [f"    {r}" for r in reset]
    for k in range(1, parts + 1):
        lines += [
            f'    Load \\Dynamic, "{load_dir}{name}_mod{k}.mod";',
            f'    %"{name}_part{k}"%;',
            f'    UnLoad "{load_dir}{name}_mod{k}.mod";',
        ]
    lines += [f"    {r}" for r in reset]
    lines += ["  ENDPROC", "ENDMODULE"]
    path = outdir / f"{name}_main.mod"
    path.write_text("\n".join(lines) + "\n")
    return path


def ordered_modules(paths: Sequence[Path]) -> list[Path]:
    """Part modules in run order: the main module's Load order if it is given, else as given."""
    paths = [Path(p) for p in paths]
    mains = [p for p in paths if p.stem.endswith("_main")]
    parts = [p for p in paths if not p.stem.endswith("_main")]
    if not mains:
        return parts
    by_stem = {p.stem.lower(): p for p in parts}
    order = [m.lower() for m in _LOAD.findall(mains[0].read_text())]
    missing = [s for s in order if s not in by_stem]
    if missing:
        raise CurvsliceError(f"main module loads {missing[0]}.mod, which is not among the given files")
    return [by_stem[s] for s in order]


def write_rapid_joints(
    outdir: Path,
    q: np.ndarray,
    t: np.ndarray,
    *,
    segment: np.ndarray | None = None,
    extruding: np.ndarray | None = None,
    max_targets: int = 7000,
    name: str = "curvslice",
    extruder_signal: str = "doExtruder",
    zone: str = "z1",
    approach_speed: str = "v100",
    load_dir: str = "HOME:/",
) -> list[Path]:
    """Write ``name_main.mod`` + ``name_mod1.mod …`` (≤ ``max_targets`` jointtargets each).

    Returns ``[main, mod1, mod2, …]``. Row i is a ``MoveAbsJ`` lasting exactly ``t[i] - t[i-1]``
    (``\\T``); joint angles are written in degrees. ``extruding[i]`` sets ``extruder_signal``
    before the move to row i, after a ``fine`` stop so the switch happens at the point. A new
    ``segment`` value also ends the previous motion with ``fine``.
    """
    q, t, seg, ext = joint_program(q, t, segment, extruding)
    check_identifier(name)
    dt = relative_times(t)
    deg = np.degrees(q)
    outdir = Path(outdir)
    clean_outdir(outdir, SPLIT_FILES.format(name=name))
    n = len(q)
    # stop after the untimed approach, where the next row switches the extruder or starts a new
    # segment, and where a module ends
    stop = output_switches(ext, seg)
    stop[[0, -1]] = True
    parts = chunks(n, max_targets)
    paths = []
    for k, rows in enumerate(parts, start=1):
        stop[rows.stop - 1] = True
        lines = [
            f"MODULE {name}_mod{k}",
            f"  ! curvslice joint program part {k} of {len(parts)}, rows {rows.start}..{rows.stop - 1}",
            f"  ! t_start {float(t[rows.start])!r}",
        ]
        lines += [
            f"  LOCAL CONST jointtarget j{i} := [[{','.join(f'{v:.6f}' for v in deg[i])}],{_NINES}];" for i in rows
        ]
        lines.append(f"  PROC {name}_part{k}()")
        for i in rows:
            first = i == rows.start
            if first or seg[i] != seg[i - 1]:
                lines.append(f"    ! segment {seg[i]}")
            if first or ext[i] != ext[i - 1]:
                lines.append(f"    SetDO {extruder_signal}, {int(ext[i])};")
            z = "fine" if stop[i] else zone
            speed = approach_speed if i == 0 else f"v1000\\T:={dt[i]:.9f}"
            lines.append(f"    MoveAbsJ j{i}, {speed}, {z}, tool0;")
        lines += ["  ENDPROC", "ENDMODULE"]
        path = outdir / f"{name}_mod{k}.mod"
        path.write_text("\n".join(lines) + "\n")
        paths.append(path)
    main = write_main_module(outdir, name, len(parts), load_dir, [f"SetDO {extruder_signal}, 0;"])
    return [main, *paths]


def read_rapid_joints(paths: Sequence[Path]) -> dict[str, np.ndarray]:
    """Read modules of :func:`write_rapid_joints` back to ``q`` (rad), ``t``, ``segment``, ``extruding``.

    ``paths`` may include the main module (its Load order is then used) or list the part
    modules in run order.
    """

    def parser(path: Path, targets: dict[str, list[float]]):
        def move(line: str) -> tuple[list[float], float | None] | None:
            m = _MOVEABSJ.match(line)
            if m is None:
                return None
            if m[1] not in targets:
                raise CurvsliceError(f"{path}: MoveAbsJ to undeclared jointtarget {m[1]}")
            return targets[m[1]], m[2]

        return move

    def output(line: str) -> bool | None:
        m = _SETDO.match(line)
        return None if m is None else m[2] == "1"

    files = []
    for path in ordered_modules(paths):
        text = path.read_text()
        targets = {m[1]: [float(v) for v in m[2].split(",")] for m in _JOINTTARGET.finditer(text)}
        files.append((path, text, parser(path, targets)))
    rows = read_joint_rows(files, _COMMENT_NUMBER, output)
    rows["q"] = np.radians(rows["q"])
    return rows

def speed_words(robot: RobotPath, io: RapidIO) -> np.ndarray:
    """(N,) int: the speed shown on ``io.speed_outputs`` during each move (seed 004 §2.3.2).

    The word is the TCP speed in units of ``io.speed_unit`` mm/s while extruding, else 0. A
    speed that does not fit in the outputs is an error naming its G-code line (seed 004's
    converter silently dropped the 8th bit).
    """
    word = np.where(robot.extruding, np.rint(robot.speed / io.speed_unit), 0).astype(np.int64)
    limit = (1 << len(io.speed_outputs)) - 1
    over = word > limit
    if io.speed_outputs and over.any():
        i = int(np.argmax(over))
        raise CurvsliceError(
            f"line {robot.line[i]}: {robot.speed[i]:g} mm/s is {word[i]} speed units of {io.speed_unit:g} mm/s, "
            f"more than {len(io.speed_outputs)} speed outputs can show (max {limit}); "
            f"add outputs to rapid.speed_outputs or raise rapid.speed_unit"
        )
    return word


def _output_states(robot: RobotPath, io: RapidIO) -> list[tuple[list[str], np.ndarray]]:
    """(signal names, per-row value) of every output the program drives; bits MSB first."""
    states = []
    if io.speed_outputs:
        states.append((list(io.speed_outputs), speed_words(robot, io)))
    if io.retract_output:
        states.append(([io.retract_output], robot.retracted.astype(np.int64)))
    if io.extruder_output:
        states.append(([io.extruder_output], robot.extruding.astype(np.int64)))
    return states


def _set_outputs(names: list[str], value: int) -> str:
    bits = len(names)
    return " ".join(f"SetDO {n}, {(value >> (bits - 1 - b)) & 1};" for b, n in enumerate(names))


def write_rapid(outdir: Path, robot: RobotPath, io: RapidIO, *, name: str = "curvslice") -> list[Path]:
    """A Cartesian RAPID program: ``name_main.mod`` + ``name_mod1.mod …`` (≤ ``io.max_targets``
    robtargets each). Returns ``[main, mod1, …]``.

    Each row is ``MoveL`` (``MoveJ`` for G28 homing) to a robtarget with the normalised tool
    quaternion and ``io.robconf``, at a speeddata declared once per distinct speed in the main
    module, through zone ``io.zone``; ``fine`` only where an output switches before the next
    move, before a dwell and at module ends. Outputs are written before the move they apply
    to: the speed word, the retraction signal, the extruder signal (as the cell defines them).
    The filament of each move is kept as a trailing ``! E…`` comment.
    """
    check_identifier(name)
    check_robot_path(robot, "RAPID writer")
    outdir = Path(outdir)
    n = len(robot)
    states = _output_states(robot, io)
    speeds = np.round(robot.speed, 3)
    table = {float(v): k for k, v in enumerate(dict.fromkeys(speeds.tolist()), start=1)}
    quats = robot.quaternions / np.linalg.norm(robot.quaternions, axis=1, keepdims=True)
    events = robot.events_at()
    stop = output_switches(*(v for _, v in states))
    stop[:-1] |= np.array([any(ev.code == "G4" for ev in events.get(i + 1, [])) for i in range(n - 1)], bool)
    conf = ",".join(str(int(c)) for c in io.robconf)
    clean_outdir(outdir, SPLIT_FILES.format(name=name))

    def event_lines(i: int) -> list[str]:
        return [f"    WaitTime \\InPos, {fixed(ev.params['seconds'], 3)};" if ev.code == "G4" else f"    ! {event_text(ev)}"
                for ev in events.get(i, [])]

    parts = chunks(n, io.max_targets)
    paths = []
    for k, rows in enumerate(parts, start=1):
        stop[rows.stop - 1] = True
        lines = [f"MODULE {name}_mod{k}", f"  ! curvslice path part {k} of {len(parts)}, rows {rows.start}..{rows.stop - 1}"]
        for i in rows:
            xyz = ",".join(fixed(v, 3) for v in robot.positions[i])
            q = ",".join(f"{v:.7f}" for v in quats[i])
            lines.append(f"  LOCAL CONST robtarget p{i} := [[{xyz}],[{q}],[{conf}],{_NINES}];")
        lines.append(f"  PROC {name}_part{k}()")
        for i in rows:
            lines += event_lines(i)
            for names, value in states:
                if i == rows.start or value[i] != value[i - 1]:
                    lines.append(f"    {_set_outputs(names, int(value[i]))}")
            move = "MoveJ" if robot.home[i] else "MoveL"
            zone = "fine" if stop[i] else io.zone
            lines.append(
                f"    {move} p{i}, sd{table[float(speeds[i])]}, {zone}, {io.tool}\\WObj:={io.wobj}; "
                f"! E{fixed(robot.extrusion[i], 6)}"
            )
        if k == len(parts):
            lines += event_lines(n)
        lines += ["  ENDPROC", "ENDMODULE"]
        path = outdir / f"{name}_mod{k}.mod"
        path.write_text("\n".join(lines) + "\n")
        paths.append(path)
    declarations = [f"CONST speeddata sd{k} := [{fixed(v, 3)},500,5000,1000];" for v, k in table.items()]
    reset = [_set_outputs(names, 0) for names, _ in states]
    return [write_main_module(outdir, name, len(parts), io.load_dir, reset, declarations), *paths]


def read_rapid(paths: Sequence[Path], io: RapidIO = RapidIO()) -> dict[str, object]:
    """Read a program of :func:`write_rapid` (main module included, for the speeds).

    Returns ``positions`` (N,3), ``quaternions`` (N,4), ``speed`` (N,), ``extrusion`` (N,),
    ``home`` (N,), ``events`` and the output values during each move: ``speed_word``,
    ``retracted``, ``extruding`` (from the cell's output names; absent outputs read as 0).
    """
    paths = [Path(p) for p in paths]
    speeds: dict[str, float] = {}
    for p in paths:
        speeds.update({m[1]: float(m[2]) for m in _SPEEDDATA.finditer(p.read_text())})
    bit_of = {n: len(io.speed_outputs) - 1 - b for b, n in enumerate(io.speed_outputs)}
    signals: dict[str, int] = {}
    pos, quat, speed, extrusion, home, words, ret, ext, events = [], [], [], [], [], [], [], [], []
    for path in ordered_modules(paths):
        text = path.read_text()
        targets = {m[1]: (m[2], m[3]) for m in _ROBTARGET.finditer(text)}
        for line in text.splitlines():
            if m := _MOVE.match(line):
                xyz, q = targets[m[2]]
                pos.append([float(v) for v in xyz.split(",")])
                quat.append([float(v) for v in q.split(",")])
                speed.append(speeds.get(m[3], np.nan))
                extrusion.append(float(m[4]) if m[4] else 0.0)
                home.append(m[1] == "MoveJ")
                words.append(sum(signals.get(n, 0) << b for n, b in bit_of.items()))
                ret.append(bool(signals.get(io.retract_output, 0)) if io.retract_output else False)
                ext.append(bool(signals.get(io.extruder_output, 0)) if io.extruder_output else words[-1] > 0)
            elif m := _WAITTIME.match(line):
                events.append(Event(len(pos), 0, "G4", {"seconds": float(m[1])}, ""))
            elif m := _COMMENT.match(line):
                if ev := parse_event_text(m[1], len(pos)):
                    events.append(ev)
            else:
                for sig, value in _SETDO_ANY.findall(line):
                    signals[sig] = int(value)
    return {
        "positions": np.asarray(pos, float).reshape(-1, 3),
        "quaternions": np.asarray(quat, float).reshape(-1, 4),
        "speed": np.asarray(speed, float),
        "extrusion": np.asarray(extrusion, float),
        "home": np.asarray(home, bool),
        "speed_word": np.asarray(words, np.int64),
        "retracted": np.asarray(ret, bool),
        "extruding": np.asarray(ext, bool),
        "events": events,
    }


def write_probe_routine(
    path: str | Path,
    xs: np.ndarray,
    ys: np.ndarray,
    *,
    name: str = "BedProbe",
    probe_offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 0.0),
    signal: str = "diProbe",
    tool: str = "tool0",
    wobj: str = "wobj0",
    clearance: float = 20.0,
    depth: float = 5.0,
    csv_name: str = "HOME:/probe.csv",
) -> int:
    """Write a RAPID module probing the lattice ``xs`` × ``ys`` (seed 004 Appendix 9); returns the count.

    For each point (row by row, serpentine) the nozzle moves ``clearance`` above the target with
    the probe over the grid point (``probe_offset`` = probe tip − nozzle tip), searches down to
    ``depth`` below z = 0 with ``SearchL \\Stop`` until ``signal`` rises, retracts, and appends the
    touched bed point (search position + ``probe_offset``) to ``csv_name`` as ``x,y,z``.
    """
    xs = np.asarray(xs, float)
    ys = np.asarray(ys, float)
    require_finite(f"RAPID probe routine writer ({Path(path).name})", xs=xs, ys=ys, probe_offset=probe_offset,
                   orientation=orientation, clearance=[clearance], depth=[depth])
    q = np.asarray(orientation, float)
    q = q / np.linalg.norm(q)
    quat = ",".join(f"{v:.9f}" for v in q)
    ox, oy, oz = probe_offset
    order = [(i, j) for j in range(len(ys)) for i in (range(len(xs)) if j % 2 == 0 else reversed(range(len(xs))))]
    lines = [f"MODULE {name}", "  VAR iodev probelog;", "  VAR robtarget touched;"]
    for k, (i, j) in enumerate(order, start=1):
        x, y = fixed(xs[i] - ox, 3), fixed(ys[j] - oy, 3)
        lines.append(f"  CONST robtarget c{k} := [[{x},{y},0.0],[{quat}],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];")
    where = f"{tool}\\WObj:={wobj}"
    lines += [f"  PROC {name}()", f'    Open "{csv_name}", probelog \\Write;', '    Write probelog, "x,y,z";']
    for k in range(1, len(order) + 1):
        lines += [
            f"    MoveL Offs(c{k},0,0,{fixed(clearance, 3)}), v50, fine, {where};",
            f"    SearchL \\Stop, {signal}, touched, Offs(c{k},0,0,{fixed(-depth, 3)}), v1, {where};",
            f"    Write probelog, NumToStr(touched.trans.x + {fixed(ox, 4)},4) + \",\" + "
            f"NumToStr(touched.trans.y + {fixed(oy, 4)},4) + \",\" + NumToStr(touched.trans.z + {fixed(oz, 4)},4);",
            f"    MoveL Offs(c{k},0,0,{fixed(clearance, 3)}), v10, fine, {where};",
        ]
    lines += ["    Close probelog;", "  ENDPROC", "ENDMODULE"]
    Path(path).write_text("\n".join(lines) + "\n")
    return len(order)
