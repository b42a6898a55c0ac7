"""Strict reader of planar slicer G-code (Slic3r / PrusaSlicer / Cura) and of extended G-code.

Seeds 003 and 004 converted slicer G-code to robot programs with ad-hoc scrapers that lost
modal state (seed 004's parser took X from the previous row whenever F came first) and ignored
unknown commands. This reader keeps the full modal state of a RepRap/Marlin machine: G0/G1
(X Y Z E F, and the thesis appendix's nX nY nZ), G4, G20/G21, G28, G90/G91, G92, M82/M83,
T, M220/M221, and records temperature, fan and other common M-codes as events. Anything else
is an error naming the line, unless ``lenient`` (then a warning and the line is skipped).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from curvslice.errors import CurvsliceError
from curvslice.robot_path import Event
from curvslice.validate import read_text

_WORD = re.compile(r"(n[XYZ]|[A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))?")  # no exponents: "X10E5" is X10 E5
_PAREN_COMMENT = re.compile(r"\([^)]*\)")
_LINE_NUMBER = re.compile(r"^\s*N\d+\s*")
_CHECKSUM = re.compile(r"\*\d+\s*$")
_NUMBERED_CHECKSUM = re.compile(r"^(\s*N\d+.*)\*(\d+)\s*(?:;.*)?$")  # RepRap host protocol: N… *cs
#: Largest magnitude of a G-code number (mm, mm/min, filament mm): beyond it the file is not a print.
MAX_NUMBER = 1e9
_LAYER_MARK = re.compile(r"^\s*;\s*(?:LAYER\s*:\s*(-?\d+)|(LAYER_CHANGE))", re.IGNORECASE)

_MOVE_WORDS = {"X", "Y", "Z", "E", "F", "nX", "nY", "nZ"}
#: Machine events recorded but not interpreted, with the parameters each may carry.
EVENT_CODES: dict[str, set[str]] = {
    # temperatures
    "M104": {"S", "T", "R"}, "M109": {"S", "T", "R"}, "M140": {"S", "R"}, "M190": {"S", "R"},
    "M141": {"S"}, "M191": {"S", "R"}, "M105": set(),
    # fans
    "M106": {"S", "P"}, "M107": {"P"},
    # motors, limits, firmware tuning the slicers emit in their start code
    "M17": set(), "M18": {"X", "Y", "Z", "E", "S"}, "M84": {"X", "Y", "Z", "E", "S"},
    "M201": {"X", "Y", "Z", "E"}, "M203": {"X", "Y", "Z", "E"}, "M204": {"P", "R", "T", "S"},
    "M205": {"X", "Y", "Z", "E", "S", "T", "B", "J"}, "M900": {"K"}, "M907": {"X", "Y", "Z", "E"},
    # progress, messages, waits, pauses
    "M73": {"P", "R", "Q", "S", "C", "D"}, "M400": set(),
    "M300": {"S", "P"}, "M600": set(), "M0": {"P", "S"}, "M1": {"P", "S"},
    # firmware retraction, bed probing
    "G10": set(), "G11": set(), "G29": set(), "G80": set(),
    # free-text commands: messages, firmware version check, object labels, PrusaSlicer printer checks
    "M117": set(), "M118": set(), "M115": set(), "M486": set(),
    "M862.1": set(), "M862.2": set(), "M862.3": set(), "M862.4": set(), "M862.5": set(), "M862.6": set(),
}
_TEXT_CODES = {"M117", "M118", "M115", "M486", "M862.1", "M862.2", "M862.3", "M862.4", "M862.5", "M862.6"}


@dataclass
class GcodeProgram:
    """Moves of a G-code file with all modal state resolved (mm, mm/min, machine coordinates).

    Row i is the move *to* ``positions[i]`` from the previous row (or from ``start``).
    """

    positions: np.ndarray  # (N, 3) mm
    normals: np.ndarray | None  # (N, 3) unit nX nY nZ, or None when the file has none
    feed: np.ndarray  # (N,) mm/min, after M220
    extrusion: np.ndarray  # (N,) filament mm on this move (negative = retraction), after M221
    rapid: np.ndarray  # (N,) bool: G0
    home: np.ndarray  # (N,) bool: G28
    tool: np.ndarray  # (N,) int32 active extruder
    layer: np.ndarray  # (N,) int32, from ;LAYER comments, else counted from Z of extruding moves
    line: np.ndarray  # (N,) int32 1-based source line
    start: np.ndarray  # (3,) position before the first move
    source: str = "<gcode>"  # file name, for messages
    events: list[Event] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.positions)


def _strip(raw: str) -> str:
    """The code part of a line: no ``( )`` comment (which may hold a ``;``), ``;`` comment, line number
    or checksum."""
    code = _PAREN_COMMENT.sub(" ", raw).split(";", 1)[0]
    code = _CHECKSUM.sub("", code)
    return _LINE_NUMBER.sub("", code).strip()


def _checksum_error(raw: str) -> str | None:
    """For a numbered line with a checksum (``N12 G1 X5*87``), why the checksum is wrong, else None.

    The checksum is the XOR of every byte before ``*`` (RepRap host protocol)."""
    m = _NUMBERED_CHECKSUM.match(raw)
    if not m or ";" in _PAREN_COMMENT.sub(" ", m[1]):
        return None
    computed = 0
    for byte in m[1].lstrip().encode():
        computed ^= byte
    return None if computed == int(m[2]) else f"checksum *{m[2]} does not match the line (its bytes give *{computed})"


def _number(text: str) -> float:
    """A G-code number; too many digits or a magnitude above :data:`MAX_NUMBER` is an error."""
    value = float(text)
    if len(text) > 32 or not abs(value) <= MAX_NUMBER:
        shown = text if len(text) <= 20 else f"{text[:12]}… ({len(text)} characters)"
        raise ValueError(f"number {shown} is out of range (|value| <= {MAX_NUMBER:g})")
    return value


def _commands(code: str) -> list[tuple[str, dict[str, float | None], str]]:
    """Split a code line into (command, parameters, text) groups; each G/M/T word starts one."""
    head = re.match(r"\s*([GMgm]\d+(?:\.\d+)?)", code)
    if head and head[1].upper() in _TEXT_CODES:
        return [(head[1].upper(), {}, code[head.end():].strip())]
    groups: list[tuple[str, dict[str, float | None], str]] = []
    pos = 0
    for m in _WORD.finditer(code):
        if code[pos : m.start()].strip():
            raise ValueError(f"cannot read {code[pos:m.start()].strip()!r}")
        pos = m.end()
        letter, value = m[1], m[2]
        key = letter if letter.startswith("n") else letter.upper()
        if key in ("G", "M") or (key == "T" and not (groups and "T" in _allowed(groups[-1][0]))):
            if value is None:
                raise ValueError(f"{key} without a number")
            number = _number(value)
            name = f"{key}{int(number)}" if number == int(number) else f"{key}{value}"
            groups.append((name, {}, ""))
        elif not groups:
            raise ValueError(f"parameter {key} before any command")
        else:
            groups[-1][1][key] = None if value is None else _number(value)
    if code[pos:].strip():
        raise ValueError(f"cannot read {code[pos:].strip()!r}")
    return groups


def parse_gcode(
    text: str,
    *,
    source: str = "<gcode>",
    lenient: bool = False,
    home: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> GcodeProgram:
    """Read G-code text. ``home`` is where G28 sends each axis (and where the machine starts)."""
    home_pos = np.asarray(home, dtype=np.float64)
    pos = home_pos.copy()  # machine position
    offset = np.zeros(3)  # G92: logical = machine - offset
    normal = np.array([0.0, 0.0, 1.0])
    e_logical = 0.0
    feed = 0.0
    scale = 1.0  # G20 inch -> mm
    rel_xyz = rel_e = False
    speed_factor = flow_factor = 1.0
    tool = 0
    layer_marked = False
    layer = 0
    rows: list[tuple] = []
    normals_seen = False
    events: list[Event] = []
    warnings: list[str] = []

    def fail(lineno: int, message: str) -> None:
        if not lenient:
            raise CurvsliceError(f"{source}, line {lineno}: {message} (use --lenient to skip such lines)")
        warnings.append(f"{source}, line {lineno}: {message}; line skipped")

    for lineno, raw in enumerate(text.removeprefix("\ufeff").splitlines(), start=1):
        if mark := _LAYER_MARK.match(raw):
            layer_marked = True
            layer = int(mark[1]) if mark[1] is not None else layer + 1
            continue
        code = _strip(raw)
        if not code:
            continue
        if problem := _checksum_error(raw):
            fail(lineno, problem)
            continue
        try:
            commands = _commands(code)
        except ValueError as exc:
            fail(lineno, f"malformed G-code {code if len(code) <= 60 else code[:60] + '…'!r}: {exc}")
            continue
        unknown = [c for c, _, _ in commands if not _known(c)]
        if unknown:
            arcs = unknown[0] in ("G2", "G3")
            fail(lineno, f"unknown command {unknown[0]}" + (" (arcs: turn off arc fitting in the slicer)" if arcs else ""))
            continue
        bad = [(c, k) for c, params, _ in commands for k in params if k not in _allowed(c)]
        if bad:
            fail(lineno, f"{bad[0][0]} does not take parameter {bad[0][1]}")
            continue
        for name, params, free in commands:
            if name in ("G0", "G1"):
                vals = {k: v for k, v in params.items() if v is not None}
                if "F" in vals:
                    if vals["F"] <= 0:
                        fail(lineno, f"feed rate F{vals['F']:g} must be positive")
                        break
                    feed = vals["F"] * scale
                if not (vals.keys() & (_MOVE_WORDS - {"F"})):
                    continue  # only a feed-rate change
                target = pos.copy()
                for axis, key in enumerate("XYZ"):
                    if key in vals:
                        v = vals[key] * scale
                        target[axis] = pos[axis] + v if rel_xyz else v + offset[axis]
                if vals.keys() & {"nX", "nY", "nZ"}:
                    normals_seen = True
                    n = np.array([vals.get(k, normal[i]) for i, k in enumerate(("nX", "nY", "nZ"))])
                    length = np.linalg.norm(n)
                    if length < 0.5:
                        fail(lineno, f"tool orientation ({n[0]:g}, {n[1]:g}, {n[2]:g}) is not a unit vector")
                        break
                    normal = n / length
                de = 0.0
                if "E" in vals:
                    e = vals["E"] * scale
                    de = e if rel_e else e - e_logical
                    e_logical = e_logical + e if rel_e else e
                pos = target
                rows.append((*pos, *normal, feed * speed_factor, de * flow_factor, name == "G0", False, tool, layer, lineno))
            elif name == "G28":
                axes = [i for i, k in enumerate("XYZ") if k in params] or [0, 1, 2]
                pos = pos.copy()
                pos[axes] = home_pos[axes]
                offset[axes] = 0.0
                rows.append((*pos, *normal, feed * speed_factor, 0.0, False, True, tool, layer, lineno))
            elif name == "G92":
                for axis, key in enumerate("XYZ"):
                    if params.get(key) is not None:
                        offset[axis] = pos[axis] - params[key] * scale
                    elif key in params:
                        offset[axis] = pos[axis]
                if "E" in params:
                    e_logical = (params["E"] or 0.0) * scale
                if not params:
                    offset = pos.copy()
                    e_logical = 0.0
            elif name in ("G20", "G21"):
                scale = 25.4 if name == "G20" else 1.0
            elif name in ("G90", "G91"):
                rel_xyz = rel_e = name == "G91"
            elif name in ("M82", "M83"):
                rel_e = name == "M83"
            elif name in ("M220", "M221"):
                percent = params.get("S")
                if percent is None or percent <= 0:
                    fail(lineno, f"{name} needs a positive S percentage")
                    break
                if name == "M220":
                    speed_factor = percent / 100.0
                else:
                    flow_factor = percent / 100.0
                events.append(Event(len(rows), lineno, name, {"S": percent}, ""))
            else:  # G4, T, and recorded events
                if name.startswith("T"):
                    tool = int(name[1:])
                if name == "G4":
                    p = params.get("P") or 0.0
                    s = params.get("S") or 0.0
                    params = {"seconds": s + p / 1000.0}
                events.append(Event(len(rows), lineno, name, {k: v for k, v in params.items() if v is not None}, free))

    data = np.array([r[:12] for r in rows], dtype=np.float64).reshape(-1, 12)
    extruding = data[:, 7] > 0
    if layer_marked:
        layers = data[:, 11].astype(np.int32)
    else:
        layers = np.zeros(len(data), np.int32)
        z_ext = data[extruding, 2]
        change = np.zeros(len(z_ext), bool)
        change[1:] = z_ext[1:] != z_ext[:-1]
        layers[extruding] = np.cumsum(change) + 1
        layers = np.maximum.accumulate(layers) if len(layers) else layers
        layers[layers == 0] = 1
    return GcodeProgram(
        positions=data[:, 0:3].copy(),
        normals=data[:, 3:6].copy() if normals_seen else None,
        feed=data[:, 6].copy(),
        extrusion=data[:, 7].copy(),
        rapid=data[:, 8].astype(bool),
        home=data[:, 9].astype(bool),
        tool=data[:, 10].astype(np.int32),
        layer=layers,
        line=np.array([r[12] for r in rows], dtype=np.int32),
        start=np.asarray(home, dtype=np.float64),
        source=source,
        events=events,
        warnings=warnings,
    )


def _known(name: str) -> bool:
    return name in _STATE_CODES or name in EVENT_CODES or re.fullmatch(r"T\d+", name) is not None


def _allowed(name: str) -> set[str]:
    return _STATE_CODES.get(name) or EVENT_CODES.get(name) or set()


#: Commands that change the modal state (or move), with their parameters.
_STATE_CODES: dict[str, set[str]] = {
    "G0": _MOVE_WORDS, "G1": _MOVE_WORDS, "G4": {"P", "S"}, "G20": set(), "G21": set(),
    "G28": {"X", "Y", "Z", "W"}, "G90": set(), "G91": set(), "G92": {"X", "Y", "Z", "E"},
    "M82": set(), "M83": set(), "M220": {"S"}, "M221": {"S", "T"},
}


def read_gcode(path: str | Path, *, lenient: bool = False, home: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> GcodeProgram:
    """Read a G-code file (see :func:`parse_gcode`)."""
    path = Path(path)
    if not path.is_file():
        raise CurvsliceError(f"G-code file {path} does not exist")
    return parse_gcode(read_text(path, "G-code"), source=str(path), lenient=lenient, home=home)
