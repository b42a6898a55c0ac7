"""python-fcl scenes of a workcell: which arm poses collide (§3.5.3, §4.3.1 "Nodes ... with
collision are excluded from the graph, ... checked by a collision detection library [FCL]").

Bodies (mm): the robot's collision meshes (moving with their joints), the platform and the part
printed so far (the union of earlier layers; both carried by the flange through T_P^E), and the
static extruder (nozzle frame N) and obstacles (base frame B). Checked pairs: robot self-collision
(except the pairs the robot declares allowed), every robot link and every carried body against every
static body, and the carried bodies against every link except the one they are mounted on.
A bounding-box test, vectorized over poses, sends only overlapping pairs on; with ``bounds`` (the
default) the conservative sphere / distance-field proxy of :mod:`curvslice.collision_estimate`
prunes them further, for the whole batch at once (a pair it proves apart cannot touch, so every
answer is still fcl's). A pair between a carried and a static body depends only on their relative
pose (for a cylinder or cone, only on its axis and centre): fcl tests each distinct one once.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import fcl
import numpy as np
import trimesh

from curvslice.collision_estimate import CarriedBounds, SphereBounds, carried_bounds
from curvslice.kinematics import Robot, fk, link_placements, rigid_inverse
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
    obj.setRotation(T[:3, :3])  # (twice as fast as building an fcl.Transform)
    obj.setTranslation(T[:3, 3])


def _boxes_overlap(centre: np.ndarray, reach: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, pairs) bool: the world-aligned boxes (``centre``, half extents ``reach``: (n, bodies, 3)) of bodies
    ``a`` and ``b`` overlap, one axis after the other on contiguous (n, bodies) planes (six times faster than
    gathering (n, pairs, 3) blocks; the same comparisons)."""
    centre, reach = np.ascontiguousarray(np.moveaxis(centre, -1, 0)), np.ascontiguousarray(np.moveaxis(reach, -1, 0))
    out = np.abs(centre[0][:, a] - centre[0][:, b]) <= reach[0][:, a] + reach[0][:, b]
    for k in (1, 2):
        out &= np.abs(centre[k][:, a] - centre[k][:, b]) <= reach[k][:, a] + reach[k][:, b]
    return out


#: rows up to which :func:`_distinct` groups by a dict of their bytes instead of sorting
SMALL_DISTINCT = 64


def _distinct(key: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[bytes]]:
    """Rows of integer ``key`` (n, m): the index of one row per distinct value (the first one),
    each row's group, and the distinct values' bytes (a few rows: by a dict, no sort)."""
    if len(key) <= SMALL_DISTINCT:
        names = [row.tobytes() for row in key]
        seen: dict[bytes, int] = {}
        group = np.array([seen.setdefault(name, len(seen)) for name in names], np.int64)
        first = np.zeros(len(seen), np.int64)
        first[group[::-1]] = np.arange(len(key))[::-1]
        return first, group, list(seen)
    order = np.lexsort(key.T)
    new = np.r_[True, (key[order[1:]] != key[order[:-1]]).any(axis=1)]
    group = np.empty(len(key), np.int64)
    group[order] = np.cumsum(new) - 1
    first = order[new]
    return first, group, [key[i].tobytes() for i in first]


def _rounded(key: np.ndarray) -> np.ndarray:
    """Rows of ``key`` (n, ...) flattened and rounded to 1e-6 (µm, µrad) as integers: the names of
    :meth:`CollisionScene._remembered`'s answers (their bytes)."""
    return np.rint(key.reshape(len(key), -1) * 1e6).astype(np.int64)


def rotation_core(body: Body) -> tuple[fcl.CollisionGeometry, np.ndarray] | None:
    """The part of an extruder body (pose in the nozzle frame N) that every rotation θ about the
    nozzle axis (N's z, Eq. 4.3) keeps inside the body: a cylinder or cone on the axis is its own
    core, a box with a face normal along the axis holds the largest cylinder about the axis that
    fits its footprint; ``None`` where no such core exists. Returns the fcl geometry and its pose in N."""
    R, t = body.pose[:3, :3], body.pose[:3, 3]
    along = abs(abs(R[2, 2]) - 1.0) < 1e-9  # the body's own z parallel to the nozzle axis
    if not along:
        return None
    if body.kind in ("cylinder", "cone"):
        return ((fcl.Cylinder if body.kind == "cylinder" else fcl.Cone)(*body.dims), body.pose) \
            if np.hypot(t[0], t[1]) < 1e-9 else None
    if body.kind != "box":
        return None
    axis = R.T @ -t  # the nozzle axis's point at the box centre's height, box frame
    radius = min(body.dims[0] / 2 - abs(axis[0]), body.dims[1] / 2 - abs(axis[1]))
    if radius <= 0:
        return None
    pose = np.eye(4)
    pose[2, 3] = t[2]
    return fcl.Cylinder(radius, float(body.dims[2])), pose


#: a box's sweep cylinder (:func:`rotation_sweep`) is used while its cross-section is at most this many
#: times the box's (the UR5 cell's heater block: 1.6; the mount beam, far off the axis: 34)
SWEEP_RATIO = 3.0


def rotation_sweep(body: Body) -> tuple[fcl.CollisionGeometry, np.ndarray] | None:
    """The cylinder about the nozzle axis that holds an extruder box (pose in the nozzle frame N) at
    every rotation θ about that axis (Eq. 4.3): the box's height, radius its farthest edge from the
    axis. Where it meets nothing, neither does the box at any θ, so one fcl test per nozzle placement
    answers all rotations (§4.3.1); ``None`` for a box not along the axis, or one whose sweep is more
    than :data:`SWEEP_RATIO` times its cross-section (it would meet too much to help). Returns the
    fcl geometry and its pose in N."""
    R, t = body.pose[:3, :3], body.pose[:3, 3]
    if body.kind != "box" or abs(abs(R[2, 2]) - 1.0) >= 1e-9:
        return None
    axis = R.T @ -t  # the nozzle axis's point at the box centre's height, box frame
    dx, dy, dz = (float(d) for d in body.dims)
    radius = float(np.hypot(dx / 2 + abs(axis[0]), dy / 2 + abs(axis[1])))
    if np.pi * radius ** 2 > SWEEP_RATIO * dx * dy:
        return None
    pose = np.eye(4)
    pose[2, 3] = t[2]
    return fcl.Cylinder(radius, dz), pose


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
#: configurations a query needs before the sphere bounds pay for their fixed cost (~0.4 ms a query;
#: fcl on the box-overlapping pairs costs ~30 us a configuration)
BOUNDS_BATCH = 64
#: printed layers per BVH of the carried part (see :meth:`CollisionScene.for_layer`)
PART_BLOCK = 16
#: printed layers per BVH of the carried part within a block (see :meth:`CollisionScene.for_layer`)
PART_SUB = 4
#: block bases whose pieces a scene keeps (see :meth:`CollisionScene.for_layer`)
KEPT_BASES = 2
#: cells of the part's distance field along its longest side at most (cells ≥ 0.5 mm)
FIELD_CELLS = 160


@dataclass(frozen=True, eq=False)
class _Piece:
    """A piece of the printed part: its fcl body and what the proxy knows of it."""

    shape: _Shape
    bounds: CarriedBounds | None
    answers: dict = field(default_factory=dict)  # fcl's answers against static bodies, by relative pose


class CollisionScene:
    """Collision queries for arm configurations of one robot in one workcell (mm, rad)."""

    def __init__(self, robot: Robot, cell: Workcell, platform_vertices: np.ndarray | None = None,
                 bounds: bool = True):
        self.robot = robot
        self.mount = cell.platform_mount
        self.nozzle = cell.nozzle
        self.links = [_mesh_shape(s.link, s.mesh) for s in robot.links]
        self.static = []
        self.static_poses = []
        self._extruder = list(cell.extruder)
        for body in cell.extruder:
            self.static.append(_body_shape(body))
            self.static_poses.append(cell.nozzle @ body.pose)
        for body in cell.obstacles:
            self.static.append(_body_shape(body))
            self.static_poses.append(body.pose)
        for shape, pose in zip(self.static, self.static_poses):
            _set(shape.obj, pose)
        # the static bodies' world-aligned boxes (centres, half extents) in the base frame
        self._static_boxes = (np.array([P[:3, :3] @ sh.center + P[:3, 3] for sh, P in zip(self.static, self.static_poses)]),
                              np.array([np.abs(P[:3, :3]) @ sh.half for sh, P in zip(self.static, self.static_poses)]))
        platform = platform_mesh(cell, platform_vertices)
        self.carried = [_mesh_shape("platform", platform)]
        self._answers = [{}]  # per carried body: {static body: {relative pose: fcl's answer}}
        self.bounds = SphereBounds(robot, cell, platform) if bounds else None
        self.fcl_configs = 0  # configurations that needed at least one fcl pair test
        self._pieces: dict[tuple[int, ...], dict[tuple[int, ...], _Piece]] = {}  # per block base: its pieces
        self._symmetric = [b.kind in ("cylinder", "cone") for b in list(cell.extruder) + list(cell.obstacles)]
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
        cores = [rotation_core(body) for body in cell.extruder]
        self._cores = [(fcl.CollisionObject(geom, fcl.Transform()), pose, float(np.hypot(geom.radius, geom.lz / 2)))
                       for geom, pose in filter(None, cores)]  # with the radius of a ball around each
        # the extruder bodies that are their own rotation core (a cylinder or cone on the axis):
        # blocked() tests them exactly as _relative_answers would, so its free frames answer them
        self._own_core = [s for s, (body, core) in enumerate(zip(cell.extruder, cores))
                          if core is not None and body.kind in ("cylinder", "cone")]
        # per static body: its sweep (rotation_sweep) as a placed fcl object and its pose in the
        # body's own frame (None: none)
        self._sweeps: list[tuple[fcl.CollisionObject, np.ndarray] | None] = [None] * len(self.static)
        for s, body in enumerate(cell.extruder):
            sweep = rotation_sweep(body)
            if sweep is not None:
                obj = fcl.CollisionObject(sweep[0], fcl.Transform())
                _set(obj, cell.nozzle @ sweep[1])
                self._sweeps[s] = (obj, np.linalg.inv(body.pose) @ sweep[1])
        self._build_pairs()

    def set_part(self, mesh: trimesh.Trimesh | None) -> None:
        """The printed part (model frame) carried on the platform; ``None`` or empty removes it."""
        self._carry([self._piece(mesh)] if mesh is not None and len(mesh.faces) else [])

    def _piece(self, mesh: trimesh.Trimesh, bounds: CarriedBounds | None = None) -> _Piece:
        """A part piece: its BVH and, with the scene's ``bounds``, its distance field (or ``bounds``,
        a field of a mesh holding all of ``mesh``'s triangles: a lower bound on the distance to more
        triangles is one on the distance to these)."""
        if bounds is None and self.bounds is not None:
            bounds = self._field(mesh)
        return _Piece(_mesh_shape("part", mesh), bounds)

    @staticmethod
    def _field(mesh: trimesh.Trimesh) -> CarriedBounds:
        return carried_bounds(mesh, max(0.5, float(mesh.extents.max()) / FIELD_CELLS))

    def _carry(self, pieces: list[_Piece]) -> None:
        self.carried = self.carried[:1] + [p.shape for p in pieces]
        self._answers = self._answers[:1] + [p.answers for p in pieces]
        if self.bounds is not None:
            self.bounds.set_pieces([p.bounds for p in pieces])
        self._build_pairs()

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """The scene is the collision predicate of its carried part: :meth:`collisions`."""
        return self.collisions(q)

    def blocked(self, frames: np.ndarray) -> np.ndarray:
        """(n,) bool: nozzle frames (n, 4, 4) in the model frame P (a waypoint at any θ) where the
        rotation-invariant core of the extruder (:func:`rotation_core`) meets the platform or the
        part carried now. There every rotation θ about the nozzle axis, on every IK branch, puts a
        checked carried/static pair in contact (fcl would say so node by node): a rung no p can
        make reachable (§4.3.1)."""
        frames = np.asarray(frames, float).reshape(-1, 4, 4)
        out = np.zeros(len(frames), bool)
        if not self._cores:
            return out
        request = fcl.CollisionRequest()
        lo = np.array([s.center - s.half for s in self.carried])
        hi = np.array([s.center + s.half for s in self.carried])
        for shape in self.carried:  # meshes in P
            _set(shape.obj, np.eye(4))
        for obj, pose, reach in self._cores:
            placed = frames @ pose
            c = placed[:, :3, 3]
            near = ((c[:, None] >= lo[None] - reach) & (c[:, None] <= hi[None] + reach)).all(axis=-1)
            for i in np.flatnonzero(~out & near.any(axis=1)):
                _set(obj, placed[i])
                out[i] = any(fcl.collide(obj, self.carried[k].obj, request, fcl.CollisionResult())
                             for k in np.flatnonzero(near[i]))
        free = frames[~out]
        for s in self._own_core if len(free) else ():  # fcl's answer for these bodies at every θ of a free frame: apart
            names = [row.tobytes() for row in _rounded((free @ self._extruder[s].pose)[:, :3, 2:])]
            for answers in self._answers:
                answers.setdefault(s, {}).update(dict.fromkeys(names, 0))
        return out

    def held_blocked(self, frames: np.ndarray) -> np.ndarray:
        """(n,) bool: nozzle frames (n, 4, 4) in the model frame P, each at its own rotation θ about
        the nozzle axis, where a static body (extruder or obstacle) meets the platform or the part
        carried now. The frame fixes the platform's pose in the base frame (T_B^P = T_B^N (T_P^N)⁻¹,
        Eq. 2.3), so such a contact is one of the checked carried/static pairs at every
        configuration realizing that frame, on every IK branch: fcl's own answer for the node, found
        once per frame instead of once per node (a world-aligned box test first)."""
        frames = np.asarray(frames, float).reshape(-1, 4, 4)
        out = np.zeros(len(frames), bool)
        if not len(frames) or not self.static:
            return out
        held = self.nozzle @ rigid_inverse(frames)  # T_B^P per frame
        shapes = self.carried
        R, t = held[:, :3, :3], held[:, :3, 3]
        centre = np.stack([(R @ c.center) + t for c in shapes], axis=1)  # (n, C, 3) carried boxes in B
        reach = np.stack([np.abs(R) @ c.half for c in shapes], axis=1)
        s_centre, s_reach = self._static_boxes
        near = (np.abs(centre[:, :, None] - s_centre[None, None]) <= reach[:, :, None] + s_reach[None, None]).all(axis=-1)
        inverse = None
        pairs = self._carried_static
        for k in pairs[np.argsort(-self._hits[pairs], kind="stable")].tolist():  # those found in contact most often first
            c, st = self._carried_of[k], self._static_of[k]
            rows = np.flatnonzero(near[:, c, st] & ~out)
            if len(rows):
                inverse = rigid_inverse(held) if inverse is None else inverse
                out[rows] = self._relative_answers(k, held[rows], inverse[rows])
        return out

    def for_layer(self, layers: list[trimesh.Trimesh], layer: int):
        """Carry the union of layers 1..layer-1 (print order) and return the scene, the layer's
        collision predicate (``scene(q)``, :meth:`collisions`; :meth:`blocked` for whole rungs).

        The part is carried as up to three pieces (BVH and distance field): the layers before the
        last multiple of ``PART_BLOCK`` (the block's base, built once per block of layers), those
        after it up to the last multiple of ``PART_SUB`` (built once per ``PART_SUB`` layers) and the
        few after that (built once per layer); rebuilding the whole part every layer is quadratic in
        the layers, and so was the base's tail of up to 15 layers rebuilt every layer (the kitten
        0.8's scene building: 120 layer builds a block of 16 with two pieces, 48 with three; more
        pieces cost more in every query than they save). The pieces of the last ``KEPT_BASES``
        bases are kept, so a task whose layers straddle a block boundary, asked for its layers
        again (the jerk stage after the graph search), builds nothing twice."""
        earlier = layers[: max(layer - 1, 0)]
        cut = len(earlier) // PART_BLOCK * PART_BLOCK
        mid = cut + (len(earlier) - cut) // PART_SUB * PART_SUB
        base = tuple(id(m) for m in earlier[:cut] if len(m.faces))
        if base not in self._pieces:
            self._pieces[base] = {}
            for old in list(self._pieces)[:-KEPT_BASES]:
                del self._pieces[old]
        kept = self._pieces[base]
        pieces = []
        # the last piece's distance field is that of its whole group of PART_SUB layers, built once for
        # the up to PART_SUB - 1 pieces of the group (on the bunny the field, not the BVH, is most of a
        # small piece's cost: 0.2-0.3 s on a curved layer's grid of 2M cells): the layer being planned and
        # those after it in the group only loosen the bound where the extruder's bodies are near them
        group = [m for m in layers[mid: mid + PART_SUB] if len(m.faces)]
        for run, field_layers in ((earlier[:cut], None), (earlier[cut:mid], None), (earlier[mid:], group)):
            run = [m for m in run if len(m.faces)]
            if not run:
                continue
            key = tuple(id(m) for m in run)
            if key not in kept:
                bounds = None
                if field_layers is not None and self.bounds is not None:
                    field_key = ("field",) + tuple(id(m) for m in field_layers)
                    if field_key not in kept:
                        kept[field_key] = self._field(trimesh.util.concatenate(field_layers))
                    bounds = kept[field_key]
                kept[key] = self._piece(trimesh.util.concatenate(run), bounds)
            pieces.append(kept[key])
        self._carry(pieces)
        return self

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
        # per pair: its first body as a carried body's index and its second as a static one's (a carried /
        # static pair has both in range: 0 <= carried < C, static >= 0)
        self._carried_of, self._static_of = self.pairs[:, 0] - L, self.pairs[:, 1] - (L + C)
        self._carried_static = np.flatnonzero((self._carried_of >= 0) & (self._carried_of < C) & (self._static_of >= 0))
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

    def collisions(self, q: np.ndarray, chunk: int = 4096) -> np.ndarray:
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
        for T_inv, half, s in self._boxes:  # only where a link may touch that static box
            links = np.zeros((len(q), L), bool)
            column = np.flatnonzero((a < L) & (b == first_static + s))
            links[:, a[column]] = near[:, column]
            rows = np.flatnonzero(~hit & links.any(axis=1))
            if len(rows):
                hit[rows] = self._inside_box(poses[rows], T_inv, half, links[rows])
        self.fcl_configs += int((near.any(axis=1) & ~hit).sum())
        # carried-vs-static pairs depend on the relative pose only (_relative_answers)
        carried_static = (a >= L) & (a < first_static) & (b >= first_static)
        order = np.argsort(-self._hits, kind="stable")  # the pairs found in contact most often first
        platform_inverse = None
        live = carried_static & near.any(axis=0)
        for k in order[live[order]]:
            rows = np.flatnonzero(near[:, k] & ~hit)
            if not len(rows):
                continue
            if platform_inverse is None:
                platform_inverse = rigid_inverse(poses[:, L])
            hit[rows] |= self._relative_answers(k, poses[rows, L], platform_inverse[rows])
        self._test(poses, near, np.flatnonzero(~hit & near[:, ~carried_static].any(axis=1)),
                   np.flatnonzero(~carried_static), out=hit)
        return hit

    def _relative_answers(self, k: int, placed: np.ndarray, inverse: np.ndarray) -> np.ndarray:
        """(n,) bool: fcl's answer for pair ``k`` (a carried body against a static one) with the
        platform placed at T_B^P ``placed`` (n, 4, 4) (``inverse``: their inverses). It depends on
        the static body's pose in the platform frame only (a cylinder or cone: its axis and centre),
        so fcl tests each distinct one once (µm, µrad) and the answers are remembered while that
        body is carried: :meth:`collisions` and :meth:`held_blocked` (one nozzle frame, every IK
        branch) share them."""
        c, s = self._carried_of[k], self._static_of[k]
        T = inverse @ self.static_poses[s]  # the static body in the platform frame
        out = np.zeros(len(T), bool)
        rows = np.arange(len(T))
        if self._sweeps[s] is not None:  # first its sweep (rotation_sweep), one answer for every θ
            obj, offset = self._sweeps[s]
            rows = rows[self._remembered(c, ("sweep", s), (T @ offset)[:, :3, 2:], placed,
                                         lambda P: self._test_pair(P, k, obj))]
            if not len(rows):
                return out
            T, placed = T[rows], placed[rows]
        out[rows] = self._remembered(c, s, T[:, :3, 2:] if self._symmetric[s] else T[:, :3, :], placed,
                                     lambda P: self._test_pair(P, k))
        return out

    def _remembered(self, c: int, name, key: np.ndarray, placed: np.ndarray,
                    test: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        """(n,) bool: the remembered answers ``self._answers[c][name]`` by ``key`` (n, ...) (a static
        body's pose in the platform frame, µm and µrad), ``test`` on the carried body ``placed`` at the
        first row of each new one."""
        first, group, names = _distinct(_rounded(key))
        known = self._answers[c].setdefault(name, {})
        found = np.array([known.get(name, -1) for name in names], np.int8)
        todo = np.flatnonzero(found < 0)
        if len(todo):
            found[todo] = test(placed[first[todo]])
            known.update(zip([names[i] for i in todo], found[todo].tolist()))
        return found[group] > 0

    def _test_pair(self, placed: np.ndarray, k: int, fixed: fcl.CollisionObject | None = None) -> np.ndarray:
        """fcl on pair ``k`` (a carried body against a static one), the carried body at ``placed``
        (n, 4, 4); with ``fixed``, against that placed object instead (a static body's sweep)."""
        pa, pb = self.pairs[k]
        moving = self.shapes[pa].obj
        other = self.shapes[pb].obj if fixed is None else fixed
        request = fcl.CollisionRequest()
        found = np.zeros(len(placed), bool)
        for r, T in enumerate(placed):
            _set(moving, T)
            found[r] = fcl.collide(moving, other, request, fcl.CollisionResult())
        if fixed is None:
            self._hits[k] += found.sum()
        return found

    def _inside_box(self, poses: np.ndarray, T_inv: np.ndarray, half: np.ndarray,
                    links: np.ndarray | None = None) -> np.ndarray:
        """(n,) bool: a robot link surely meets the static box (T_inv: base to box frame, half
        extents; ``links`` (n, L) bool: the links to look at, default all): one of its vertices lies
        inside the box, or a connected piece of its mesh whose bounding sphere stays within the box's
        footprint has vertices on both sides of the box's slab, so its surface crosses the solid box.
        Either is a contact fcl reports for that checked pair: a cheap, exact witness for the most
        common collision (an elbow-down branch through the table)."""
        links = np.ones((len(poses), len(self.links)), bool) if links is None else links
        row, piece = np.nonzero(links[:, self._probe_link])
        M = T_inv @ poses[row, self._probe_link[piece]]  # (m, 4, 4): link pieces in the box frame
        local = M[:, :3, :3] @ np.swapaxes(self._probe[piece], 1, 2) + M[:, :3, 3:]  # (m, 3, V)
        inside = (np.abs(local) < half[:, None] - 1e-6).all(axis=1).any(axis=1)
        c = (M[:, :3, :3] @ self._sphere[piece, :3, None])[..., 0] + M[:, :3, 3]
        within = (np.abs(c[:, :2]) + self._sphere[piece, 3:] < half[:2]).all(axis=-1)
        z = local[:, 2]
        across = within & (z.min(axis=1) < half[2] - 1e-6) & (z.max(axis=1) > -half[2] + 1e-6)
        out = np.zeros(len(poses), bool)
        out[row[inside | across]] = True
        return out

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
        near = _boxes_overlap(centre, reach, a, b)
        if self.bounds is not None and len(poses) >= BOUNDS_BATCH:
            near &= ~self.bounds.apart(poses, self.pairs, near)
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

    def colliding_pairs(self, q: np.ndarray) -> list:
        """Names of all pairs in contact at one configuration (6,) (for reports and the verifier);
        for configurations (n, 6), a list per configuration (their poses found at once)."""
        q = np.asarray(q, float)
        poses = self._poses(np.atleast_2d(q))
        near = self._near(poses)  # pairs whose world-aligned boxes overlap (the others cannot touch)
        n_moving = len(self.shapes) - len(self.static)
        request = fcl.CollisionRequest()
        out = []
        for pose, live in zip(poses, near):
            for body in range(n_moving):
                _set(self.shapes[body].obj, pose[body])
            out.append([(self.shapes[pa].name, self.shapes[pb].name) for pa, pb in self.pairs[live]
                        if fcl.collide(self.shapes[pa].obj, self.shapes[pb].obj, request, fcl.CollisionResult())])
        return out[0] if q.ndim == 1 else out
