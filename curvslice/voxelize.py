"""Conservative voxelization H ⊂ H̄ (thesis §3.4.1).

The voxel set H̄ must *contain* the solid H so that working surfaces extracted from the grid can
be trimmed back onto ∂H (§3.4.5). A voxel is occupied when

* its centre is inside H (winding number of a +z ray, vectorized per column), or
* the surface ∂H meets the open voxel box (exact triangle-box separating-axis test).

Every point of H then lies in an occupied voxel: either its voxel's centre is inside, or the voxel
holds points inside and outside H and therefore meets ∂H.

Grid convention (the ``field.npz`` contract): voxel (i, j, k) is the box centred at ``origin + w*(i, j, k)``; the
z faces lie on multiples of w so row k = 0 sits on the platform top z = 0; one empty voxel of
padding surrounds the model in x, y and above it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from curvslice.errors import CurvsliceError

#: Bytes per grid cell of the dense per-stage arrays (occupancy, fields, scratch) plus per-voxel
#: working memory of the growing stage; used to refuse grids that cannot fit.
BYTES_PER_CELL = 40
BYTES_PER_VOXEL = 400
DEFAULT_MEMORY_LIMIT = 8 * 2**30
#: Candidate (triangle, voxel) pairs tested per vectorized batch.
PAIR_BATCH = 1_000_000


@dataclass
class VoxelGrid:
    """A dense boolean occupancy grid; voxel (i,j,k) is centred at ``origin + voxel_size*(i,j,k)``."""

    occupied: np.ndarray
    origin: np.ndarray
    voxel_size: float

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.occupied.shape  # type: ignore[return-value]

    def centres(self, ijk: np.ndarray) -> np.ndarray:
        """Centres (n,3) of voxel indices (n,3)."""
        return self.origin + self.voxel_size * np.asarray(ijk, float)

    def occupied_centres(self) -> np.ndarray:
        return self.centres(np.argwhere(self.occupied))


def grid_for(bounds: np.ndarray, voxel_size: float, pad: int = 1) -> tuple[np.ndarray, tuple[int, int, int]]:
    """Origin and shape of the grid covering ``bounds`` (2x3, with z ≥ 0) with ``pad`` empty voxels
    around in x, y and above; the x, y grid is centred on the bounding box."""
    w = float(voxel_size)
    lo, hi = np.asarray(bounds, float)
    nxy = np.maximum(np.ceil((hi[:2] - lo[:2]) / w - 1e-9).astype(int), 1) + 2 * pad
    mid = (lo[:2] + hi[:2]) / 2
    origin_xy = mid - w * nxy / 2 + w / 2
    nz = max(int(np.ceil(hi[2] / w - 1e-9)), 1) + pad
    origin = np.array([origin_xy[0], origin_xy[1], w / 2])
    return origin, (int(nxy[0]), int(nxy[1]), nz)


def estimate_memory(mesh: trimesh.Trimesh, voxel_size: float) -> tuple[int, tuple[int, int, int]]:
    """Bytes the field stages need for ``mesh`` at ``voxel_size``, and the grid shape."""
    _, shape = grid_for(mesh.bounds, voxel_size)
    cells = int(np.prod(np.array(shape, dtype=np.int64)))
    voxels = abs(float(mesh.volume)) / voxel_size**3 + mesh.area / voxel_size**2
    return int(cells * BYTES_PER_CELL + voxels * BYTES_PER_VOXEL), shape


def check_memory(mesh: trimesh.Trimesh, voxel_size: float, limit: int = DEFAULT_MEMORY_LIMIT) -> None:
    """Refuse a voxel size whose grid would not fit in ``limit`` bytes, suggesting one that does."""
    if not voxel_size > 0:
        raise CurvsliceError(f"--voxel must be positive, got {voxel_size}")
    need, shape = estimate_memory(mesh, voxel_size)
    if need > limit:
        suggest = voxel_size * (need / limit) ** (1 / 3) * 1.05
        raise CurvsliceError(
            f"voxel size {voxel_size:g} mm needs a {shape[0]}x{shape[1]}x{shape[2]} grid "
            f"(~{need / 2**30:.1f} GiB, limit {limit / 2**30:.1f} GiB); use --voxel {suggest:.3g} or larger"
        )


def _edge_function(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> np.ndarray:
    """2D orientation of p w.r.t. the directed edge a→b, computed on the canonically ordered edge
    so the two triangles sharing an edge get exactly opposite values (robust tie-breaking)."""
    swap = (a[:, 0] > b[:, 0]) | ((a[:, 0] == b[:, 0]) & (a[:, 1] > b[:, 1]))
    u = np.where(swap[:, None], b, a)
    v = np.where(swap[:, None], a, b)
    e = (v[:, 0] - u[:, 0]) * (p[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (p[:, 0] - u[:, 0])
    return np.where(swap, -e, e)


def _expand_boxes(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For integer boxes lo..hi (inclusive, shape (n,d)), the owner row and the cell of every
    cell in every box: ``(owner (m,), cell (m,d))``."""
    size = hi - lo + 1
    counts = np.prod(size, axis=1)
    owner = np.repeat(np.arange(len(lo)), counts)
    start = np.cumsum(counts) - counts
    local = np.arange(counts.sum()) - np.repeat(start, counts)
    cell = np.empty((len(owner), lo.shape[1]), dtype=np.int64)
    sz = size[owner]
    for d in range(lo.shape[1] - 1, -1, -1):
        cell[:, d] = lo[owner, d] + local % sz[:, d]
        local //= sz[:, d]
    return owner, cell


def _batches(counts: np.ndarray, batch: int):
    """Split rows into consecutive slices whose summed ``counts`` stay near ``batch``."""
    csum = np.cumsum(counts)
    start = 0
    while start < len(counts):
        base = csum[start - 1] if start else 0
        stop = int(np.searchsorted(csum, base + batch, side="right"))
        stop = max(stop, start + 1)
        yield slice(start, stop)
        start = stop


def _vertical_hits(t: np.ndarray, s: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (triangle ``t`` whose xy projection has orientation ``s``, xy point ``p``): does the vertical
    line through p cross the triangle -- on an edge shared by two triangles exactly one of them, by a
    top-left rule -- and at which z (for the pairs that cross)."""
    inside = np.ones(len(t), bool)
    lam = []
    for e0, e1 in ((1, 2), (2, 0), (0, 1)):
        e = _edge_function(t[:, e0, :2], t[:, e1, :2], p) * s  # >0 inside for both windings
        d = (t[:, e1, :2] - t[:, e0, :2]) * s[:, None]
        top_left = (d[:, 1] < 0) | ((d[:, 1] == 0) & (d[:, 0] < 0))
        inside &= (e > 0) | ((e == 0) & top_left)
        lam.append(e)
    lam = np.stack([x[inside] for x in lam], axis=1)  # barycentric coordinates * 2|area|
    return inside, (lam * t[inside][:, :, 2]).sum(axis=1) / lam.sum(axis=1)


def centres_inside(tri: np.ndarray, origin: np.ndarray, w: float, shape: tuple[int, int, int]) -> np.ndarray:
    """Boolean grid: voxel centre inside the closed surface, by the winding number of a +z ray
    through every column of centres (crossings counted once by a top-left tie rule)."""
    nx, ny, nz = shape
    a, b, c = tri[:, 0, :2], tri[:, 1, :2], tri[:, 2, :2]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    keep = area2 != 0
    tri, area2 = tri[keep], area2[keep]
    sign = np.sign(area2)  # +1: normal has +z component (ray exits the solid upwards)
    xy_lo = tri[:, :, :2].min(axis=1)
    xy_hi = tri[:, :, :2].max(axis=1)
    # widened column range: the exact edge functions below decide columns on a triangle's border
    i_lo = np.maximum(np.ceil((xy_lo - origin[:2]) / w - 1e-6), 0).astype(np.int64)
    i_hi = np.minimum(np.floor((xy_hi - origin[:2]) / w + 1e-6), np.array([nx - 1, ny - 1])).astype(np.int64)
    ok = (i_hi >= i_lo).all(axis=1)
    tri, sign, area2, i_lo, i_hi = tri[ok], sign[ok], area2[ok], i_lo[ok], i_hi[ok]
    counts = np.prod(i_hi - i_lo + 1, axis=1)
    crossings = np.zeros((nx, ny, nz + 1), dtype=np.int32)
    for sl in _batches(counts, PAIR_BATCH):
        owner, cell = _expand_boxes(i_lo[sl], i_hi[sl])
        t = tri[sl][owner]
        p = origin[:2] + w * cell
        s = sign[sl][owner]
        inside, z = _vertical_hits(t, s, p)
        cell, s = cell[inside], s[inside]
        k_star = np.clip(np.ceil((z - origin[2]) / w), 0, nz).astype(np.int64)  # voxels below the crossing
        np.add.at(crossings, (cell[:, 0], cell[:, 1], k_star), s.astype(np.int32))
    winding = np.cumsum(crossings[:, :, ::-1], axis=2)[:, :, ::-1][:, :, 1:]
    return winding > 0


@dataclass(frozen=True)
class RayWinding:
    """Winding number of a closed, outward-oriented triangle mesh at any points: the signed count of
    the mesh's crossings by a +z ray (+1 where it leaves through a face whose normal points up), with
    the tie rule of :func:`centres_inside`, so a point is inside by the same nonzero rule as a voxel
    centre. Exact where the surface crosses itself or shells overlap (winding number 2 is inside), where
    a closest-feature sign is not. Triangles are bucketed by their xy bounding boxes, highest first within a
    bucket, so a point's candidates are the prefix that reaches above it."""

    triangles: np.ndarray  # (F,3,3), those with a non-degenerate xy projection
    sign: np.ndarray       # (F,) +1 normal up, -1 down
    xy_lo: np.ndarray      # (F,2) xy bounding boxes
    xy_hi: np.ndarray
    members: np.ndarray    # triangles of bucket b: members[starts[b]:starts[b + 1]], highest top first
    starts: np.ndarray
    keys: np.ndarray       # per member: bucket + depth of its top below the highest top, in [0, 1)
    z_top: float
    z_span: float
    lo_xy: np.ndarray
    size: float
    dims: tuple[int, int]

    @classmethod
    def of(cls, tri: np.ndarray) -> RayWinding:
        tri = np.asarray(tri, float)
        a, b, c = tri[:, 0, :2], tri[:, 1, :2], tri[:, 2, :2]
        area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        tri, area2 = tri[area2 != 0], area2[area2 != 0]
        xy_lo, xy_hi = tri[:, :, :2].min(axis=1), tri[:, :, :2].max(axis=1)
        lo_xy = xy_lo.min(axis=0)
        scale = float(np.ptp(tri.reshape(-1, 3), axis=0).max())
        size = max(float(np.median((xy_hi - xy_lo).max(axis=1))), 1e-3 * scale)
        b_lo = np.floor((xy_lo - lo_xy) / size).astype(np.int64)
        b_hi = np.floor((xy_hi - lo_xy) / size).astype(np.int64)
        dims = (int(b_hi[:, 0].max()) + 1, int(b_hi[:, 1].max()) + 1)
        owner, cell = _expand_boxes(b_lo, b_hi)
        bucket = cell[:, 0] * dims[1] + cell[:, 1]
        top = tri[:, :, 2].max(axis=1)
        z_top, z_span = float(top.max()), 2.0 * float(np.ptp(tri[:, :, 2])) + 1.0
        keys = bucket + (z_top - top[owner]) / z_span
        order = np.argsort(keys, kind="stable")
        starts = np.searchsorted(bucket[order], np.arange(dims[0] * dims[1] + 1))
        return cls(tri, np.sign(area2), xy_lo, xy_hi, owner[order], starts, keys[order], z_top, z_span, lo_xy,
                   size, dims)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Integer winding numbers (n,) of ``points`` (n,3): 0 outside, 1 inside, 2 where shells overlap."""
        p = np.asarray(points, float).reshape(-1, 3)
        cell = np.floor((p[:, :2] - self.lo_xy) / self.size).astype(np.int64)
        ok = (cell >= 0).all(axis=1) & (cell[:, 0] < self.dims[0]) & (cell[:, 1] < self.dims[1])
        bucket = np.where(ok, cell[:, 0] * self.dims[1] + cell[:, 1], 0)
        depth = np.clip((self.z_top - p[:, 2]) / self.z_span, 0.0, 0.75)  # a top at the point's height counts
        counts = np.where(ok, np.searchsorted(self.keys, bucket + depth, side="right") - self.starts[bucket], 0)
        winding = np.zeros(len(p), np.int64)
        for sl in _batches(counts, PAIR_BATCH):
            c = counts[sl]
            own = np.repeat(np.arange(sl.start, sl.stop), c)
            pos = np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c) + np.repeat(self.starts[bucket[sl]], c)
            tid = self.members[pos]
            x, y = p[own, 0], p[own, 1]
            lo, hi = self.xy_lo[tid], self.xy_hi[tid]
            near = (lo[:, 0] <= x) & (lo[:, 1] <= y) & (hi[:, 0] >= x) & (hi[:, 1] >= y)
            own, tid = own[near], tid[near]
            hit, z = _vertical_hits(self.triangles[tid], self.sign[tid], p[own, :2])
            up = z > p[own[hit], 2]
            winding += np.bincount(own[hit][up], self.sign[tid[hit][up]], len(p)).astype(np.int64)
        return winding


def surface_voxels(tri: np.ndarray, origin: np.ndarray, w: float, shape: tuple[int, int, int]) -> np.ndarray:
    """Boolean grid: voxels whose open box the triangles meet (separating axis theorem,
    Akenine-Möller 2001). Open boxes suffice for conservativeness: a voxel whose open box reaches
    the interior of H either has its centre in H or is crossed by ∂H; a face of H lying exactly on
    a voxel face does not mark the voxel beyond it."""
    grid = np.zeros(shape, bool)
    h = w / 2 * (1 - 1e-9)
    lo = np.floor((tri.min(axis=1) - origin) / w + 0.5 - 1e-6).astype(np.int64)
    hi = np.floor((tri.max(axis=1) - origin) / w + 0.5 + 1e-6).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, np.array(shape) - 1)
    counts = np.prod(np.maximum(hi - lo + 1, 0), axis=1)
    for sl in _batches(counts, PAIR_BATCH):
        owner, cell = _expand_boxes(lo[sl], hi[sl])
        v = tri[sl][owner] - (origin + w * cell)[:, None, :]
        hit = (v.min(axis=1) < h).all(axis=1) & (v.max(axis=1) > -h).all(axis=1)
        e = np.stack([v[:, 1] - v[:, 0], v[:, 2] - v[:, 1], v[:, 0] - v[:, 2]], axis=1)
        n = np.cross(e[:, 0], e[:, 1])
        hit &= np.abs(np.einsum("ij,ij->i", n, v[:, 0])) < h * np.abs(n).sum(axis=1)
        for ei in range(3):
            for ax in range(3):
                axis = np.zeros((1, 3))
                axis[0, ax] = 1.0
                a = np.cross(np.broadcast_to(axis, e[:, ei].shape), e[:, ei])
                proj = np.einsum("ijk,ik->ij", v, a)
                r = h * np.abs(a).sum(axis=1)
                # a zero axis (edge parallel to a box axis) separates nothing
                hit &= ((proj.min(axis=1) < r) & (proj.max(axis=1) > -r)) | (r == 0)
        c = cell[hit]
        grid[c[:, 0], c[:, 1], c[:, 2]] = True
    return grid


def voxelize(mesh: trimesh.Trimesh, voxel_size: float, memory_limit: int = DEFAULT_MEMORY_LIMIT) -> VoxelGrid:
    """Conservative voxel set H̄ ⊇ H of a closed mesh placed with z ≥ 0 (§3.4.1)."""
    check_memory(mesh, voxel_size, memory_limit)
    w = float(voxel_size)
    origin, shape = grid_for(mesh.bounds, w)
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    occupied = centres_inside(tri, origin, w, shape) | surface_voxels(tri, origin, w, shape)
    if not occupied.any():
        raise CurvsliceError("voxelization produced no voxels; is the mesh empty or degenerate?")
    return VoxelGrid(occupied=occupied, origin=origin, voxel_size=w)
