"""Trimming a working surface by the solid H (thesis §3.4.5, step 3 of :mod:`curvslice.working_surfaces`).

Vertices are classified by a signed distance to ∂H: the exact distance to the closest triangle, signed
by the winding number of a +z ray (:class:`~curvslice.voxelize.RayWinding`, the voxelizer's nonzero
rule), which stays right where ∂H crosses itself or shells overlap -- there the closest feature's
pseudonormal (Bærentzen & Aanæs 2005) can lie on a sheet inside H (the cow's skin) and say "outside"
inside H or "inside" outside it. A point in a voxel that ∂H does not touch takes that voxel's side
(:class:`VoxelSides`) without a ray. Triangles are clipped along the zero set and every new boundary
vertex is placed on ∂H by regula falsi.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from curvslice.errors import CurvsliceError
from curvslice.voxelize import RayWinding, centres_inside, surface_voxels

#: Vertices within this distance of ∂H (in voxel widths) are snapped onto ∂H (no slivers).
SNAP = 0.01
#: Regula falsi stops within this distance of ∂H (voxel widths); the vertex then moves onto ∂H.
ROOT_TOL = 0.01
ROOT_ITERATIONS = 40
#: Inside points this close to a sheet of the mesh inside H count this deep (voxel widths): beyond
#: the snap and root tolerances, so neither snaps a layer onto such a sheet nor ends it there.
SHEET = 2 * max(SNAP, ROOT_TOL)


@dataclass(frozen=True)
class SolidDistance:
    """Exact signed distance to a closed, outward-oriented triangle mesh (negative inside).

    The closest triangle comes from k-d trees over triangle centroids, one per radius class so the
    search ball stays tight; the sign from the winding number (inside where it is nonzero), which
    is right also where the mesh crosses itself or its shells overlap.
    """

    triangles: np.ndarray       # (F,3,3)
    normals: np.ndarray         # (F,3) unit face normals
    winding: RayWinding
    step: float                 # offset off a face that probes the winding number on either side
    centroids: np.ndarray
    radii: np.ndarray
    trees: tuple[tuple[cKDTree, np.ndarray, float], ...]
    all_tree: cKDTree

    @classmethod
    def of(cls, mesh: trimesh.Trimesh) -> SolidDistance:
        if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
            raise CurvsliceError("the solid must be a closed, outward-oriented mesh to trim layers by it; "
                                 "re-run the solid stage (solid.stl) or repair the model")
        tri = np.asarray(mesh.triangles, float)
        nf = len(tri)
        centroids = tri.mean(axis=1)
        radii = np.linalg.norm(tri - centroids[:, None, :], axis=2).max(axis=1)
        bound = 1.5 * float(np.median(radii))
        trees = []
        remaining = np.arange(nf)
        while len(remaining):
            sel = remaining[radii[remaining] <= bound] if radii[remaining].max() > bound else remaining
            if len(sel):
                trees.append((cKDTree(centroids[sel]), sel, float(radii[sel].max())))
            remaining = np.setdiff1d(remaining, sel, assume_unique=True)
            bound *= 2
        step = 1e-7 * float(np.ptp(tri.reshape(-1, 3), axis=0).max())
        return cls(tri, np.asarray(mesh.face_normals, float), RayWinding.of(tri), step, centroids, radii,
                   tuple(trees), cKDTree(centroids))

    def __call__(self, points: np.ndarray, sheet: float = 0.0, side: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (n,) and closest points (n,3) on the mesh; ``side`` (n,), where nonzero,
        is each point's side known in advance (−1 inside, +1 outside), which spares its ray.

        With ``sheet`` > 0, an inside point within ``sheet`` of a sheet of the mesh that lies inside H
        (the winding number is nonzero on both of its sides: a skin crossing into the solid, the
        doubled part of overlapping shells) is at −``sheet``: inside, but not on ∂H -- its distance to
        ∂H is at least that, and the trimming must neither snap it nor end a layer there."""
        p = np.asarray(points, float).reshape(-1, 3)
        if len(p) == 0:
            return np.zeros(0), np.zeros((0, 3))
        k = min(4, len(self.centroids))
        _, near = self.all_tree.query(p, k=k)
        near = near.reshape(len(p), k)
        owner = np.repeat(np.arange(len(p)), k)
        best = self._best(p, owner, near.ravel())
        upper = np.sqrt(best[0])
        for tree, ids, rmax in self.trees:
            hits = tree.query_ball_point(p, upper + rmax, return_sorted=False)
            counts = np.fromiter(map(len, hits), np.int64, len(hits))
            if counts.sum() == 0:
                continue
            cand = ids[np.fromiter(itertools.chain.from_iterable(hits), np.int64, int(counts.sum()))]
            own = np.repeat(np.arange(len(p)), counts)
            gap = np.linalg.norm(p[own] - self.centroids[cand], axis=1) - self.radii[cand]
            keep = gap <= upper[own]
            best = self._best(p, own[keep], cand[keep], best)
        d2, q, tri = best
        d = np.sqrt(d2)
        inside = np.zeros(len(p), bool) if side is None else np.asarray(side) < 0
        ray = np.ones(len(p), bool) if side is None else np.asarray(side) == 0
        inside[ray] = self.winding(p[ray]) != 0
        probe = np.flatnonzero(inside & (d <= sheet))
        if len(probe):
            off = self.step * self.normals[tri[probe]]
            within = (self.winding(q[probe] + off) != 0) & (self.winding(q[probe] - off) != 0)
            d[probe[within]] = np.maximum(d[probe[within]], sheet)
        return np.where(inside, -d, d), q

    def _best(self, p: np.ndarray, owner: np.ndarray, cand: np.ndarray,
              previous: tuple[np.ndarray, ...] | None = None) -> tuple[np.ndarray, ...]:
        """Fold candidate (point, triangle) pairs into the running best per point."""
        if previous is not None and len(owner) == 0:
            return previous
        q = trimesh.triangles.closest_point(self.triangles[cand], p[owner])
        d2 = np.einsum("ij,ij->i", p[owner] - q, p[owner] - q)
        order = np.lexsort((d2, owner))
        first = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]
        if previous is None:
            d2_out, q_out, tri_out = np.full(len(p), np.inf), np.zeros((len(p), 3)), np.zeros(len(p), np.int64)
        else:
            d2_out, q_out, tri_out = (x.copy() for x in previous)
        rows = owner[first]
        better = d2[first] < d2_out[rows]
        rows, first = rows[better], first[better]
        d2_out[rows], q_out[rows], tri_out[rows] = d2[first], q[first], cand[first]
        return d2_out, q_out, tri_out


@dataclass(frozen=True)
class VoxelSides:
    """Per voxel of the field grid: −1 entirely inside H, +1 entirely outside, 0 touched by ∂H."""

    side: np.ndarray
    origin: np.ndarray
    voxel_size: float

    @classmethod
    def of(cls, solid: trimesh.Trimesh, origin: np.ndarray, voxel_size: float,
           shape: tuple[int, int, int]) -> VoxelSides:
        tri = np.asarray(solid.triangles, float)
        touched = surface_voxels(tri, origin, voxel_size, shape)
        inside = centres_inside(tri, origin, voxel_size, shape)
        side = np.where(touched, 0, np.where(inside, -1, 1)).astype(np.int8)
        return cls(side, np.asarray(origin, float), float(voxel_size))

    def __call__(self, points: np.ndarray) -> np.ndarray:
        ijk = np.rint((points - self.origin) / self.voxel_size).astype(np.int64)
        inside_grid = ((ijk >= 0) & (ijk < self.side.shape)).all(axis=1)
        out = np.ones(len(points), np.int8)  # beyond the grid: outside H̄ ⊇ H
        i = ijk[inside_grid]
        out[inside_grid] = self.side[i[:, 0], i[:, 1], i[:, 2]]
        return out

    def signed(self, distance: SolidDistance, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``distance(points)`` with the sign of every point in a voxel untouched by ∂H taken from
        that voxel: the whole voxel lies on one side (the same nonzero rule as the distance's sign,
        so a safeguard that keeps trimming in bulk right whatever sign a distance gives off ∂H)."""
        side = self(points)
        d, q = distance(points, SHEET * self.voxel_size, side)
        return np.where(side != 0, side * np.abs(d), d), q


def trim_by_solid(vertices: np.ndarray, faces: np.ndarray, distance: SolidDistance,
                  sides: VoxelSides) -> tuple[np.ndarray, np.ndarray]:
    """Keep the part of a triangle mesh inside H (§3.4.5, Fig. 3.8b): triangles are clipped along
    the zero set of the signed distance, new vertices lie on ∂H; orientation is preserved."""
    if len(faces) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    w = sides.voxel_size
    v = np.array(vertices, float)
    side = sides(v)
    exact = side == 0  # in a voxel touched by ∂H: needs the exact value
    sd = np.where(exact, np.nan, np.where(side > 0, np.inf, -np.inf))
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    keys, e_inv = np.unique(edges[:, 0] * len(v) + edges[:, 1], return_inverse=True)
    uniq = np.stack([keys // len(v), keys % len(v)], axis=1)
    e_inv = e_inv.reshape(-1)
    crossing_edges = np.sign(sd[uniq[:, 0]]) != np.sign(sd[uniq[:, 1]])
    exact[uniq[crossing_edges].ravel()] = True  # endpoints of possible crossings need the value
    d, q = sides.signed(distance, v[exact])
    sd[exact] = d
    on = np.abs(sd) <= SNAP * w
    v[np.flatnonzero(exact)[np.abs(d) <= SNAP * w]] = q[np.abs(d) <= SNAP * w]
    sd[on] = 0.0
    s = np.sign(sd)

    # new vertices where an edge goes strictly from inside to outside: regula falsi (Illinois)
    cross = (s[uniq[:, 0]] * s[uniq[:, 1]]) < 0
    ce = uniq[cross]
    a, b = v[ce[:, 0]], v[ce[:, 1]]
    fa, fb = sd[ce[:, 0]], sd[ce[:, 1]]
    x = a.copy()
    todo = np.ones(len(ce), bool)
    side_kept = np.zeros(len(ce), np.int8)
    for _ in range(ROOT_ITERATIONS):
        if not todo.any():
            break
        i = np.flatnonzero(todo)
        t = fa[i] / (fa[i] - fb[i])
        xi = a[i] + t[:, None] * (b[i] - a[i])
        fx, qx = sides.signed(distance, xi)
        x[i] = xi
        done = np.abs(fx) <= ROOT_TOL * w
        x[i[done]] = qx[done]
        # Illinois: halve the value kept twice in a row
        left = np.sign(fx) == np.sign(fa[i])
        a[i[left]], fa[i[left]] = xi[left], fx[left]
        b[i[~left]], fb[i[~left]] = xi[~left], fx[~left]
        halve_b = left & (side_kept[i] == 1)
        halve_a = ~left & (side_kept[i] == -1)
        fb[i[halve_b]] *= 0.5
        fa[i[halve_a]] *= 0.5
        side_kept[i] = np.where(left, 1, -1)
        todo[i[done]] = False
    if todo.any():
        _, qx = distance(x[todo])
        x[todo] = qx  # not converged (ill-conditioned); the closest point of ∂H is the best estimate
    new_id = np.full(len(uniq), -1, np.int64)
    new_id[cross] = len(v) + np.arange(cross.sum())
    v = np.concatenate([v, x])

    # Sutherland-Hodgman per triangle: slots (corner k, crossing on edge k), k = 0, 1, 2
    keep_corner = s[faces] <= 0
    slots = np.full((len(faces), 6), -1, np.int64)
    slots[:, 0::2] = np.where(keep_corner, faces, -1)
    slots[:, 1::2] = new_id[e_inv].reshape(-1, 3)
    order = np.argsort(slots < 0, axis=1, kind="stable")
    poly = np.take_along_axis(slots, order, axis=1)
    count = (poly >= 0).sum(axis=1)
    tris = [poly[count >= j + 2][:, [0, j, j + 1]] for j in (1, 2, 3)]  # fan: (0,1,2), (0,2,3), (0,3,4)
    out = np.concatenate(tris)
    used, out = np.unique(out, return_inverse=True)
    return v[used], out.reshape(-1, 3)
