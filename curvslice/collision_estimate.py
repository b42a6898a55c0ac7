"""Fast collision estimation beside the exact fcl check (thesis §4.4).

Two estimators, both answering "surely free" or "maybe colliding" for arm configurations:

* :class:`SphereBounds`, a conservative geometric proxy: every robot link, carried body (platform,
  part) and static body (extruder, obstacles) is covered by spheres (each sphere contains whole
  triangles, so the cover contains the body); static bodies also have their exact distance function
  (box, cylinder; a cone by its bounding cylinder), the platform its hull planes and the printed part
  an unsigned distance field (``scipy.ndimage.distance_transform_edt`` of the cells its surface
  touches, minus the cell and sampling slack). A checked pair whose lower bound on the distance is
  positive cannot touch, so fcl is asked only about the other pairs: no false "free" by construction.
* :class:`LearnedCollision`, the thesis's collision-indication function (§4.4, Algorithm 7): an RBF
  support-vector machine (scikit-learn ``SVC``) trained per layer on samples centred on contact
  configurations, its bias shifted to the safe side until every colliding training sample is
  classified as colliding.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.cluster.vq import kmeans2
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from curvslice.kinematics import Robot, fk, ik, rigid_inverse
from curvslice.workcell import Body, Workcell, flange_poses, waypoints_from_flange

SQRT3_2 = np.sqrt(3.0) / 2
#: mm of clearance a lower bound must show before a pair counts as apart (fcl's own tolerances are far smaller)
CLEARANCE = 1e-3


def sphere_cover(mesh: trimesh.Trimesh, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """Spheres (centres (S, 3), radii (S,)) whose union contains every triangle of ``mesh``: the
    triangles (split to edges ≤ cell / 2) are grouped by the cell of their centroid; a group's sphere
    is centred in its cell and reaches its farthest vertex (a ball holding a triangle's corners holds
    the triangle)."""
    v, f = trimesh.remesh.subdivide_to_size(np.asarray(mesh.vertices, float), np.asarray(mesh.faces), cell / 2)
    tri = v[f]
    key = np.floor(tri.mean(axis=1) / cell).astype(np.int64)
    cells, group = np.unique(key, axis=0, return_inverse=True)
    group = group.ravel()
    centre = (cells + 0.5) * cell
    reach = np.linalg.norm(tri - centre[group][:, None], axis=2).max(axis=1)
    radius = np.zeros(len(cells))
    np.maximum.at(radius, group, reach)
    return centre, radius


def cluster_spheres(mesh: trimesh.Trimesh, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` spheres whose union contains every triangle of a link mesh: the triangles (split to
    edges ≤ 1/8 of the mesh's size) grouped by k-means of their centroids
    (``scipy.cluster.vq.kmeans2``); a group's sphere is centred in its vertices' bounding box and
    reaches its farthest vertex."""
    v = np.asarray(mesh.vertices, float)
    v, f = trimesh.remesh.subdivide_to_size(v, np.asarray(mesh.faces), float(np.ptp(v, axis=0).max()) / 8)
    tri = v[f]
    _, group = kmeans2(tri.mean(axis=1), count, minit="++", seed=0)
    centre, radius = [], []
    for g in np.unique(group):
        pts = tri[group == g].reshape(-1, 3)
        c = (pts.min(axis=0) + pts.max(axis=0)) / 2
        centre.append(c)
        radius.append(np.linalg.norm(pts - c, axis=1).max())
    return np.array(centre), np.array(radius)


def bounding_sphere(mesh: trimesh.Trimesh) -> tuple[np.ndarray, float]:
    """A sphere (centre, radius) holding every vertex (so every triangle) of ``mesh``."""
    v = np.asarray(mesh.vertices, float)
    c = (v.min(axis=0) + v.max(axis=0)) / 2
    return c, float(np.linalg.norm(v - c, axis=1).max())


def _primitive_distance(body: Body, x: np.ndarray) -> np.ndarray:
    """Lower bound on the distance from points x (..., 3), body frame, to the solid body (exact for
    boxes and cylinders; a cone is measured by its bounding cylinder)."""
    if body.kind == "box":
        return np.linalg.norm(np.maximum(np.abs(x) - np.asarray(body.dims) / 2, 0.0), axis=-1)
    r, h = body.dims
    radial = np.maximum(np.linalg.norm(x[..., :2], axis=-1) - r, 0.0)
    axial = np.maximum(np.abs(x[..., 2]) - h / 2, 0.0)
    return np.hypot(radial, axial)


def support(body: Body, v: np.ndarray) -> np.ndarray:
    """Support function max_{x ∈ body} v·x of the solid primitive (body frame, centred like fcl's:
    a cone's base at z = -h/2, its apex at +h/2) for directions v (..., 3)."""
    if body.kind == "box":
        return np.abs(v) @ (np.asarray(body.dims, float) / 2)
    r, h = body.dims
    side = r * np.linalg.norm(v[..., :2], axis=-1)
    if body.kind == "cylinder":
        return h / 2 * np.abs(v[..., 2]) + side
    return np.maximum(h / 2 * v[..., 2], -h / 2 * v[..., 2] + side)


def solid_cover(body: Body, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Spheres (centres (m, 3), radii (m,), body frame) whose union contains the SOLID primitive (a
    printed part inside it counts as a contact): a box by a grid of cells (radius: half their
    diagonal), a cylinder or cone by slabs along its axis (radius: the slab's disc and half its
    height)."""
    if body.kind == "box":
        dims = np.asarray(body.dims, float)
        counts = np.ceil(dims / spacing).astype(int)
        step = dims / counts
        axes = [-d / 2 + (np.arange(k) + 0.5) * s for d, k, s in zip(dims, counts, step)]
        centre = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        return centre, np.full(len(centre), np.linalg.norm(step) / 2)
    r, h = body.dims
    k = int(np.ceil(h / spacing))
    z = -h / 2 + (np.arange(k) + 0.5) * h / k
    reach = np.full(k, r) if body.kind == "cylinder" else r * (h / 2 - (z - h / (2 * k))) / h  # cone: widest at its slab's bottom
    return np.c_[np.zeros((k, 2)), z], np.hypot(reach, h / (2 * k))


@dataclass
class _DistanceGrid:
    """Lower bound of the unsigned distance to a triangle soup, from an EDT on cells of size h."""

    origin: np.ndarray
    h: float
    edt: np.ndarray  # distance (mm) from each cell centre to the nearest marked cell centre
    slack: float  # how far a surface point can be from its marked cell's centre

    def __call__(self, x: np.ndarray) -> np.ndarray:
        p = x.reshape(-1, 3)
        u = (p - self.origin) / self.h  # in cells
        i = np.clip(np.floor(u), 0, np.array(self.edt.shape) - 1)
        f = u - i - 0.5  # from the (nearest) cell's centre, in cells
        flat = np.ravel_multi_index(i.astype(np.intp).T, self.edt.shape)
        inside = self.edt.ravel()[flat] - self.slack - self.h * np.sqrt(np.einsum("ij,ij->i", f, f))
        out = np.maximum(np.maximum(self.origin - p, p - self.top), 0.0)  # every triangle lies in the grid's box
        return np.maximum(inside, np.sqrt(np.einsum("ij,ij->i", out, out))).reshape(x.shape[:-1])

    @property
    def top(self) -> np.ndarray:
        return self.origin + np.array(self.edt.shape) * self.h


def distance_grid(mesh: trimesh.Trimesh, h: float, span: int = 3) -> _DistanceGrid:
    """The conservative distance field of a mesh's triangles (cell size ``h`` mm): every cell a
    triangle's bounding box meets is marked, so each surface point lies in a marked cell (within
    h·√3/2 of its centre); ``scipy.ndimage.distance_transform_edt`` then gives each cell centre's
    distance to the marked ones. Only triangles whose box spans more than ``span`` cells along an
    axis are split first (to edges ≤ h, two cells at most): a model's triangles are mostly about
    a voxel, and splitting them all cost more than the field."""
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    origin = v.min(axis=0) - 2 * h
    shape = np.ceil((v.max(axis=0) + 2 * h - origin) / h).astype(int) + 1
    tri = v[f]
    lo = np.floor((tri.min(axis=1) - origin) / h).astype(np.int64)
    hi = np.floor((tri.max(axis=1) - origin) / h).astype(np.int64)
    big = (hi - lo >= span).any(axis=1)
    if big.any():
        sv, sf = trimesh.remesh.subdivide_to_size(v, f[big], h)
        small = sv[sf]
        lo = np.vstack([lo[~big], np.floor((small.min(axis=1) - origin) / h).astype(np.int64)])
        hi = np.vstack([hi[~big], np.floor((small.max(axis=1) - origin) / h).astype(np.int64)])
    # each triangle marks the cells lo + min(offset, hi - lo): those of the offsets its box reaches on every
    # axis (a clamped offset repeats one of them), written by flat index
    marked = np.zeros(shape, bool)
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    start, extent = lo @ strides, hi - lo
    reaches = [[extent[:, axis] >= o for o in range(span)] for axis in range(3)]
    for offset in np.ndindex(span, span, span):
        keep = reaches[0][offset[0]] & reaches[1][offset[1]] & reaches[2][offset[2]]
        marked.reshape(-1)[start[keep] + int(np.dot(offset, strides))] = True
    return _DistanceGrid(origin, h, _edt(~marked) * h, SQRT3_2 * h)


def _edt(free: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.distance_transform_edt(free)`` (cells), its distances summed from the feature
    transform in integers (the same exact sums of squares, without its float copies of the index grids)."""
    nearest = distance_transform_edt(free, return_distances=False, return_indices=True)
    squared = np.zeros(free.shape, np.int64)
    for axis, n in enumerate(free.shape):
        d = nearest[axis] - np.arange(n, dtype=nearest.dtype).reshape((-1,) + (1,) * (free.ndim - 1 - axis))
        squared += d * d
    return np.sqrt(squared.astype(np.float64))


@dataclass(frozen=True)
class CarriedBounds:
    """What the proxy knows of a carried body (model frame P): the facet planes (n·x ≤ d) and
    vertices of its convex hull (none for a printed part: its hull is not worth the cost) and its
    distance field."""

    normals: np.ndarray
    offsets: np.ndarray
    vertices: np.ndarray
    field: _DistanceGrid


def carried_bounds(mesh: trimesh.Trimesh, grid: float, hull: bool = False) -> CarriedBounds:
    """:class:`CarriedBounds` of a mesh: its distance field (cells of ``grid`` mm), and with
    ``hull`` its convex hull's facets and vertices."""
    planes, vertices = np.zeros((0, 4)), np.zeros((0, 3))
    if hull:
        h = mesh.convex_hull
        planes = np.c_[h.face_normals, np.einsum("ij,ij->i", h.face_normals, h.triangles[:, 0])]
        planes = np.unique(np.round(planes, 9), axis=0)  # one plane per facet
        vertices = np.asarray(h.vertices, float)
    field = convex_grid(planes, vertices, grid) if hull and mesh.is_convex else distance_grid(mesh, grid)
    return CarriedBounds(planes[:, :3], planes[:, 3], vertices, field)


def convex_grid(planes: np.ndarray, vertices: np.ndarray, h: float) -> _DistanceGrid:
    """The distance field of a convex body's surface (facet planes n·x = d (F, 4), vertices) on
    cells of size ``h``, from the planes alone: at a cell centre |max_i(n_i·x − d_i)|, the exact
    distance to the surface inside and a lower bound outside, so no marking slack is needed (the
    platform's field: no surface to split and mark)."""
    origin = vertices.min(axis=0) - 2 * h
    shape = np.ceil((vertices.max(axis=0) + 2 * h - origin) / h).astype(int) + 1
    x, y, z = (origin[k] + (np.arange(shape[k]) + 0.5) * h for k in range(3))
    signed = np.full(tuple(shape), -np.inf)
    for n, d in zip(planes[:, :3], planes[:, 3]):  # one plane at a time: the grid stays in cache
        np.maximum(signed, (n[0] * x - d)[:, None, None] + (n[1] * y)[None, :, None] + (n[2] * z)[None, None, :],
                   out=signed)
    return _DistanceGrid(origin, h, np.abs(signed), 1e-6)  # slack: the planes' rounding


def _transform(T: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Points x (n, ..., 3) moved by the rigid transforms T (n, 4, 4)."""
    Rt = np.swapaxes(T[:, :3, :3], 1, 2).reshape((len(T),) + (1,) * (x.ndim - 3) + (3, 3))
    return x @ Rt + T[:, :3, 3].reshape((len(T),) + (1,) * (x.ndim - 2) + (3,))


class SphereBounds:
    """A conservative, vectorized proof that body pairs of a :class:`~curvslice.collision.CollisionScene`
    are apart (same body order: links, carried platform and part pieces, static bodies), so the
    exact check needs fcl only for the others (§4.4's estimator as a prefilter: no false "free").

    Links are covered by k-means spheres; a link is apart from a static primitive when each sphere
    is farther from it than its radius (exact primitive distance), from a carried body (platform,
    part piece) by the body's distance field. Link pairs: sphere against sphere. Carried-static
    pairs: the platform's hull facets and the static body's own axes as separating axes (support
    functions); a part piece by slabs covering a static cylinder, in the piece's field."""

    def __init__(self, robot: Robot, cell: Workcell, platform: trimesh.Trimesh, spheres: int = 16, slabs: int = 10,
                 platform_grid: float = 1.0):
        link = [cluster_spheres(s.mesh, spheres) for s in robot.links]
        k = max(len(r) for _, r in link)
        self.centres = np.stack([np.vstack([c, c[-1:].repeat(k - len(c), 0)]) for c, _ in link])  # (L, K, 3)
        self.radii = np.stack([np.r_[r, r[-1:].repeat(k - len(r))] for _, r in link])  # (L, K)
        whole = [bounding_sphere(s.mesh) for s in robot.links]
        self.whole = (np.array([c for c, _ in whole]), np.array([r for _, r in whole]))  # (L, 3), (L,)
        self.static = list(cell.extruder) + list(cell.obstacles)
        self.static_poses = np.array([cell.nozzle @ b.pose for b in cell.extruder] + [b.pose for b in cell.obstacles])
        self.static_inverse = rigid_inverse(self.static_poses.reshape(-1, 4, 4))
        # Carried-static pairs are tested only where fcl is slow and its answers are not shared (the
        # scene remembers fcl's answer per relative pose, one per nozzle placement for a cylinder or
        # cone): the platform against boxes, a part piece against cylinders (slabs along the axis in
        # the piece's field).
        self.covers = [solid_cover(b, b.dims[1] / slabs) if b.kind == "cylinder" else None for b in self.static]
        self.platform = carried_bounds(platform, platform_grid, hull=True)
        self.pieces = [self.platform]
        self._groups: dict[bytes, list] = {}

    def set_pieces(self, pieces: list[CarriedBounds]) -> None:
        """The part pieces the scene carries after the platform."""
        self.pieces = [self.platform] + list(pieces)

    def _group(self, pairs: np.ndarray) -> list[tuple]:
        """The pair columns by test: (kind, body, columns, links) with kind "static" (links against
        static body), "carried" (links against carried body), "links" (link pairs), "pair"."""
        key = pairs.tobytes()
        if key not in self._groups:
            L, C = len(self.centres), len(self.pieces)
            groups = []
            for kind, other, test in (("static", lambda x, y: (x < L) & (y >= L + C), 1),
                                      ("carried", lambda x, y: (x >= L) & (x < L + C) & (y < L), 0)):
                mask = other(pairs[:, 0], pairs[:, 1])
                for body in np.unique(pairs[mask, test]):
                    cols = np.flatnonzero(mask & (pairs[:, test] == body))
                    groups.append((kind, int(body), cols, pairs[cols, 1 - test]))
            cols = np.flatnonzero((pairs[:, 0] < L) & (pairs[:, 1] < L))
            groups.append(("links", -1, cols, pairs[cols]))
            for col in np.flatnonzero((pairs[:, 0] >= L) & (pairs[:, 0] < L + C) & (pairs[:, 1] >= L + C)):
                s = pairs[col, 1] - L - C
                if (self.covers[s] is not None) if pairs[col, 0] > L else self.static[s].kind == "box":
                    groups.append(("pair", col, np.array([col]), pairs[col]))
            self._groups[key] = groups
        return self._groups[key]

    def apart(self, poses: np.ndarray, pairs: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """(n, len(pairs)) bool for body poses (n, bodies, 4, 4) as built by
        :meth:`CollisionScene._poses`: True where the pair surely does not touch. With ``rows``
        (n, len(pairs)) bool, only those entries are examined (the others stay False). Each link is
        first tested by its bounding sphere, then (where that fails) by its cover. A link's cover
        centres (base frame, and frame P for the carried bodies) are placed once per row for all the
        bodies it is tested against."""
        n, L, C = len(poses), len(self.centres), len(self.pieces)
        rows = np.ones((n, len(pairs)), bool) if rows is None else rows
        out = np.zeros((n, len(pairs)), bool)
        R, t = poses[:, :L, :3, :3], poses[:, :L, :3, 3]
        whole = (R @ self.whole[0][..., None])[..., 0] + t  # (n, L, 3) bounding-sphere centres
        platform_inverse = rigid_inverse(poses[:, L])
        whole_in_p = None  # the bounding-sphere centres in frame P
        placed = {"B": np.empty((n, L) + self.centres.shape[1:]), "P": np.empty((n, L) + self.centres.shape[1:])}
        known = {"B": np.zeros((n, L), bool), "P": np.zeros((n, L), bool)}

        def spheres(r: np.ndarray, link: np.ndarray, frame: str = "B") -> np.ndarray:
            """Cover centres (m, K, 3) of links at rows, in the base frame B or the platform's P."""
            todo = ~known[frame][r, link]
            if todo.any():
                rr, ll = r[todo], link[todo]
                placed[frame][rr, ll] = self.centres[ll] @ np.swapaxes(R[rr, ll], 1, 2) + t[rr, ll][:, None] \
                    if frame == "B" else _transform(platform_inverse[rr], spheres(rr, ll))
                known[frame][rr, ll] = True
            return placed[frame][r, link]

        for kind, body, cols, other in self._group(pairs):
            r = np.flatnonzero(rows[:, cols].any(axis=1))
            if not len(r):
                continue
            if kind == "pair":
                out[r, cols[0]] = self._carried_static(self.pieces[other[0] - L], other[1] - L - C, platform_inverse[r])
                continue
            if kind == "links":
                a, b = other[:, 0], other[:, 1]
                clear = np.linalg.norm(whole[r][:, a] - whole[r][:, b], axis=-1) - self.whole[1][a] - self.whole[1][b]
            elif kind == "static":
                clear = self._static_clearance(body - L - C, whole[r][:, other], self.whole[1][other])
            else:
                whole_in_p = _transform(platform_inverse, whole) if whole_in_p is None else whole_in_p
                clear = self.pieces[body - L].field(whole_in_p[r][:, other]) - self.whole[1][other]
            ok = clear > CLEARANCE
            i, j = np.nonzero(~ok & rows[r][:, cols])  # the bounding sphere is not enough: the cover
            if len(i):
                if kind == "links":
                    xa, xb = spheres(r[i], other[j, 0]), spheres(r[i], other[j, 1])
                    d = np.linalg.norm(xa[:, :, None] - xb[:, None], axis=-1)
                    fine = (d - self.radii[other[j, 0]][:, :, None] - self.radii[other[j, 1]][:, None]).min(axis=(1, 2))
                elif kind == "static":
                    fine = self._static_clearance(body - L - C, spheres(r[i], other[j]), self.radii[other[j]]).min(axis=1)
                else:
                    fine = (self.pieces[body - L].field(spheres(r[i], other[j], "P")) - self.radii[other[j]]).min(axis=1)
                ok[i, j] = fine > CLEARANCE
            out[np.ix_(r, cols)] = ok
        return out & rows

    def _static_clearance(self, s: int, x: np.ndarray, radius: np.ndarray) -> np.ndarray:
        """Lower bounds on the gap between spheres (centres x (m, ..., 3) in the base frame, radii
        broadcast to them) and static body ``s`` (its exact primitive)."""
        T = self.static_inverse[s]
        return _primitive_distance(self.static[s], x @ T[:3, :3].T + T[:3, 3]) - radius

    def _carried_static(self, piece: CarriedBounds, s: int, platform_inverse: np.ndarray) -> np.ndarray:
        body = self.static[s]
        T = platform_inverse @ self.static_poses[s]  # the static body in frame P
        R, t = T[:, :3, :3], T[:, :3, 3]
        apart = np.zeros(len(T), bool)
        if len(piece.normals):
            # separating axes: the hull's facet normals (min over the body of n·x beyond the facet's d)
            lowest = t @ piece.normals.T - support(body, -(piece.normals @ R))
            apart = (lowest > piece.offsets + CLEARANCE).any(axis=1)
            # and the body's own axes (box faces; the axis of a cylinder or cone) against the hull vertices
            for j in range(3 if body.kind == "box" else 2, 3):
                axis = R[:, :, j]
                e = np.eye(3)[j]
                proj = axis @ piece.vertices.T
                centre = (axis * t).sum(axis=1)
                apart |= (proj.min(axis=1) > centre + support(body, e) + CLEARANCE)
                apart |= (proj.max(axis=1) < centre - support(body, -e) - CLEARANCE)
        cover = self.covers[s]
        if cover is not None:
            r = np.flatnonzero(~apart)
            x = _transform(T[r], cover[0][None])
            apart[r] = (piece.field(x) - cover[1]).min(axis=1) > CLEARANCE
        return apart


THETA_SAMPLES = 72  # θ of a random contact sample is drawn from this many (5°) steps of Eq. 4.3


def contact_configurations(robot: Robot, cell: Workcell, surface: trimesh.Trimesh, count: int,
                           rng: np.random.Generator) -> np.ndarray:
    """Configurations on the contact C-space (§4.4.2, initial sampling): random points of the
    working surface, its normal (turned upwards) as the tool axis, a random θ (Eq. 4.3), every IK
    solution inside the joint limits."""
    points, faces = trimesh.sample.sample_surface(surface, count, seed=int(rng.integers(2**31)))
    normals = surface.face_normals[faces] * np.where(surface.face_normals[faces][:, 2:3] < 0, -1.0, 1.0)
    return _contact(robot, cell, points, normals, rng)


def _contact(robot: Robot, cell: Workcell, points: np.ndarray, normals: np.ndarray,
             rng: np.random.Generator, near: np.ndarray | None = None) -> np.ndarray:
    """IK solutions (inside the limits) realizing waypoints (points, normals) at a random θ; with
    ``near`` (n, 6) one per waypoint, the solution closest to it (the projection of Eq. 4.15)."""
    keep = normals[:, 2] > -1 + 1e-6
    points, normals = points[keep], normals[keep]
    T = flange_poses(cell, points, normals, THETA_SAMPLES)
    n = len(points)
    if near is None:
        T = T[np.arange(n), rng.integers(0, THETA_SAMPLES, n)]
    q, ok = ik(robot, T.reshape(-1, 4, 4))
    lo, hi = cell.limits(robot)
    ok &= ((q >= lo - 1e-12) & (q <= hi + 1e-12)).all(axis=-1)
    if near is None:
        return q[ok]
    q = q.reshape(n, -1, 6)
    d = np.where(ok.reshape(n, -1), np.linalg.norm(_wrap(q - near[keep][:, None]), axis=-1), np.inf)
    best = d.argmin(axis=1)
    found = np.isfinite(d[np.arange(n), best])
    return q[np.arange(n), best][found]


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def project_to_contact(robot: Robot, cell: Workcell, surface: trimesh.Trimesh, q: np.ndarray,
                       rng: np.random.Generator) -> np.ndarray:
    """Υ of Eq. 4.15, approximated: the nozzle tip of FK(q) moved to the closest point of the
    working surface S (tool axis = S's normal there), the IK solution nearest to q (over θ steps)."""
    tip, _ = waypoints_from_flange(cell, fk(robot, q))
    points, _, faces = trimesh.proximity.closest_point(surface, tip)
    normals = surface.face_normals[faces] * np.where(surface.face_normals[faces][:, 2:3] < 0, -1.0, 1.0)
    return _contact(robot, cell, points, normals, rng, near=q)


def contact_centred_samples(robot: Robot, cell: Workcell, surface: trimesh.Trimesh,
                            collides: Callable[[np.ndarray], np.ndarray], initial: int = 300,
                            total: int = 3000, k: int = 20, tau_alpha: float = 0.8, tau_beta: float = 0.05,
                            rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 7: initial samples on the contact C-space, then rounds of up-scaling (a midpoint
    between k-NN farther than τ_α apart) and boundary refinement (between k-NN with different labels
    farther than τ_β apart), half of the new samples projected onto the contact C-space (Eq. 4.15),
    until nothing is added or ``total`` samples exist. Returns samples (n, 6) and labels (n,) bool."""
    rng = rng or np.random.default_rng(0)
    q = contact_configurations(robot, cell, surface, initial, rng)
    label = collides(q)
    while len(q) < total:
        tree = cKDTree(q)
        dist, nn = tree.query(q, k=min(k + 1, len(q)))
        dist, nn = dist[:, 1:], nn[:, 1:]
        far = dist > tau_alpha  # up-scaling
        boundary = (dist > tau_beta) & (label[nn] != label[:, None])  # refinement
        i, j = np.nonzero(far | boundary)
        pairs = np.unique(np.sort(np.c_[np.arange(len(q))[i], nn[i, j]], axis=1), axis=0)
        if len(pairs) == 0:
            break
        rng.shuffle(pairs)
        pairs = pairs[: total - len(q)]
        new = (q[pairs[:, 0]] + q[pairs[:, 1]]) / 2
        half = rng.random(len(new)) >= 0.5
        new = np.vstack([new[~half], project_to_contact(robot, cell, surface, new[half], rng)])
        q = np.vstack([q, new])
        label = np.r_[label, collides(new)]
    return q, label


class LearnedCollision:
    """Γ̃(q) = Σ α_i K(q_i, q) + b (Eq. 4.14), Gaussian kernel γ = 0.7, trained with scikit-learn's
    ``SVC`` on the samples of Algorithm 7; b is raised by ε = 1 (§4.4.1) and further until every
    colliding training sample has Γ̃ ≥ 0 (the safe side). Γ̃ < 0: estimated free."""

    def calibrate(self, samples: np.ndarray, labels: np.ndarray) -> None:
        """Raise the bias further until every colliding configuration of a held-out labelled set has
        Γ̃ ≥ 0 (the training set alone leaves false "free" near it)."""
        if labels.any():
            self.shift = max(self.shift, self.shift - float(self.indication(samples[labels]).min()))

    def __init__(self, samples: np.ndarray, labels: np.ndarray, gamma: float = 0.7, epsilon: float = 1.0):
        from sklearn.svm import SVC  # imported here: only the estimator needs scikit-learn (1-2 s to import)

        self.svm = SVC(kernel="rbf", gamma=gamma, C=10.0).fit(samples, labels.astype(int))
        score = self.svm.decision_function(samples)
        self.shift = max(epsilon, float(-score[labels].min()) if labels.any() else 0.0)
        self.kernels = int(self.svm.support_.size)

    def indication(self, q: np.ndarray) -> np.ndarray:
        """Γ̃ at configurations q (n, 6)."""
        return self.svm.decision_function(np.atleast_2d(q)) + self.shift

    def maybe_colliding(self, q: np.ndarray) -> np.ndarray:
        return self.indication(q) >= 0
