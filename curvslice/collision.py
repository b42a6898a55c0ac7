"""python-fcl scenes of a workcell: which arm poses collide (§3.5.3, §4.3.1 "Nodes ... with
collision are excluded from the graph, ... checked by a collision detection library [FCL]").

Bodies (mm): the robot's collision meshes (moving with their joints), the platform and the part
printed so far (the union of earlier layers; both carried by the flange through T_P^E), and the
static extruder (nozzle frame N) and obstacles (base frame B). Checked pairs: robot self-collision
(except the pairs the robot declares allowed), every robot link and every carried body against every
static body, and the carried bodies against every link except the one they are mounted on.
A bounding-box test, vectorized over poses, sends only overlapping pairs to fcl; with ``bounds``
the conservative sphere proxy of :mod:`curvslice.collision_estimate` prunes the pairs further (a
pair it proves apart cannot touch, so every answer is still fcl's).
"""

from __future__ import annotations

from dataclasses import dataclass

import fcl
import numpy as np
import trimesh

from curvslice.collision_estimate import SphereBounds
from curvslice.kinematics import Robot, fk, link_placements
from curvslice.workcell import Body, Workcell


@dataclass(frozen=True, eq=False)
class _Shape:
    name: str
    obj: fcl.CollisionObject
    center: np.ndarray  # centre of the body-frame bounding box
    half: np.ndarray  # half extents of the body-frame bounding box


def _bvh(mesh: trimesh.Trimesh) -> fcl.BVHModel:
    model = fcl.BVHModel()
    model.beginModel(len(mesh.vertices), len(mesh.faces))
    model.addSubModel(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int32))
    model.endModel()
    return model


def _mesh_shape(name: str, mesh: trimesh.Trimesh) -> _Shape:
    lo, hi = mesh.bounds
    return _Shape(name, fcl.CollisionObject(_bvh(mesh), fcl.Transform()), (lo + hi) / 2, (hi - lo) / 2)


def _body_shape(body: Body) -> _Shape:
    if body.kind == "box":
        geom = fcl.Box(*body.dims)
        half = np.asarray(body.dims, float) / 2
    else:
        geom = (fcl.Cylinder if body.kind == "cylinder" else fcl.Cone)(*body.dims)
        half = np.array([body.dims[0], body.dims[0], body.dims[1] / 2])
    return _Shape(body.name, fcl.CollisionObject(geom, fcl.Transform()), np.zeros(3), half)


def _set(obj: fcl.CollisionObject, T: np.ndarray) -> None:
    obj.setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))


def platform_mesh(cell: Workcell, platform_vertices: np.ndarray | None = None) -> trimesh.Trimesh:
    """The platform solid in the model frame P: the hull of the slice's platform vertices, or the
    workcell's disc (radius, thickness) under z = 0."""
    if platform_vertices is not None and len(platform_vertices) >= 4:
        return trimesh.convex.convex_hull(np.asarray(platform_vertices, float))
    disc = trimesh.creation.cylinder(radius=cell.platform_radius, height=cell.platform_thickness, sections=48)
    disc.apply_translation([0, 0, -cell.platform_thickness / 2])
    return disc


#: link vertices tested against the static boxes before fcl (see :meth:`CollisionScene._inside_box`)
PROBES = 24
#: printed layers per BVH of the carried part (see :meth:`CollisionScene.for_layer`)
PART_BLOCK = 16


class CollisionScene:
    """Collision queries for arm configurations of one robot in one workcell (mm, rad)."""

    def __init__(self, robot: Robot, cell: Workcell, platform_vertices: np.ndarray | None = None,
                 bounds: bool = False):
        self.robot = robot
        self.mount = cell.platform_mount
        self.links = [_mesh_shape(s.link, s.mesh) for s in robot.links]
        self.static = []
        self.static_poses = []
        for body in cell.extruder:
            self.static.append(_body_shape(body))
            self.static_poses.append(cell.nozzle @ body.pose)
        for body in cell.obstacles:
            self.static.append(_body_shape(body))
            self.static_poses.append(body.pose)
        for shape, pose in zip(self.static, self.static_poses):
            _set(shape.obj, pose)
        platform = platform_mesh(cell, platform_vertices)
        self.carried = [_mesh_shape("platform", platform)]
        self.bounds = SphereBounds(robot, cell, platform) if bounds else None
        self.fcl_configs = 0  # configurations that needed at least one fcl pair test
        self._blocks: dict[tuple[int, ...], _Shape] = {}  # BVHs of the earlier whole blocks and of the tails after them
        # probes for _inside_box, per connected piece of every link mesh (body frame): up to PROBES
        # of its vertices, the link carrying it, its bounding sphere
        pieces = [(k, piece) for k, s in enumerate(robot.links) for piece in s.mesh.split(only_watertight=False)]
        self._probe = np.stack([np.asarray(m.vertices)[np.linspace(0, len(m.vertices) - 1, PROBES).astype(int)]
                                for _, m in pieces])
        self._probe_link = np.array([k for k, _ in pieces])
        self._sphere = np.array([np.r_[m.bounds.mean(axis=0), np.linalg.norm(m.vertices - m.bounds.mean(axis=0), axis=1).max()]
                                 for _, m in pieces])
        self._boxes = [(np.linalg.inv(pose), np.asarray(shape.half), k)
                       for k, (body, pose, shape) in enumerate(zip(list(cell.extruder) + list(cell.obstacles),
                                                                   self.static_poses, self.static)) if body.kind == "box"]
        self._flange_link = max(range(len(robot.links)), key=lambda k: robot.links[k].joint)
        self._build_pairs()

    def set_part(self, mesh: trimesh.Trimesh | None) -> None:
        """The printed part (model frame) carried on the platform; ``None`` or empty removes it."""
        self._carry([_mesh_shape("part", mesh)] if mesh is not None and len(mesh.faces) else [], mesh)

    def _carry(self, parts: list[_Shape], mesh: trimesh.Trimesh | None) -> None:
        self.carried = self.carried[:1] + parts
        if self.bounds is not None:
            self.bounds.set_part(mesh, len(parts))
        self._build_pairs()

    def for_layer(self, layers: list[trimesh.Trimesh], layer: int):
        """Carry the union of layers 1..layer-1 (print order) and return :meth:`collisions`.

        The part is carried as two BVHs: the layers before the last multiple of ``PART_BLOCK``
        (built once per block of layers and reused) and the few layers after it (kept for the block's
        layers, which are asked for again by the jerk stage's collision rounds); rebuilding the whole
        part every layer is quadratic in the layers."""
        earlier = layers[: max(layer - 1, 0)]
        cut = len(earlier) // PART_BLOCK * PART_BLOCK
        parts = []
        for block, keep in ((earlier[:cut], True), (earlier[cut:], False)):
            block = [m for m in block if len(m.faces)]
            key = tuple(id(m) for m in block)
            shape = self._blocks.get(key)
            if shape is None and block:
                shape = _mesh_shape("part", trimesh.util.concatenate(block))
                if keep:  # a new whole block: the tails of the previous one are not needed again
                    self._blocks = {key: shape}
                elif len(self._blocks) <= PART_BLOCK:  # tails: a layer is asked for again (graph, jerk rounds)
                    self._blocks[key] = shape
            if shape is not None:
                parts.append(shape)
        nonempty = [m for m in earlier if len(m.faces)]
        self._carry(parts, trimesh.util.concatenate(nonempty) if self.bounds is not None and nonempty else None)
        return self.collisions

    def _build_pairs(self) -> None:
        L, C, S = len(self.links), len(self.carried), len(self.static)
        names = [s.link for s in self.robot.links]
        pairs = []
        for a in range(L):
            for b in range(a + 1, L):
                if frozenset((names[a], names[b])) not in self.robot.allowed_pairs and names[a] != names[b]:
                    pairs.append((a, b))
        moving = L + C
        for a in range(moving):
            pairs += [(a, moving + s) for s in range(S)]
        for c in range(C):
            pairs += [(L + c, a) for a in range(L) if a != self._flange_link]
        self.pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        self._hits = np.zeros(len(self.pairs))
        self.shapes = self.links + self.carried + self.static
        self.centers = np.array([s.center for s in self.shapes])
        self.halves = np.array([s.half for s in self.shapes])

    def _poses(self, q: np.ndarray) -> np.ndarray:
        """World poses (n, bodies, 4, 4) of links, carried bodies and static bodies."""
        n = len(q)
        links = link_placements(self.robot, q)
        carried = (fk(self.robot, q) @ self.mount)[:, None].repeat(len(self.carried), axis=1)
        static = np.broadcast_to(np.array(self.static_poses).reshape(-1, 4, 4), (n, len(self.static), 4, 4))
        return np.concatenate([links, carried, static], axis=1)

    def collisions(self, q: np.ndarray, chunk: int = 256) -> np.ndarray:
        """(n,) bool: True where configuration q[i] (rad) puts any checked pair in contact."""
        q = np.atleast_2d(np.asarray(q, float))
        if len(q) == 0 or len(self.pairs) == 0:
            return np.zeros(len(q), bool)
        return np.concatenate([self._collisions(q[s : s + chunk]) for s in range(0, len(q), chunk)])

    def _collisions(self, q: np.ndarray) -> np.ndarray:
        poses = self._poses(q)
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        near = self._near(poses)
        hit = np.zeros(len(q), bool)
        L, first_static = len(self.links), len(self.shapes) - len(self.static)
        for T_inv, half, s in self._boxes:  # only where a link's bounding box overlaps that static box
            rows = np.flatnonzero(~hit & near[:, (a < L) & (b == first_static + s)].any(axis=1))
            if len(rows):
                hit[rows] = self._inside_box(poses[rows], T_inv, half)
        self.fcl_configs += int((near.any(axis=1) & ~hit).sum())
        # carried-vs-static pairs depend on the flange pose only, shared by all IK branches of a
        # pose: test them once per distinct flange pose
        L = len(self.links)
        flange_only = (a >= L) & (a < L + len(self.carried)) & (b >= len(self.shapes) - len(self.static))
        rows = np.flatnonzero(~hit & near[:, flange_only].any(axis=1))
        if len(rows):
            key = np.round(poses[rows, L, :3, :].reshape(len(rows), -1), 6)
            _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
            pose_hit = self._test(poses, near, rows[first], np.flatnonzero(flange_only))
            hit[rows] = pose_hit[inverse.ravel()]
        self._test(poses, near, np.flatnonzero(~hit & near[:, ~flange_only].any(axis=1)),
                   np.flatnonzero(~flange_only), out=hit)
        return hit

    def _inside_box(self, poses: np.ndarray, T_inv: np.ndarray, half: np.ndarray) -> np.ndarray:
        """(n,) bool: a robot link surely meets the static box (T_inv: base to box frame, half
        extents): one of its vertices lies inside the box, or a connected piece of its mesh whose
        bounding sphere stays within the box's footprint has vertices on both sides of the box's
        slab, so its surface crosses the solid box. Either is a contact fcl reports for that checked
        pair: a cheap, exact witness for the most common collision (an elbow-down branch through the
        table)."""
        M = T_inv @ poses[:, self._probe_link]  # (n, pieces, 4, 4): link pieces in the box frame
        local = M[..., :3, :3] @ np.swapaxes(self._probe, 1, 2) + M[..., :3, 3:]  # (n, pieces, 3, V)
        inside = (np.abs(local) < half[:, None] - 1e-6).all(axis=2).any(axis=2)
        c = (M[..., :3, :3] @ self._sphere[:, :3, None])[..., 0] + M[..., :3, 3]
        within = (np.abs(c[..., :2]) + self._sphere[:, 3:] < half[:2]).all(axis=-1)
        z = local[:, :, 2]
        across = within & (z.min(axis=2) < half[2] - 1e-6) & (z.max(axis=2) > -half[2] + 1e-6)
        return (inside | across).any(axis=1)

    def maybe_colliding(self, q: np.ndarray) -> np.ndarray:
        """(n,) bool: False where the bounding boxes (and ``bounds``) prove every pair apart."""
        q = np.atleast_2d(np.asarray(q, float))
        return np.concatenate([self._near(self._poses(q[s : s + 256])).any(axis=1) for s in range(0, len(q), 256)]
                              + [np.zeros(0, bool)])

    def _near(self, poses: np.ndarray) -> np.ndarray:
        """(n, pairs) bool: the pairs not proven apart by world-aligned boxes around every body
        (and by the sphere ``bounds``)."""
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        R = poses[..., :3, :3]
        centre = (R @ self.centers[..., None])[..., 0] + poses[..., :3, 3]
        reach = (np.abs(R) @ self.halves[..., None])[..., 0]
        near = (np.abs(centre[:, a] - centre[:, b]) <= reach[:, a] + reach[:, b]).all(axis=-1)
        if self.bounds is not None:
            some = np.flatnonzero(near.any(axis=0))
            near[:, some] &= self.bounds.pair_bounds(poses, self.pairs[some]) <= 0
        return near

    def _test(self, poses: np.ndarray, near: np.ndarray, rows: np.ndarray, pairs: np.ndarray,
              out: np.ndarray | None = None) -> np.ndarray:
        """fcl on the near ``pairs`` of configurations ``rows``; True per row on first contact
        (written into ``out[row]`` when given)."""
        found = np.zeros(len(rows), bool)
        request = fcl.CollisionRequest()
        n_moving = len(self.shapes) - len(self.static)
        pairs = pairs[np.argsort(-self._hits[pairs], kind="stable")]  # the pairs found in contact most often first
        for r, i in enumerate(rows):
            placed = set()
            for k in pairs[near[i, pairs]]:
                pa, pb = self.pairs[k]
                for body in (pa, pb):
                    if body < n_moving and body not in placed:
                        _set(self.shapes[body].obj, poses[i, body])
                        placed.add(body)
                if fcl.collide(self.shapes[pa].obj, self.shapes[pb].obj, request, fcl.CollisionResult()):
                    found[r] = True
                    self._hits[k] += 1
                    break
        if out is not None:
            out[rows] |= found
        return found

    def colliding_pairs(self, q: np.ndarray) -> list[tuple[str, str]]:
        """Names of all pairs in contact at one configuration (for reports and the verifier)."""
        poses = self._poses(np.atleast_2d(np.asarray(q, float)))[0]
        n_moving = len(self.shapes) - len(self.static)
        for body in range(n_moving):
            _set(self.shapes[body].obj, poses[body])
        request = fcl.CollisionRequest()
        out = []
        for pa, pb in self.pairs:
            if fcl.collide(self.shapes[pa].obj, self.shapes[pb].obj, request, fcl.CollisionResult()):
                out.append((self.shapes[pa].name, self.shapes[pb].name))
        return out
