"""Robot arms of the workcell: models, forward kinematics and analytic inverse kinematics.

The thesis's cells (§2.3.1, §3.6.1, §4.5) use UR3/UR5 arms holding the platform under a fixed
nozzle, and seed 000 an ABB IRB120. Every IK pose of §3.5.3 ("an analytical inverse kinematics
solver is applied to determine all possible configurations") comes from here:

- UR3/UR5/UR10 are loaded with pinocchio from the URDFs (and collision meshes) shipped in the
  ``example-robot-data`` wheel; their closed-form IK is the offset-wrist solution of Hawkins
  (2013, "Analytic inverse kinematics for the Universal Robots UR-5/UR-10 arms"), up to 8 solutions.
- The IRB120 is built from its datasheet dimensions (290/270/70/302/72 mm, the ROS-Industrial
  joint conventions) as a generated URDF; its IK is the spherical-wrist closed form, up to 8.

Units are millimetres and radians. The base frame B of a robot is the root frame of its URDF
(``base_link``), the flange frame E is ``tool0`` (z out of the flange). Pinocchio's FK is the
reference the analytic solvers are tested against (:func:`fk_reference`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pinocchio as pin
import trimesh

from curvslice.errors import CurvsliceError

ROBOT_NAMES = ("ur3", "ur5", "ur10", "irb120")

#: Link pairs the UR SRDF of example-robot-data (``srdf/ur5.srdf``) declares never in collision.
_UR_ALLOWED_PAIRS = (
    ("base_link", "shoulder_link"),
    ("base_link", "upper_arm_link"),
    ("shoulder_link", "upper_arm_link"),
    ("upper_arm_link", "forearm_link"),
    ("forearm_link", "wrist_1_link"),
    ("forearm_link", "wrist_2_link"),
    ("forearm_link", "wrist_3_link"),
    ("wrist_1_link", "wrist_2_link"),
    ("wrist_1_link", "wrist_3_link"),
    ("wrist_2_link", "wrist_3_link"),
)

# ABB IRB120 (3 kg / 0.58 m) datasheet dimensions in metres, limits in degrees, speeds in deg/s.
_IRB120_URDF = """<?xml version="1.0"?>
<robot name="irb120">
  <link name="base_link"/>
  <link name="link_1"/><link name="link_2"/><link name="link_3"/>
  <link name="link_4"/><link name="link_5"/><link name="link_6"/><link name="tool0"/>
  {joints}
  <joint name="joint_6-tool0" type="fixed"><parent link="link_6"/><child link="tool0"/>
    <origin xyz="0 0 0" rpy="0 1.5707963267948966 0"/></joint>
</robot>"""
_IRB120_JOINTS = (  # parent, child, origin xyz (m), axis, lower/upper (deg), speed (deg/s)
    ("base_link", "link_1", (0, 0, 0), (0, 0, 1), (-165, 165), 250),
    ("link_1", "link_2", (0, 0, 0.290), (0, 1, 0), (-110, 110), 250),
    ("link_2", "link_3", (0, 0, 0.270), (0, 1, 0), (-110, 70), 250),
    ("link_3", "link_4", (0, 0, 0.070), (1, 0, 0), (-160, 160), 320),
    ("link_4", "link_5", (0.302, 0, 0), (0, 1, 0), (-120, 120), 320),
    ("link_5", "link_6", (0.072, 0, 0), (1, 0, 0), (-400, 400), 420),
)
# Approximate collision capsules (link, radius mm, end points mm in the link frame), after the
# datasheet outline drawing; adjacent links are allowed to touch.
_IRB120_CAPSULES = (
    ("base_link", 90.0, (0, 0, 100), (0, 0, 110)),
    ("link_1", 70.0, (0, 0, 170), (0, 0, 290)),
    ("link_2", 45.0, (0, 0, 0), (0, 0, 270)),
    ("link_3", 45.0, (0, 0, 0), (0, 0, 70)),
    ("link_4", 35.0, (40, 0, 0), (250, 0, 0)),
    ("link_5", 28.0, (0, 0, 0), (40, 0, 0)),
    ("link_6", 20.0, (-5, 0, 0), (0, 0, 0)),
)


@dataclass(frozen=True, eq=False)
class LinkShape:
    """One collision body of a robot: a triangle mesh (mm) fixed on a pinocchio joint frame."""

    link: str
    joint: int  # pinocchio joint index carrying it (0 = the fixed base)
    placement: np.ndarray  # (4, 4) mm, body frame in the joint frame
    mesh: trimesh.Trimesh


@dataclass(frozen=True, eq=False)
class Robot:
    """A 6-DOF arm: pinocchio model (metres), kinematic parameters (mm), limits, collision bodies."""

    name: str
    family: str  # "ur" (offset wrist) or "spherical"
    model: pin.Model
    tool_frame: int  # pinocchio frame id of the flange E (tool0)
    lower: np.ndarray  # (6,) rad
    upper: np.ndarray  # (6,) rad
    max_speed: np.ndarray  # (6,) rad/s, from the URDF
    params: dict[str, float]  # kinematic lengths in mm
    base_offset: np.ndarray  # (4, 4) base_link -> frame in which ``params`` are stated
    links: tuple[LinkShape, ...]
    allowed_pairs: frozenset[frozenset[str]]  # link pairs excluded from self-collision

    @cached_property
    def chain(self) -> tuple[tuple[int, ...], tuple[int, ...], np.ndarray]:
        """The constants of :func:`joint_placements`, read from the pinocchio model once: each
        joint's axis (0/1/2 for x/y/z), its parent joint and its placement (7, 4, 4) in mm."""
        model = self.model
        axes = tuple("XYZ".index(model.joints[j].shortname()[-1]) for j in range(1, 7))
        placements = np.stack([np.eye(4)] + [_se3(model.jointPlacements[j]) for j in range(1, 7)])
        return (0,) + axes, tuple(model.parents[j] for j in range(7)), placements

    @cached_property
    def link_frames(self) -> tuple[list[int], np.ndarray]:
        """The joint carrying each of ``links`` and the bodies' placements (L, 4, 4) on them."""
        return [s.joint for s in self.links], np.stack([s.placement for s in self.links])


def _share_dir() -> Path:
    """The cmeel prefix of the ``example-robot-data`` wheel (its URDFs and meshes)."""
    import cmeel  # installed with every cmeel wheel (pin, example-robot-data)

    base = Path(cmeel.__file__).resolve().parent.parent / "cmeel.prefix" / "share"
    if not (base / "example-robot-data").is_dir():
        raise CurvsliceError("example-robot-data is not installed (pip install example-robot-data)")
    return base


def _rot(axis: int, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about x/y/z (axis 0/1/2), vectorized over ``angle`` -> (..., 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(np.shape(angle) + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def _se3(model_placement: pin.SE3) -> np.ndarray:
    out = model_placement.homogeneous.copy()
    out[:3, 3] *= 1000.0
    return out


def _ur_robot(name: str) -> Robot:
    share = _share_dir()
    urdf = share / "example-robot-data" / "robots" / "ur_description" / "urdf" / f"{name}_robot.urdf"
    model = pin.buildModelFromUrdf(str(urdf))
    geom = pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.COLLISION, package_dirs=[str(share)])
    jp = [model.jointPlacements[i].translation * 1000.0 for i in range(model.njoints)]
    tool = model.getFrameId("tool0")
    params = {
        "d1": jp[1][2],
        "a2": -jp[3][2],
        "a3": -jp[4][2],
        "d4": jp[2][1] + jp[3][1] + jp[5][1],
        "d5": jp[6][2],
        "d6": model.frames[tool].placement.translation[1] * 1000.0,
    }
    links = []
    for obj in geom.geometryObjects:
        if not obj.meshPath.lower().endswith(".stl"):
            continue  # the 1 cm ee_link marker box carries no material
        mesh = trimesh.load(obj.meshPath, force="mesh")
        mesh.apply_scale(1000.0)
        link = model.frames[obj.parentFrame].name
        links.append(LinkShape(link, int(obj.parentJoint), _se3(obj.placement), mesh))
    base = np.diag([-1.0, -1.0, 1.0, 1.0])  # ROS base_link is the controller's 'Base' turned by pi
    return Robot(
        name=name,
        family="ur",
        model=model,
        tool_frame=tool,
        lower=model.lowerPositionLimit.copy(),
        upper=model.upperPositionLimit.copy(),
        max_speed=model.velocityLimit.copy(),
        params=params,
        base_offset=base,
        links=tuple(links),
        allowed_pairs=frozenset(frozenset(p) for p in _UR_ALLOWED_PAIRS),
    )


def _capsule(radius: float, a: tuple, b: tuple) -> trimesh.Trimesh:
    """A capsule mesh between points a and b (mm), posed in its link frame."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    height = float(np.linalg.norm(b - a))
    mesh = trimesh.creation.capsule(height=height, radius=radius, count=[12, 12])
    mesh.apply_translation([0, 0, height / 2] if height > 0 else [0, 0, 0])
    if height > 0:
        mesh.apply_transform(trimesh.geometry.align_vectors([0, 0, 1], (b - a) / height))
    mesh.apply_translation(a)
    return mesh


def _irb120_robot() -> Robot:
    joints = []
    for k, (parent, child, xyz, axis, (lo, hi), speed) in enumerate(_IRB120_JOINTS, start=1):
        joints.append(
            f'<joint name="joint_{k}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}" rpy="0 0 0"/><axis xyz="{axis[0]} {axis[1]} {axis[2]}"/>'
            f'<limit lower="{float(np.radians(lo))!r}" upper="{float(np.radians(hi))!r}" effort="100" '
            f'velocity="{float(np.radians(speed))!r}"/></joint>'
        )
    model = pin.buildModelFromXML(_IRB120_URDF.format(joints="\n  ".join(joints)))
    links = []
    for link, radius, a, b in _IRB120_CAPSULES:
        frame = model.frames[model.getFrameId(link)]
        links.append(LinkShape(link, int(frame.parentJoint), _se3(frame.placement), _capsule(radius, a, b)))
    allowed = [(_IRB120_CAPSULES[i][0], _IRB120_CAPSULES[i + 1][0]) for i in range(6)]
    allowed += [("link_3", "link_5"), ("link_4", "link_6"), ("link_3", "link_6"), ("base_link", "link_2")]
    return Robot(
        name="irb120",
        family="spherical",
        model=model,
        tool_frame=model.getFrameId("tool0"),
        lower=model.lowerPositionLimit.copy(),
        upper=model.upperPositionLimit.copy(),
        max_speed=model.velocityLimit.copy(),
        params={"d1": 290.0, "a2": 270.0, "a3": 70.0, "d4": 302.0, "d6": 72.0},
        base_offset=np.eye(4),
        links=tuple(links),
        allowed_pairs=frozenset(frozenset(p) for p in allowed),
    )


def load_robot(name: str) -> Robot:
    """Load ``ur3``, ``ur5``, ``ur10`` (example-robot-data URDFs) or ``irb120`` (datasheet)."""
    key = name.lower()
    if key in ("ur3", "ur5", "ur10"):
        return _ur_robot(key)
    if key == "irb120":
        return _irb120_robot()
    raise CurvsliceError(f"unknown robot {name!r}: choose one of {', '.join(ROBOT_NAMES)}")


def fk_reference(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Flange poses T_E^B (n, 4, 4) in mm by pinocchio's FK on the URDF (the test reference)."""
    q = np.atleast_2d(np.asarray(q, float))
    data = robot.model.createData()
    out = np.empty((len(q), 4, 4))
    for i, row in enumerate(q):
        pin.forwardKinematics(robot.model, data, row)
        out[i] = _se3(pin.updateFramePlacement(robot.model, data, robot.tool_frame))
    return out


def joint_placements(robot: Robot, q: np.ndarray) -> np.ndarray:
    """World poses (n, 7, 4, 4) in mm of the base (index 0) and the six joint frames of the
    pinocchio model, vectorized over configurations (each joint turns about its own x, y or z)."""
    q = np.atleast_2d(np.asarray(q, float))
    axes, parents, placements = robot.chain
    out = np.empty((len(q), 7, 4, 4))
    out[:, 0] = np.eye(4)
    for j in range(1, 7):
        turn = np.zeros((len(q), 4, 4))
        turn[:, :3, :3] = _rot(axes[j], q[:, j - 1])
        turn[:, 3, 3] = 1.0
        out[:, j] = out[:, parents[j]] @ placements[j] @ turn
    return out


def link_placements(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Poses (n, L, 4, 4) in mm of every collision body of ``robot.links`` at configurations q."""
    frames = joint_placements(robot, q)
    joints, local = robot.link_frames
    return frames[:, joints] @ local


def _ur_dh(robot: Robot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    p = robot.params
    d = np.array([p["d1"], 0, 0, p["d4"], p["d5"], p["d6"]])
    a = np.array([0, p["a2"], p["a3"], 0, 0, 0])
    alpha = np.array([np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0])
    return d, a, alpha


def _dh(theta: np.ndarray, d: float, a: float, alpha: float) -> np.ndarray:
    """Standard Denavit-Hartenberg link transform, vectorized over theta -> (..., 4, 4)."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    out = np.zeros(np.shape(theta) + (4, 4))
    out[..., 0, 0], out[..., 0, 1], out[..., 0, 2], out[..., 0, 3] = ct, -st * ca, st * sa, a * ct
    out[..., 1, 0], out[..., 1, 1], out[..., 1, 2], out[..., 1, 3] = st, ct * ca, -ct * sa, a * st
    out[..., 2, 1], out[..., 2, 2], out[..., 2, 3] = sa, ca, d
    out[..., 3, 3] = 1.0
    return out


def rigid_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4)."""
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def fk(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Analytic flange poses T_E^B (..., 4, 4) in mm, vectorized over configurations (..., 6)."""
    q = np.asarray(q, float)
    if robot.family == "ur":
        d, a, alpha = _ur_dh(robot)
        T = _dh(q[..., 0], d[0], a[0], alpha[0])
        for i in range(1, 6):
            T = T @ _dh(q[..., i], d[i], a[i], alpha[i])
        return robot.base_offset @ T
    p = robot.params
    R = _rot(2, q[..., 0]) @ _rot(1, q[..., 1] + q[..., 2]) @ _rot(0, q[..., 3]) @ _rot(1, q[..., 4])
    R = R @ _rot(0, q[..., 5])
    c1, s1 = np.cos(q[..., 0]), np.sin(q[..., 0])
    s2, c2 = np.sin(q[..., 1]), np.cos(q[..., 1])
    phi = q[..., 1] + q[..., 2]
    radial = p["a2"] * s2 + p["d4"] * np.cos(phi) + p["a3"] * np.sin(phi)
    height = p["d1"] + p["a2"] * c2 - p["d4"] * np.sin(phi) + p["a3"] * np.cos(phi)
    wrist = np.stack([c1 * radial, s1 * radial, height], axis=-1)
    out = np.zeros(q.shape[:-1] + (4, 4))
    out[..., :3, :3] = R @ _rot(1, np.full(q.shape[:-1], np.pi / 2))
    out[..., :3, 3] = wrist + p["d6"] * R[..., :, 0]
    out[..., 3, 3] = 1.0
    return out


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angles mapped to [-pi, pi)."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


#: signs (shoulder, wrist, elbow) of the 8 UR solutions in their branch order
UR_BRANCH_SIGNS = np.array([[s1, s5, s3] for s1 in (1.0, -1.0) for s5 in (1.0, -1.0) for s3 in (1.0, -1.0)])


def _ik_ur(robot: Robot, T: np.ndarray, branch: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Hawkins's closed form for the UR offset wrist: (n, 8, 6) solutions and (n, 8) validity, or
    with ``branch`` (n,) only that solution of each pose: (n, 1, 6) and (n, 1). Shoulder and wrist
    (4 combinations) fix joints 1, 5, 6 and the frame of the elbow's plane; the elbow doubles them."""
    d, a, alpha = _ur_dh(robot)
    d4, d6, a2, a3 = d[3], d[5], a[1], a[2]
    Td = rigid_inverse(robot.base_offset) @ T
    R, p = Td[:, :3, :3], Td[:, :3, 3]
    if branch is None:
        sign, elbow = UR_BRANCH_SIGNS[None, ::2, :2], np.array([1.0, -1.0])  # (1, 4, 2), then x2
    else:
        sign, elbow = UR_BRANCH_SIGNS[np.asarray(branch)][:, None, :2], UR_BRANCH_SIGNS[np.asarray(branch), 2:]
    p05 = p - d6 * R[:, :, 2]
    r = np.hypot(p05[:, 0], p05[:, 1])
    cphi = d4 / np.maximum(r, 1e-12)
    ok1 = np.abs(cphi) <= 1.0 + 1e-9
    phi = np.arccos(np.clip(cphi, -1, 1))
    th1 = np.arctan2(p05[:, 1], p05[:, 0])[:, None] + sign[..., 0] * phi[:, None] + np.pi / 2  # (n, B)
    s1, c1 = np.sin(th1), np.cos(th1)
    c5 = (p[:, 0, None] * s1 - p[:, 1, None] * c1 - d4) / d6
    ok5 = np.abs(c5) <= 1.0 + 1e-9
    th5 = np.arccos(np.clip(c5, -1, 1)) * sign[..., 1]
    s5 = np.sin(th5)
    num = -R[:, 0, 1, None] * s1 + R[:, 1, 1, None] * c1
    den = R[:, 0, 0, None] * s1 - R[:, 1, 0, None] * c1
    safe = np.abs(s5) > 1e-10
    s5s = np.where(safe, s5, 1.0)
    th6 = np.where(safe, np.arctan2(num / s5s, den / s5s), 0.0)  # wrist singular: any theta6
    T01 = _dh(th1, d[0], a[0], alpha[0])
    T46 = _dh(th5, d[4], a[4], alpha[4]) @ _dh(th6, d[5], a[5], alpha[5])
    T14 = rigid_inverse(T01) @ Td[:, None] @ rigid_inverse(T46)
    P13 = T14[..., :3, :3] @ np.array([0.0, -d4, 0.0]) + T14[..., :3, 3]
    n13 = np.linalg.norm(P13, axis=-1)
    c3 = (n13**2 - a2**2 - a3**2) / (2 * a2 * a3)
    ok3 = np.abs(c3) <= 1.0 + 1e-9
    th3 = np.arccos(np.clip(c3, -1, 1))[..., None] * elbow[:, None] if branch is not None else \
        np.arccos(np.clip(c3, -1, 1))[..., None] * elbow  # (n, B, E)
    th2 = -np.arctan2(P13[..., 1], -P13[..., 0])[..., None] + np.arcsin(
        np.clip(a3 * np.sin(th3) / np.maximum(n13, 1e-12)[..., None], -1, 1))
    T13 = _dh(th2, d[1], a[1], alpha[1]) @ _dh(th3, d[2], a[2], alpha[2])
    T34 = rigid_inverse(T13) @ T14[..., None, :, :]
    th4 = np.arctan2(T34[..., 1, 0], T34[..., 0, 0])
    shape = th3.shape
    q = np.stack([np.broadcast_to(x, shape) for x in (th1[..., None], th2, th3, th4, th5[..., None], th6[..., None])],
                 axis=-1).reshape(len(T), -1, 6)
    ok = np.broadcast_to((ok1[:, None] & ok5 & ok3)[..., None], shape).reshape(len(T), -1)
    return q, ok


def _ik_spherical(robot: Robot, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Spherical-wrist closed form (IRB120): 2 shoulder x 2 elbow x 2 wrist = up to 8 solutions."""
    p = robot.params
    a2, L3 = p["a2"], np.hypot(p["d4"], p["a3"])
    beta = np.arctan2(p["a3"], p["d4"])
    R_t = T[:, :3, :3]
    wc = T[:, :3, 3] - p["d6"] * R_t[:, :, 2]
    rho = np.hypot(wc[:, 0], wc[:, 1])
    th1 = np.arctan2(wc[:, 1], wc[:, 0])[:, None] + np.array([0.0, np.pi])  # (n,2)
    X = rho[:, None] * np.array([1.0, -1.0])
    Z = (wc[:, 2] - p["d1"])[:, None] * np.ones(2)
    k = (a2**2 + L3**2 - X**2 - Z**2) / (2 * a2 * L3)
    ok3 = np.abs(k) <= 1.0 + 1e-9
    ak = np.arcsin(np.clip(k, -1, 1))
    th3 = beta + np.stack([ak, np.pi - ak], -1)  # (n,2,2)
    gamma = th3 - beta
    A, B = a2 - L3 * np.sin(gamma), L3 * np.cos(gamma)
    Xb, Zb = X[..., None], Z[..., None]
    th2 = np.arctan2(A * Xb - B * Zb, B * Xb + A * Zb)
    R03 = _rot(2, np.broadcast_to(th1[:, :, None], th2.shape)) @ _rot(1, th2 + th3)
    R6 = R_t @ _rot(1, np.full(len(T), -np.pi / 2))  # link_6 frame = tool0 turned back about y
    M = np.swapaxes(R03, -1, -2) @ R6[:, None, None]  # = Rx(q4) Ry(q5) Rx(q6)
    b = np.arccos(np.clip(M[..., 0, 0], -1, 1))[..., None] * np.array([1.0, -1.0])  # (n,2,2,2)
    sb = np.sin(b)
    safe = np.abs(sb) > 1e-10
    sbs = np.where(safe, sb, 1.0)
    th4 = np.where(safe, np.arctan2(M[..., 1, 0, None] / sbs, -M[..., 2, 0, None] / sbs),
                   np.arctan2(M[..., 2, 1], M[..., 1, 1])[..., None])
    th6 = np.where(safe, np.arctan2(M[..., 0, 1, None] / sbs, M[..., 0, 2, None] / sbs), 0.0)
    shape = b.shape
    q = np.stack(
        [np.broadcast_to(x, shape) for x in (th1[:, :, None, None], th2[..., None], th3[..., None],
                                             th4, b, th6)], axis=-1,
    ).reshape(len(T), 8, 6)
    ok = np.broadcast_to(ok3[:, :, None, None], shape).reshape(len(T), 8)
    return q, ok


def ik(robot: Robot, T: np.ndarray, tol: float = 1e-3, chunk: int = 512, check: bool = True,
       branch: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """All analytic IK solutions of flange poses T_E^B (n, 4, 4) in mm (§3.5.3).

    Returns ``q`` (n, 8, 6) with angles in [-pi, pi) and ``valid`` (n, 8): a branch is valid when
    it exists and its FK reproduces the pose within ``tol`` mm and ``tol``/1000 rad (branches lose
    accuracy only at exact singularities). Joint limits are not applied here. Poses are solved in
    chunks small enough for the stacked 4x4 products to stay in cache (3x faster than one batch).
    ``check=False`` skips the FK re-check (validity = the closed form's own existence tests): for
    finite differences, where a pose is never kept. ``branch`` (n,) int: only that solution of each
    pose, q (n, 6) and valid (n,) (the same values as the full solve's, for the UR family at an
    eighth of its cost).
    """
    T = np.asarray(T, float).reshape(-1, 4, 4)
    one = branch is not None
    if one:
        branch = np.broadcast_to(np.asarray(branch, np.int64), (len(T),))
    width = 1 if one else 8
    q = np.empty((len(T), width, 6))
    valid = np.empty((len(T), width), bool)
    for s in range(0, len(T), chunk):
        Tc = T[s : s + chunk]
        with np.errstate(invalid="ignore", divide="ignore"):
            if robot.family == "ur":
                qc, ok = _ik_ur(robot, Tc, branch[s : s + chunk] if one else None)
            else:
                qc, ok = _ik_spherical(robot, Tc)
                if one:
                    k = np.arange(len(Tc))
                    qc, ok = qc[k, branch[s : s + chunk]][:, None], ok[k, branch[s : s + chunk]][:, None]
        qc = _wrap(np.nan_to_num(qc))
        q[s : s + chunk] = qc
        if not check:
            valid[s : s + chunk] = ok
            continue
        back = fk(robot, qc)
        pos_err = np.linalg.norm(back[..., :3, 3] - Tc[:, None, :3, 3], axis=-1)
        rot_err = np.abs(back[..., :3, :3] - Tc[:, None, :3, :3]).max(axis=(-1, -2))
        valid[s : s + chunk] = ok & (pos_err <= tol) & (rot_err <= tol * 1e-3)
    return (q[:, 0], valid[:, 0]) if one else (q, valid)
