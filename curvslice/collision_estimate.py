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
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from curvslice.kinematics import Robot, fk, ik
from curvslice.workcell import Body, Workcell, flange_poses, waypoints_from_flange

SQRT3_2 = np.sqrt(3.0) / 2


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


def axis_spheres(mesh: trimesh.Trimesh, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` spheres along a body's principal axis (a robot link is long and round) whose union
    contains every triangle: the triangles (split to edges ≤ half a slab) are split into ``count`` slabs by the projection of their
    centroid on the axis; a slab's sphere is centred in its vertices' bounding box and reaches its
    farthest vertex."""
    v = np.asarray(mesh.vertices, float)
    axis = np.linalg.svd(v - v.mean(axis=0), full_matrices=False)[2][0]
    v, f = trimesh.remesh.subdivide_to_size(v, np.asarray(mesh.faces), np.ptp(v @ axis) / count / 2)
    tri = v[f]
    t = tri.mean(axis=1) @ axis
    group = np.minimum(((t - t.min()) / (np.ptp(t) + 1e-12) * count).astype(int), count - 1)
    centre, radius = [], []
    for g in np.unique(group):
        pts = tri[group == g].reshape(-1, 3)
        c = (pts.min(axis=0) + pts.max(axis=0)) / 2
        centre.append(c)
        radius.append(np.linalg.norm(pts - c, axis=1).max())
    return np.array(centre), np.array(radius)


def _body_mesh(body: Body) -> trimesh.Trimesh:
    if body.kind == "box":
        return trimesh.creation.box(body.dims)
    r, h = body.dims
    if body.kind == "cylinder":
        return trimesh.creation.cylinder(radius=r, height=h, sections=32)
    cone = trimesh.creation.cone(radius=r, height=h, sections=32)  # base at z = 0, apex at +h
    cone.apply_translation([0, 0, -h / 2])  # centred like fcl's cone
    return cone


def _primitive_distance(body: Body, x: np.ndarray) -> np.ndarray:
    """Lower bound on the distance from points x (..., 3), body frame, to the solid body (exact for
    boxes and cylinders; a cone is measured by its bounding cylinder)."""
    if body.kind == "box":
        return np.linalg.norm(np.maximum(np.abs(x) - np.asarray(body.dims) / 2, 0.0), axis=-1)
    r, h = body.dims
    radial = np.maximum(np.linalg.norm(x[..., :2], axis=-1) - r, 0.0)
    axial = np.maximum(np.abs(x[..., 2]) - h / 2, 0.0)
    return np.hypot(radial, axial)


@dataclass
class _DistanceGrid:
    """Lower bound of the unsigned distance to a triangle soup, from an EDT on cells of size h."""

    origin: np.ndarray
    h: float
    edt: np.ndarray  # distance (mm) from each cell centre to the nearest marked cell centre
    slack: float  # cell half-diagonal + triangle sampling distance

    def __call__(self, x: np.ndarray) -> np.ndarray:
        shape = np.array(self.edt.shape)
        u = (x - self.origin) / self.h - 0.5  # continuous cell-centre index
        idx = np.clip(np.rint(u), 0, shape - 1).astype(np.int64)
        centre = self.origin + (idx + 0.5) * self.h
        inside = self.edt[idx[..., 0], idx[..., 1], idx[..., 2]] - self.slack - np.linalg.norm(x - centre, axis=-1)
        lo, hi = self.origin, self.origin + shape * self.h  # every triangle lies inside this box
        outside = np.linalg.norm(np.maximum(np.maximum(lo - x, x - hi), 0.0), axis=-1)
        return np.maximum(inside, outside)


def distance_grid(mesh: trimesh.Trimesh, h: float) -> _DistanceGrid:
    """The conservative distance field of a mesh's triangles (cell size ``h`` mm)."""
    v, f = trimesh.remesh.subdivide_to_size(np.asarray(mesh.vertices, float), np.asarray(mesh.faces), h / 2)
    origin = v.min(axis=0) - 2 * h
    shape = np.ceil((v.max(axis=0) + 2 * h - origin) / h).astype(int) + 1
    marked = np.zeros(shape, bool)
    idx = np.floor((v - origin) / h).astype(np.int64)
    marked[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    edt = distance_transform_edt(~marked) * h
    # every triangle point is within h/2 of a vertex (edges ≤ h/2) and a vertex within SQRT3_2 h of its cell centre
    return _DistanceGrid(origin, h, edt, SQRT3_2 * h + h / 2)


class SphereBounds:
    """Per-pair lower bounds on the distance between the bodies of a :class:`CollisionScene`
    (same body order: links, carried platform [and part], static extruder and obstacle bodies)."""

    def __init__(self, robot: Robot, cell: Workcell, platform: trimesh.Trimesh, link_spheres: int = 8,
                 static_cell: float = 4.0, platform_cell: float = 20.0, part_cell: float = 6.0, grid: float = 0.8):
        self.robot = robot
        self.static_bodies = list(cell.extruder) + list(cell.obstacles)
        self.link_spheres = [axis_spheres(s.mesh, link_spheres) for s in robot.links]
        # huge obstacles (a table) would need huge spheres: their exact distance is used instead
        self.static_spheres = [sphere_cover(_body_mesh(b), max(static_cell, max(b.dims) / 6)) if max(b.dims) <= 200
                               else None for b in self.static_bodies]
        hull = platform.convex_hull
        planes = np.c_[hull.face_normals, np.einsum("ij,ij->i", hull.face_normals, hull.triangles[:, 0])]
        planes = np.unique(np.round(planes, 9), axis=0)  # one plane per facet
        self.planes = (planes[:, :3], planes[:, 3])
        self.carried_spheres = [sphere_cover(hull, platform_cell)]
        self.carried_distance = [self._hull_distance]
        self.part_cell, self.grid = part_cell, grid

    def _hull_distance(self, x: np.ndarray) -> np.ndarray:
        n, d = self.planes
        return np.maximum(x @ n.T - d, 0.0).max(axis=-1)

    def set_part(self, mesh: trimesh.Trimesh | None, shapes: int = 1) -> None:
        """The printed part (model frame P), or ``None``; the scene carries it as ``shapes`` bodies
        (pieces of it), each bounded here by the whole part (a piece is no nearer than the whole)."""
        del self.carried_spheres[1:], self.carried_distance[1:]
        if mesh is not None and len(mesh.faces):
            self.carried_spheres += [sphere_cover(mesh, self.part_cell)] * shapes
            self.carried_distance += [distance_grid(mesh, self.grid)] * shapes

    def pair_bounds(self, poses: np.ndarray, pairs: np.ndarray) -> np.ndarray:
        """(n, len(pairs)) lower bounds (mm; ≤ 0: maybe touching) for body poses (n, bodies, 4, 4)
        as built by :meth:`CollisionScene._poses`."""
        L, C = len(self.link_spheres), len(self.carried_spheres)
        inv = {}

        def local(body: int, x: np.ndarray) -> np.ndarray:  # world points (n, S, 3) in a body's frame
            if body not in inv:
                T = poses[:, body]
                R = np.swapaxes(T[:, :3, :3], 1, 2)
                inv[body] = (R, -np.einsum("nij,nj->ni", R, T[:, :3, 3]))
            R, t = inv[body]
            return np.einsum("nij,nsj->nsi", R, x) + t[:, None]

        world = {}

        def spheres(body: int) -> tuple[np.ndarray, np.ndarray] | None:
            if body not in world:
                cover = (self.link_spheres[body] if body < L else self.carried_spheres[body - L] if body < L + C
                         else self.static_spheres[body - L - C])
                if cover is None:
                    world[body] = None
                else:
                    T = poses[:, body]
                    world[body] = (np.einsum("nij,sj->nsi", T[:, :3, :3], cover[0]) + T[:, None, :3, 3], cover[1])
            return world[body]

        def distance(body: int, x: np.ndarray) -> np.ndarray:  # to a carried or static body
            if body >= L + C:
                return _primitive_distance(self.static_bodies[body - L - C], x)
            return self.carried_distance[body - L](x)

        out = np.full((len(poses), len(pairs)), -np.inf)
        for k, (a, b) in enumerate(pairs):
            if a < L and b < L:  # link-link: sphere against sphere
                sa, sb = spheres(a), spheres(b)
                d = np.linalg.norm(sa[0][:, :, None] - sb[0][:, None], axis=-1) - sa[1][:, None] - sb[1][None]
                out[:, k] = d.min(axis=(1, 2))
            elif b >= L + C:  # moving-static: the moving spheres against the static body's distance
                sa = spheres(a)
                out[:, k] = (distance(b, local(b, sa[0])) - sa[1]).min(axis=1)
                sb = spheres(b)
                if a >= L and sb is not None:  # carried-static: also the static spheres against the carried field
                    out[:, k] = np.maximum(out[:, k], (distance(a, local(a, sb[0])) - sb[1]).min(axis=1))
            else:  # carried-link: the link spheres against the carried body's distance
                link, carried = (a, b) if a < L else (b, a)
                s = spheres(link)
                out[:, k] = (distance(carried, local(carried, s[0])) - s[1]).min(axis=1)
        return out


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
