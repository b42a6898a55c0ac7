"""The robot workcell: a fixed nozzle, a robot holding the platform, and the frames of Eq. 2.3.

Frames (thesis §2.5, Fig. 2.7; §3.5.3): B the robot base (URDF root), E the flange (``tool0``),
P the platform = model frame (Z up, platform top at z = 0), O the deposition frame at a waypoint
(origin c_j, z axis t_j pointing from the part towards the nozzle), N the nozzle frame (origin at
the nozzle tip, z axis along the nozzle towards the extruder body). A waypoint is printed when

    T_E^B  T_P^E  T_O^P = T_N^B            (Eq. 2.3)

so the flange pose is T_E^B = T_N^B (T_O^P)^-1 (T_P^E)^-1. The rotation θ of O about t_j is free
(Eq. 4.3); :func:`flange_poses` samples p values of it uniformly in [-π, π).

Workcell file (JSON; lengths in mm, angles in degrees, as a person edits it)::

    {
      "name": "ur5-default",
      "robot": "ur5",                                  # ur3 | ur5 | ur10 | irb120
      "nozzle": {"xyz_mm": [x, y, z], "rpy_deg": [r, p, y]},          # T_N^B
      "platform_mount": {"xyz_mm": [...], "rpy_deg": [...]},          # T_P^E
      "platform": {"radius_mm": 64, "thickness_mm": 21},              # disc under z = 0 in P
      "extruder": [body, ...],        # bodies in the nozzle frame N (the tip itself is free)
      "obstacles": [body, ...],       # bodies in the base frame B (table, frame posts)
      "joint_limits_deg": {"lower": [...6], "upper": [...6]},        # optional, narrows the URDF's
      "max_joint_speed_rad_s": 1.0,   # ξ of §3.5.3
      "max_joint_acceleration_rad_s2": 3.0,   # a_max of Eq. 4.2, one number or 6 (per joint)
      "max_joint_jerk_rad_s3": 15.0,          # j_max of Eq. 4.2, one number or 6 (per joint)
      "linear_speed_mm_s": 10.0,      # v̄ of §3.5.3 (used when the tool-path gives no feed)
      "travel_speed_mm_s": 50.0,      # jumps between paths
      "min_step_time_s": 0.008,       # floor on Δt (one controller cycle) for coincident waypoints
      "tool_turn_speed_deg_s": 30.0,  # ω̄: the tool axis turns at most this fast (0 = no limit)
      "rotations": 30,                # p of §3.5.3 / n of Eq. 4.3
      "max_axis_deviation_deg": 20.0, # a waypoint may tilt its tool axis this far (0 = never)
      "axis_deviation_step_deg": 2.5, # ... searched in steps of this size
      "axis_smoothing_mm": 2.5        # σ of the robot's low-pass of the tool axis along a path (0 = none)
    }

Acceleration and jerk limits (Eq. 4.2, §4.3.2): neither Universal Robots (UR3/UR5/UR10 CB3 and
e-Series datasheets and user manuals) nor ABB (IRB120 product specification) publish per-joint
maximum joint accelerations or jerks; the datasheets give joint speeds only (URScript's own
``movej`` default is a = 1.4 rad/s²). The shipped workcells therefore use the conservative bounds
a_max = 3 rad/s² and j_max = 15 rad/s³ on every joint (the bounds set for this project in issue
19); a cell with measured limits states its own. Every row inside a motion segment meets them
(:mod:`curvslice.jerk`), and ``curvslice verify`` re-derives both from ``joints.csv``.

Axis deviation: a waypoint whose planned orientation t_j has no collision-free pose (all p rotations ×
all IK branches collide, typically the heater block meeting the platform at steep tilts next to it)
may instead be printed about the same contact point with an axis tilted by at most
``max_axis_deviation_deg`` from t_j, searched in rings of ``axis_deviation_step_deg`` (towards the
vertical first). The thesis already low-passes orientations (§3.5.2), so a small bounded deviation
keeps the deposition physically valid; every deviation is recorded in ``joints.csv`` and
``report.json`` and the bound is checked by the verifier.

Step times: Δt_j = max(‖c_{j+1} − c_j‖ / v̄, ∠(t_j, t_{j+1}) / ω̄, min_step). The thesis uses the
first term only (§3.5.3); with tool-paths whose orientation turns up to 10° between samples
(§3.5.2's low-pass threshold) that forces a motion split at almost every crest, so the arm is
instead given time to turn the tool (ω̄ = 0 restores the thesis's timing). Neighbouring steps of one
path then differ by at most 1.3x (:func:`curvslice.motion.ramp_steps`): the feed ramps down to a slow
step and back up, as a controller's look-ahead does.

Axis smoothing: the tool-path's orientation (Eq. 3.3, the closest point on the faceted layer below)
jitters from sample to sample below the 10° of the thesis's low-pass (bunny 1.0: median 6° between
samples 0.55 mm apart, a quarter of the turns reversing the one before). The arm would turn the tool
back and forth at ω̄ and ξ: on bunny layers 60-67 that made the print 2.0x longer than with the axis
low-passed over σ = 1 mm, and the graph search slower. The robot therefore follows the axis
Gaussian-filtered along each path over arc length (σ = ``axis_smoothing_mm``), moved at most half of
``max_axis_deviation_deg`` from the tool-path's own (:func:`curvslice.orientation.smooth_along_paths`);
like every deviation it is recorded in ``joints.csv`` and bounded by the verifier. 0 turns it off.
σ = 2.5 mm (about two beads): a symmetric kernel keeps a steady turn of the surface's normal and removes
the jitter (bunny 1.0: the 1 mm and 2.5 mm axes differ by 3.4° median). Measured on the whole bunny 1.0 and
kitten 0.8 against σ = 1 mm (same tool-paths): total squared jerk after the jerk stage -40 % / -31 %,
print time -6 % / -7 %, robot stage CPU -8 % / -4 %; on bunny layers 9-24, 60-67, 100-104, σ = 4 mm
lowered J by 11 % more but the print took 4 % longer and the search more checks than at 2.5.

A body is ``{"name": str, "type": "box", "size_mm": [sx, sy, sz], "xyz_mm": [...], "rpy_deg": [...]}``
or ``{"name": str, "type": "cylinder" | "cone", "radius_mm": r, "length_mm": h, "xyz_mm": [...], "rpy_deg": [...]}``
(centred on its pose, axis = its z; a cone's apex is at +h/2, so a nozzle tip pointing down is a
cone turned by rpy [180, 0, 0]).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from curvslice.errors import CurvsliceError
from curvslice.kinematics import ROBOT_NAMES, Robot, rigid_inverse
from curvslice.validate import check_number


@dataclass(frozen=True)
class Body:
    """A box or cylinder obstacle, centred on ``pose`` (4x4, mm); cylinder axis = local z."""

    name: str
    kind: str  # "box" | "cylinder" | "cone"
    dims: tuple[float, ...]  # box (sx, sy, sz) | cylinder or cone (radius, length), mm
    pose: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class Workcell:
    """A fixed-nozzle cell (Eq. 2.3). Matrices are 4x4 in mm; speeds in mm/s and rad/s."""

    name: str
    robot: str
    nozzle: np.ndarray = field(repr=False)  # T_N^B
    platform_mount: np.ndarray = field(repr=False)  # T_P^E
    platform_radius: float = 64.0
    platform_thickness: float = 21.0
    extruder: tuple[Body, ...] = ()
    obstacles: tuple[Body, ...] = ()
    joint_lower: np.ndarray | None = field(default=None, repr=False)
    joint_upper: np.ndarray | None = field(default=None, repr=False)
    max_joint_speed: float = 1.0
    max_joint_acceleration: tuple[float, ...] = (3.0,) * 6  # rad/s², per joint (Eq. 4.2)
    max_joint_jerk: tuple[float, ...] = (15.0,) * 6  # rad/s³, per joint (Eq. 4.2)
    linear_speed: float = 10.0
    travel_speed: float = 50.0
    min_step_time: float = 0.008
    tool_turn_speed: float = np.radians(30.0)  # rad/s; 0 = no limit
    rotations: int = 30
    max_axis_deviation: float = np.radians(20.0)  # rad; 0 = waypoints keep their planned axis
    axis_deviation_step: float = np.radians(2.5)  # rad
    axis_smoothing: float = 2.5  # mm, σ of the tool axis's low-pass along a path; 0 = the tool-path's axis

    def limits(self, robot: Robot) -> tuple[np.ndarray, np.ndarray]:
        """Joint limits (rad): the URDF's, narrowed by the workcell's own when given."""
        lo, hi = robot.lower.copy(), robot.upper.copy()
        if self.joint_lower is not None:
            lo = np.maximum(lo, self.joint_lower)
        if self.joint_upper is not None:
            hi = np.minimum(hi, self.joint_upper)
        return lo, hi

    def with_rotations(self, rotations: int) -> Workcell:
        if rotations < 1:
            raise CurvsliceError(f"--rotations must be at least 1 (got {rotations})")
        return replace(self, rotations=int(rotations))


def pose_matrix(xyz_mm, rpy_deg) -> np.ndarray:
    """4x4 pose from a translation (mm) and fixed-axis roll-pitch-yaw (degrees, URDF order)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix()
    T[:3, 3] = xyz_mm
    return T


def _pose_dict(T: np.ndarray) -> dict[str, list[float]]:
    with warnings.catch_warnings():  # at ±90° pitch any roll/yaw split is exact; scipy warns anyway
        warnings.simplefilter("ignore", UserWarning)
        rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True)
    return {"xyz_mm": [round(float(v), 9) for v in T[:3, 3]], "rpy_deg": [round(float(v), 9) for v in rpy]}


def _vector(spec: dict, key: str, n: int, where: str) -> list[float]:
    value = spec.get(key, [0.0] * n)
    if not (isinstance(value, list) and len(value) == n and all(isinstance(v, (int, float)) for v in value)):
        raise CurvsliceError(f"workcell {where}: '{key}' must be a list of {n} numbers")
    return [check_number(v, f"workcell {where}: '{key}'[{i}]") for i, v in enumerate(value)]


def _pose(spec: dict, where: str) -> np.ndarray:
    if not isinstance(spec, dict):
        raise CurvsliceError(f"workcell: '{where}' must be an object with xyz_mm and rpy_deg")
    return pose_matrix(_vector(spec, "xyz_mm", 3, where), _vector(spec, "rpy_deg", 3, where))


def _body(spec: dict, where: str) -> Body:
    name = str(spec.get("name", where))
    kind = spec.get("type")
    if kind == "box":
        dims = tuple(_vector(spec, "size_mm", 3, name))
    elif kind in ("cylinder", "cone"):
        dims = tuple(check_number(spec.get(k, 0), f"workcell body '{name}': '{k}'", "mm") for k in ("radius_mm", "length_mm"))
    else:
        raise CurvsliceError(f"workcell body '{name}': type must be 'box', 'cylinder' or 'cone' (got {kind!r})")
    if min(dims) <= 0:
        raise CurvsliceError(f"workcell body '{name}': sizes must be positive (got {list(dims)})")
    return Body(name, kind, dims, _pose(spec, name))


def _body_dict(body: Body) -> dict[str, object]:
    out: dict[str, object] = {"name": body.name, "type": body.kind}
    if body.kind == "box":
        out["size_mm"] = list(body.dims)
    else:
        out["radius_mm"], out["length_mm"] = body.dims
    out.update(_pose_dict(body.pose))
    return out


#: Scalar keys of the workcell JSON: (lowest, lowest excluded, highest, unit); NaN, inf and text are refused.
_SCALARS: dict[str, tuple[float, bool, float | None, str]] = {
    "max_joint_speed_rad_s": (0, True, None, "rad/s"), "linear_speed_mm_s": (0, True, None, "mm/s"),
    "travel_speed_mm_s": (0, True, None, "mm/s"), "min_step_time_s": (0, True, None, "s"),
    "tool_turn_speed_deg_s": (0, False, None, "deg/s"), "rotations": (1, False, 3600, "rotations"),
    "max_axis_deviation_deg": (0, False, 89.999, "degrees"), "axis_deviation_step_deg": (0, True, 90, "degrees"),
    "axis_smoothing_mm": (0, False, None, "mm"),
}


def _per_joint(spec: dict, key: str, default: float, source: str) -> tuple[float, ...]:
    """A positive per-joint bound given as one number or a list of 6."""
    value = spec.get(key, default)
    values = [value] * 6 if isinstance(value, (int, float)) else value
    if not (isinstance(values, list) and len(values) == 6 and all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < float("inf") for v in values)):
        raise CurvsliceError(f"{source}: '{key}' must be a finite positive number or a list of 6 of them")
    return tuple(float(v) for v in values)


def workcell_from_dict(spec: dict, source: str = "workcell") -> Workcell:
    """Validate and build a :class:`Workcell` from its JSON object (see the module docstring)."""
    for key, (lo, lo_open, hi, unit) in _SCALARS.items():
        if key in spec:
            check_number(spec[key], f"{source}: '{key}'", unit, lo=lo, lo_open=lo_open, hi=hi, integer=key == "rotations")
    platform = spec.get("platform", {})
    if not isinstance(platform, dict):
        raise CurvsliceError(f"{source}: 'platform' must be an object with radius_mm and thickness_mm")
    for key in ("radius_mm", "thickness_mm"):
        if key in platform:
            check_number(platform[key], f"{source}: 'platform.{key}'", "mm", lo=0, lo_open=True)
    robot = str(spec.get("robot", "")).lower()
    if robot not in ROBOT_NAMES:
        raise CurvsliceError(f"{source}: 'robot' must be one of {', '.join(ROBOT_NAMES)} (got {robot!r})")
    if "nozzle" not in spec:
        raise CurvsliceError(f"{source}: 'nozzle' pose (T_N^B) is required")
    platform = spec.get("platform", {})
    limits = spec.get("joint_limits_deg")
    lower = upper = None
    if limits is not None:
        lower = np.radians(_vector(limits, "lower", 6, "joint_limits_deg"))
        upper = np.radians(_vector(limits, "upper", 6, "joint_limits_deg"))
        if np.any(lower >= upper):
            raise CurvsliceError(f"{source}: joint_limits_deg lower must be below upper for every joint")
    cell = Workcell(
        name=str(spec.get("name", robot)),
        robot=robot,
        nozzle=_pose(spec["nozzle"], "nozzle"),
        platform_mount=_pose(spec.get("platform_mount", {}), "platform_mount"),
        platform_radius=float(platform.get("radius_mm", 64.0)),
        platform_thickness=float(platform.get("thickness_mm", 21.0)),
        extruder=tuple(_body(b, f"extruder[{i}]") for i, b in enumerate(spec.get("extruder", []))),
        obstacles=tuple(_body(b, f"obstacles[{i}]") for i, b in enumerate(spec.get("obstacles", []))),
        joint_lower=lower,
        joint_upper=upper,
        max_joint_speed=float(spec.get("max_joint_speed_rad_s", 1.0)),
        max_joint_acceleration=_per_joint(spec, "max_joint_acceleration_rad_s2", 3.0, source),
        max_joint_jerk=_per_joint(spec, "max_joint_jerk_rad_s3", 15.0, source),
        linear_speed=float(spec.get("linear_speed_mm_s", 10.0)),
        travel_speed=float(spec.get("travel_speed_mm_s", 50.0)),
        min_step_time=float(spec.get("min_step_time_s", 0.008)),
        tool_turn_speed=float(np.radians(spec.get("tool_turn_speed_deg_s", 30.0))),
        rotations=int(spec.get("rotations", 30)),
        max_axis_deviation=float(np.radians(spec.get("max_axis_deviation_deg", 20.0))),
        axis_deviation_step=float(np.radians(spec.get("axis_deviation_step_deg", 2.5))),
        axis_smoothing=float(spec.get("axis_smoothing_mm", 2.5)),
    )
    if not 0 <= cell.max_axis_deviation < np.pi / 2:
        raise CurvsliceError(f"{source}: 'max_axis_deviation_deg' must be in [0, 90)")
    if cell.tool_turn_speed < 0:
        raise CurvsliceError(f"{source}: 'tool_turn_speed_deg_s' must be 0 (no limit) or positive")
    for key in ("max_joint_speed", "linear_speed", "travel_speed", "min_step_time", "rotations", "axis_deviation_step"):
        if getattr(cell, key) <= 0:
            raise CurvsliceError(f"{source}: '{key}' must be positive")
    return cell


def workcell_to_dict(cell: Workcell) -> dict[str, object]:
    """The JSON object of a workcell (inverse of :func:`workcell_from_dict`)."""
    out: dict[str, object] = {
        "name": cell.name,
        "robot": cell.robot,
        "nozzle": _pose_dict(cell.nozzle),
        "platform_mount": _pose_dict(cell.platform_mount),
        "platform": {"radius_mm": cell.platform_radius, "thickness_mm": cell.platform_thickness},
        "extruder": [_body_dict(b) for b in cell.extruder],
        "obstacles": [_body_dict(b) for b in cell.obstacles],
    }
    if cell.joint_lower is not None and cell.joint_upper is not None:
        out["joint_limits_deg"] = {
            "lower": [round(float(v), 9) for v in np.degrees(cell.joint_lower)],
            "upper": [round(float(v), 9) for v in np.degrees(cell.joint_upper)],
        }
    out.update(
        max_joint_speed_rad_s=cell.max_joint_speed,
        max_joint_acceleration_rad_s2=list(cell.max_joint_acceleration),
        max_joint_jerk_rad_s3=list(cell.max_joint_jerk),
        linear_speed_mm_s=cell.linear_speed,
        travel_speed_mm_s=cell.travel_speed,
        min_step_time_s=cell.min_step_time,
        tool_turn_speed_deg_s=round(float(np.degrees(cell.tool_turn_speed)), 9),
        rotations=cell.rotations,
        max_axis_deviation_deg=round(float(np.degrees(cell.max_axis_deviation)), 9),
        axis_deviation_step_deg=round(float(np.degrees(cell.axis_deviation_step)), 9),
        axis_smoothing_mm=cell.axis_smoothing,
    )
    return out


def load_workcell(spec: str | Path) -> Workcell:
    """A shipped workcell by robot name (``ur5``, ``ur3``, ``ur10``, ``irb120``) or a JSON file."""
    text: str
    key = str(spec).lower()
    if key in ROBOT_NAMES:
        text = resources.files("curvslice").joinpath("data", f"workcell_{key}.json").read_text()
        source = f"workcell_{key}.json"
    else:
        path = Path(spec)
        if not path.is_file():
            raise CurvsliceError(f"--robot {spec}: neither a robot name ({', '.join(ROBOT_NAMES)}) nor a workcell file")
        text, source = path.read_text(), str(path)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CurvsliceError(f"{source} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise CurvsliceError(f"{source} must hold a JSON object")
    return workcell_from_dict(data, source)


def save_workcell(cell: Workcell, path: Path) -> None:
    """Write the workcell as JSON (``workcell.json`` beside the robot programs)."""
    Path(path).write_text(json.dumps(workcell_to_dict(cell), indent=2) + "\n")


def deposition_frames(positions: np.ndarray, normals: np.ndarray, thetas: np.ndarray) -> np.ndarray:
    """T_O^P (n, p, 4, 4): origin c_j, z = t_j, turned by each θ about t_j (Eq. 4.3).

    The θ = 0 frame is the minimal rotation taking +Z to t_j, so it varies smoothly along a path.
    """
    t = np.asarray(normals, float)
    t = t / np.linalg.norm(t, axis=1, keepdims=True)
    # Rodrigues' minimal rotation z -> t: R = I + [v]x + [v]x^2 / (1 + c), v = z x t, c = z.t
    c = t[:, 2]
    if np.any(c <= -1 + 1e-9):
        raise CurvsliceError("a tool orientation points straight down (-Z): no nozzle can reach it")
    v = np.stack([-t[:, 1], t[:, 0], np.zeros(len(t))], axis=1)
    K = np.zeros((len(t), 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -v[:, 2], v[:, 1]
    K[:, 1, 0], K[:, 1, 2] = v[:, 2], -v[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -v[:, 1], v[:, 0]
    R0 = np.eye(3) + K + K @ K / (1.0 + c)[:, None, None]
    th = np.asarray(thetas, float)
    Rz = np.zeros((len(th), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1] = np.cos(th), -np.sin(th), np.sin(th), np.cos(th)
    Rz[:, 2, 2] = 1.0
    out = np.zeros((len(t), len(th), 4, 4))
    out[..., :3, :3] = R0[:, None] @ Rz[None]
    out[..., :3, 3] = np.asarray(positions, float)[:, None]
    out[..., 3, 3] = 1.0
    return out


def rotation_samples(p: int) -> np.ndarray:
    """p angles θ uniformly spaced in [-π, π) (Eq. 4.3)."""
    return -np.pi + 2 * np.pi * np.arange(p) / p


def flange_poses(cell: Workcell, positions: np.ndarray, normals: np.ndarray, p: int) -> np.ndarray:
    """Flange poses T_E^B (n, p, 4, 4) realizing each waypoint at the nozzle tip (Eq. 2.3)."""
    T_OP = deposition_frames(positions, normals, rotation_samples(p))
    return cell.nozzle @ rigid_inverse(T_OP) @ rigid_inverse(cell.platform_mount)


def waypoints_from_flange(cell: Workcell, flange: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of Eq. 2.3: the nozzle tip and axis expressed in the model frame P, per flange pose.

    Returns positions (n, 3) mm and unit tool orientations (n, 3) (from the part to the nozzle).
    """
    T_NP = rigid_inverse(np.asarray(flange, float) @ cell.platform_mount) @ cell.nozzle
    return T_NP[..., :3, 3], T_NP[..., :3, 2]
