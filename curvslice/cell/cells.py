"""Print-cell description for ``curvslice convert``: how planar G-code maps onto a robot.

A *cell* is what seeds 003 (Adept Python, V+), 004 (ABB IRB 120,
RAPID) and 000 (ABB IRB 120) hard-coded in their converters: the position offset from G-code to
robot coordinates, workspace limits, the fixed nozzle orientation, and the I/O each controller
uses for the extruder (V+ signals and the Arduino sketch of seed 003, the speed bits and
retraction output of seed 004, a UR digital output).

A cell file is JSON with any of the keys of :class:`Cell` (lengths mm, speeds mm/s, orientation as
a unit quaternion ``[w, x, y, z]`` of the tool for a vertical nozzle) and sections ``rapid``,
``vplus``, ``syringe``, ``urscript`` with the keys of their dataclasses; ``--cell`` also accepts
the names in :data:`PRESETS`.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from curvslice.cell.gcode import GcodeProgram
from curvslice.errors import CurvsliceError
from curvslice.robot_path import RobotPath
from curvslice.validate import Range, check_fields, read_text


@dataclass(frozen=True)
class RapidIO:
    """ABB controller names and I/O (seed 004: DSQC 652, speed on DO10-DO16, retraction on DO9)."""

    tool: str = "tool0"
    wobj: str = "wobj0"
    robconf: tuple[int, int, int, int] = (0, 0, 0, 0)
    zone: str = "z1"
    speed_outputs: tuple[str, ...] = ()  # most significant bit first; empty = no speed encoding
    speed_unit: float = 1.0  # mm/s per count of the speed word
    retract_output: str | None = None
    extruder_output: str | None = "doExtruder"  # on/off output; None when the speed word says it
    load_dir: str = "HOME:/"
    max_targets: int = 7000


@dataclass(frozen=True)
class VplusIO:
    """Adept SmartController outputs (seed 003): each (extruder, speed) gets a binary pattern."""

    signals: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 7, 8)
    max_signals: int = 8
    motion: str = "MOVE"  # MOVE (joint-interpolated; straight on a Cartesian robot) or MOVES


@dataclass(frozen=True)
class Syringe:
    """Plunger extruder and its Arduino wiring (seed 003: RAMPS 1.4, linear stepper actuator)."""

    nozzle_to_syringe_radius: float = 0.052
    inch_per_step: float = 0.000125
    input_pins: tuple[int, ...] = (16, 17, 23, 25, 27, 29, 31, 33)  # Arduino pins wired to signals 1, 2, …
    motor_pins: tuple[tuple[int, int, int], ...] = ((26, 28, 24), (36, 34, 30))  # (step, dir, enable) per extruder
    max_steps_per_second: float = 1000.0


@dataclass(frozen=True)
class UrIO:
    """Universal Robots outputs and motion parameters."""

    extruder_output: int = 0
    retract_output: int | None = None
    blend: float = 0.5  # mm
    acceleration: float = 1200.0  # mm/s²


@dataclass(frozen=True)
class Cell:
    """How G-code coordinates, speeds and extrusion map onto one robot cell."""

    name: str = "generic"
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # added to every G-code position
    workspace_min: tuple[float, float, float] = (-np.inf, -np.inf, -np.inf)  # robot frame, after offset
    workspace_max: tuple[float, float, float] = (np.inf, np.inf, np.inf)
    workspace_policy: str = "error"  # "error" refuses an outside move, "warn" reports it
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 0.0)  # tool for a vertical nozzle
    use_normals: bool = True  # tilt the tool to the file's nX nY nZ when it has them
    home: tuple[float, float, float] = (0.0, 0.0, 0.0)  # G28 target, G-code coordinates
    max_speed: float = 250.0  # mm/s: G28 and moves without F; faster moves are capped
    rapid: RapidIO = field(default_factory=RapidIO)
    vplus: VplusIO = field(default_factory=VplusIO)
    syringe: Syringe = field(default_factory=Syringe)
    urscript: UrIO = field(default_factory=UrIO)


_SQRT_HALF = float(np.sqrt(0.5))

#: Built-in cells from the seeds. Workspace limits are only set where the seed gives them.
PRESETS: dict[str, dict] = {
    "generic": {},
    # seed 003: Adept Python (Cartesian), G-code already in robot coordinates, TRANS(x,y,z,0,180,0)
    "heuser-adept-python": {
        "name": "heuser-adept-python",
        "vplus": {"signals": [1, 2, 3, 4, 5, 6, 7, 8], "max_signals": 8, "motion": "MOVE"},
        "syringe": {"nozzle_to_syringe_radius": 0.052, "inch_per_step": 0.000125},
    },
    # seed 004: ABB IRB 120 printing on a Neptune 2S bed (220 x 220 x 250 mm) in work object PrintBed
    "huygens-irb120": {
        "name": "huygens-irb120",
        "workspace_min": [0.0, 0.0, 0.0],
        "workspace_max": [220.0, 220.0, 250.0],
        "orientation": [0.0, _SQRT_HALF, -_SQRT_HALF, 0.0],
        "max_speed": 150.0,
        "rapid": {
            "tool": "Hemera",
            "wobj": "PrintBed",
            "zone": "z1",
            "speed_outputs": [f"D652_10_DO{i}" for i in range(10, 17)],
            "retract_output": "D652_10_DO9",
            "extruder_output": None,
        },
    },
    "ur5": {"name": "ur5", "workspace_min": [-850.0, -850.0, -200.0], "workspace_max": [850.0, 850.0, 1000.0]},
}


_POSITIVE = (0.0, None, True)
#: Numeric ranges of the cell file's keys (lo, hi, lo excluded, unit); other numbers need only be finite.
_RANGES: dict[type, dict[str, Range]] = {
    Cell: {"max_speed": (*_POSITIVE, "mm/s"), "offset": (None, None, False, "mm"), "home": (None, None, False, "mm"),
           "workspace_min": (None, None, False, "mm"), "workspace_max": (None, None, False, "mm")},
    RapidIO: {"speed_unit": (*_POSITIVE, "mm/s per count"), "max_targets": (1, 10**6, False, "targets"),
              "robconf": (-8, 8, False, "")},
    VplusIO: {"signals": (1, 4096, False, "signal number"), "max_signals": (1, 64, False, "signals")},
    Syringe: {"nozzle_to_syringe_radius": (*_POSITIVE, ""), "inch_per_step": (*_POSITIVE, "inch"),
              "input_pins": (0, 255, False, "pin"), "motor_pins": (0, 255, False, "pin"),
              "max_steps_per_second": (*_POSITIVE, "steps/s")},
    UrIO: {"extruder_output": (0, 255, False, "output"), "retract_output": (0, 255, False, "output"),
           "blend": (0.0, None, False, "mm"), "acceleration": (*_POSITIVE, "mm/s²")},
}


def _build(kind: type, values: dict, where: str):
    names = {f.name: f for f in dataclasses.fields(kind)}
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise CurvsliceError(f"{where}: unknown key {unknown[0]!r} (valid: {', '.join(sorted(names))})")
    sections = {"rapid", "vplus", "syringe", "urscript"} if kind is Cell else set()
    check_fields(kind, {k: v for k, v in values.items() if k not in sections}, where, _RANGES.get(kind),
                 infinite_ok=frozenset({"workspace_min", "workspace_max"}))
    out = {}
    for key, value in values.items():
        sub = {"rapid": RapidIO, "vplus": VplusIO, "syringe": Syringe, "urscript": UrIO}.get(key)
        if sub is not None and kind is Cell:
            if not isinstance(value, dict):
                raise CurvsliceError(f"{where}: section {key!r} must be an object")
            out[key] = _build(sub, value, f"{where}.{key}")
        elif isinstance(value, list):
            out[key] = tuple(tuple(v) if isinstance(v, list) else v for v in value)
        else:
            out[key] = value
    return kind(**out)


def cell_from_dict(spec: dict, source: str = "cell") -> Cell:
    """A :class:`Cell` from a JSON-like dict, with its values checked."""
    cell = _build(Cell, spec, source)
    if cell.workspace_policy not in ("error", "warn"):
        raise CurvsliceError(f"{source}: workspace_policy must be 'error' or 'warn', not {cell.workspace_policy!r}")
    if np.any(np.asarray(cell.workspace_min, float) >= np.asarray(cell.workspace_max, float)):
        raise CurvsliceError(f"{source}: workspace_min must be below workspace_max on every axis")
    q = np.asarray(cell.orientation, float)
    if q.shape != (4,) or not np.isclose(np.linalg.norm(q), 1.0, atol=1e-6):
        raise CurvsliceError(f"{source}: orientation must be a unit quaternion [w, x, y, z]")
    if cell.max_speed <= 0:
        raise CurvsliceError(f"{source}: max_speed must be positive")
    if cell.vplus.motion not in ("MOVE", "MOVES"):
        raise CurvsliceError(f"{source}: vplus.motion must be MOVE or MOVES")
    return cell


def load_cell(spec: str | Path) -> Cell:
    """A preset name from :data:`PRESETS` or the path of a JSON cell file."""
    if str(spec) in PRESETS:
        return cell_from_dict(PRESETS[str(spec)], f"preset {spec}")
    path = Path(spec)
    if not path.is_file():
        raise CurvsliceError(f"cell {spec!r} is neither a preset ({', '.join(PRESETS)}) nor a JSON file")
    try:
        data = json.loads(read_text(path, "cell file"))
    except json.JSONDecodeError as exc:
        raise CurvsliceError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, dict):
        raise CurvsliceError(f"{path}: a cell file must hold a JSON object")
    return cell_from_dict(data, str(path))


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (…, 4) quaternions (w, x, y, z)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, float), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def tool_quaternions(normals: np.ndarray, vertical: tuple[float, float, float, float]) -> np.ndarray:
    """Tool orientations (N, 4) tilting the ``vertical`` tool by the minimal rotation +Z → normal.

    For a normal of +Z this is ``vertical`` itself (the cell's fixed orientation); otherwise the
    tool axis turns with the surface normal without spinning about it (seed 000 §4.15.2).
    """
    n = np.asarray(normals, float)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    # quaternion of the rotation a -> b is [1 + a.b, a x b] normalised; a = +Z
    tilt = np.stack([1.0 + n[:, 2], -n[:, 1], n[:, 0], np.zeros(len(n))], axis=1)
    flipped = tilt[:, 0] < 1e-12  # normal = -Z: any half-turn about a horizontal axis
    tilt[flipped] = [0.0, 1.0, 0.0, 0.0]
    tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
    q = quaternion_multiply(tilt, np.asarray(vertical, float)[None])
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def check_workspace(positions: np.ndarray, cell: Cell, labels: list[str]) -> list[str]:
    """Refuse (policy ``"error"``) or report (``"warn"``) robot-frame positions outside the cell's box.

    ``labels[i]`` names row i in the message (e.g. its G-code line).
    """
    lo, hi = np.asarray(cell.workspace_min, float), np.asarray(cell.workspace_max, float)
    outside = np.any((positions < lo) | (positions > hi), axis=1)
    if not outside.any():
        return []
    i = int(np.argmax(outside))
    x, y, z = positions[i]
    message = (
        f"{labels[i]}: move to ({x:.3f}, {y:.3f}, {z:.3f}) mm is outside the workspace of cell "
        f"{cell.name!r} [{lo[0]:g}..{hi[0]:g}] x [{lo[1]:g}..{hi[1]:g}] x [{lo[2]:g}..{hi[2]:g}]"
    )
    if cell.workspace_policy == "error":
        raise CurvsliceError(message + " (adjust the cell's offset or limits)")
    return [f"{message}; {int(outside.sum())} moves outside in total"]


def robot_path(program: GcodeProgram, cell: Cell) -> tuple[RobotPath, list[str]]:
    """Map a G-code program onto the cell: offset, workspace check, orientation, speeds.

    Returns the path and warnings (capped speeds, workspace violations under ``"warn"``).
    Raises :class:`CurvsliceError` naming the first offending line for a move outside the
    workspace (policy ``"error"``) or an extruding move with no feed rate.
    """
    warnings: list[str] = []
    if len(program) == 0:
        raise CurvsliceError("the G-code has no moves to convert")
    pos = program.positions + np.asarray(cell.offset, float)
    warnings += check_workspace(pos, cell, [f"{program.source}, line {k}" for k in program.line])
    extrusion = program.extrusion
    no_feed = (program.feed <= 0) & ~program.home
    if np.any(no_feed & (extrusion > 0)):
        i = int(np.argmax(no_feed & (extrusion > 0)))
        raise CurvsliceError(f"{program.source}, line {program.line[i]}: extruding move before any feed rate F was set")
    speed = np.where(no_feed | program.home, cell.max_speed, program.feed / 60.0)
    fast = speed > cell.max_speed
    if fast.any():
        i = int(np.argmax(fast))
        warnings.append(
            f"{program.source}, line {program.line[i]}: {speed[i]:g} mm/s exceeds the cell's max_speed {cell.max_speed:g} mm/s; "
            f"{int(fast.sum())} moves capped"
        )
        speed = np.minimum(speed, cell.max_speed)
    if cell.use_normals and program.normals is not None:
        quats = tool_quaternions(program.normals, cell.orientation)
    else:
        quats = np.tile(np.asarray(cell.orientation, float), (len(pos), 1))
    path = RobotPath(
        positions=pos,
        quaternions=quats,
        speed=speed,
        extrusion=extrusion.copy(),
        tool=program.tool.copy(),
        layer=program.layer.copy(),
        line=program.line.copy(),
        home=program.home.copy(),
        events=list(program.events),
    )
    return path, warnings


def tool_normals(quaternions: np.ndarray, vertical: tuple[float, float, float, float]) -> np.ndarray:
    """Inverse of :func:`tool_quaternions`: the nozzle direction (N, 3) each orientation stands for."""
    v = np.asarray(vertical, float)
    tilt = quaternion_multiply(np.asarray(quaternions, float), v * [1, -1, -1, -1])
    w, x, y, z = np.moveaxis(tilt, -1, 0)
    n = np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def gcode6_samples(robot: RobotPath, vertical: tuple[float, float, float, float]) -> dict[str, np.ndarray]:
    """The path as extended G-code samples (thesis appendix) for :func:`write_gcode6`.

    Every move without filament starts a new path id (it is a travel: ``G0``); moves with
    filament, retractions included, continue the current path. When the first move extrudes,
    the start point (taken as its own position) is prepended as the path's first sample.
    """
    ext = robot.extrusion
    normals = tool_normals(robot.quaternions, vertical)
    rows = np.arange(len(robot))
    if len(robot) and ext[0] != 0:
        rows = np.concatenate([[0], rows])
    extrusion = ext[rows].copy()
    if len(rows) > len(robot):
        extrusion[0] = 0.0
    path_id = np.cumsum(extrusion == 0) - 1
    return {
        "positions": robot.positions[rows],
        "normals": normals[rows],
        "extrusion": extrusion,
        "feed": robot.speed[rows] * 60.0,
        "path_id": path_id.astype(np.int32),
        "layer": robot.layer[rows].astype(np.int32),
    }
