"""Working surfaces: curved layers extracted from the growing field G and trimmed by H (thesis §3.4.5,
Fig. 3.8, Eq. 3.2).

For every layer l (print order) the surface S_l is built in three steps:

1. **Continued field.** G is an integer per voxel of H̄ (0 = empty or missed). Missed voxels get the
   layer the growth would have given them next (1 + the least G of their 18 AM-stable neighbours,
   Definition 1, Alg. 1's rule; a guess, so the jump rule of step 2 does not apply to them: cheburashka
   0.8 mm ended layer 60 inside H at a "jump" between two missed voxels); two rings of empty voxels
   around H̄ get a first-order extrapolation of G from their neighbours; the platform below z = 0 is layer 0. Both rings are cell corners, so
   an isosurface cut off by the domain ends in cells no voxel of H̄ touches: its untrimmed boundary
   lies outside H̄ ⊇ H (§3.4.5: "as long as ∂S* is always outside H"). On an edge leaving H̄ a crossing stays in the empty voxel's half, outside H.
2. **Dual contouring** (Ju et al. 2002, the thesis's [52]) at the isovalue of layer l on its narrow
   band: the grid edges whose end values bracket the isovalue, except that a jump between grown
   voxels (G = a → b ≥ a + 2, common in governed growth) carries only the layers owning its ends —
   no material of layers a+1 … b−1 lies there, and linear isosurfaces would stack b − a − 1 sheets
   1/(b − a) voxel apart. An edge leaving H̄ carries a layer's crossing only beside that layer's own
   voxels (:func:`_beside_own`: its surface reaches ∂H only where its material does). Hermite normals
   by central finite differences of G; one vertex per sign-changing cell from the QEF (truncated
   pseudo-inverse around the mass point, the vertex kept in the bounding box of its cell's Hermite
   points); one quad per crossing edge, split along its shorter diagonal and oriented along +∇G
   (towards later layers).
3. **Trimming by H** (:mod:`curvslice.trimming`): vertices are classified by a signed distance to ∂H (exact
   distance to the closest triangle, sign by the winding number of a +z ray, right also where ∂H crosses
   itself; voxels untouched by ∂H decide in bulk), triangles are clipped along the zero set, and every new boundary vertex is placed on ∂H by
   regula falsi on the signed distance. So ∂S_l lies on ∂H, except where layer l's own voxels end
   inside H (next to a jump of G).

**Isovalues (Eq. 3.2).** g_i = (i − ½)·s in units of G, with s = d / w G-steps per printed layer
(d = layer height, default w, so g_i = i − ½). The thesis prints the factor as w/d, which would give
*more* surfaces for thicker layers; d/w matches the layer count ⌈max G / d⌉ of the same paragraph.
Layer l's working surface is g_{l+1} = l·s + ½: the interface between layer l and the layers after
it, i.e. the top of layer l, where the nozzle rides while depositing it (the authors' code also
contours just above each layer, at i + 0.001). g_1 = ½ is the platform contact z = 0, not a layer
(every shared model touches z = 0 only at points).

**Empty layers.** Every layer with voxels must yield a surface. The top of the last layer (and of
any layer that nothing covers) is the skin ∂H itself, so its interface lies outside H and trims to
nothing; such a layer is extracted at the first of the lower levels l·s + ½ + s·``FALLBACK_OFFSETS``
whose trimmed surface is not empty (still above layer l − 1's level), and its mesh metadata says so.
A layer that stays empty even at l·s + ½ − 0.99·s has voxels that only graze ∂H (the voxelization
is conservative): its file is written with no faces (on the shared models: ≤ 0.12 voxel volumes of
material in all; on the corpus's vase and dome ≤ 0.27 in any connected piece, measured by the verifier).

**Separation.** Level sets of one field cannot cross, but their dual-contouring approximations can
where G jumps; each layer is pushed clear of the one before (:func:`separate_from`).
"""

from __future__ import annotations

import itertools
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree

from curvslice.errors import CurvsliceError
from curvslice.executors import Executor, InProcess
from curvslice.growing_field import ASN_OFFSETS
from curvslice.trimming import SNAP, SolidDistance, VoxelSides, trim_by_solid

#: Voxels of padding around the field grid (continuation ring, gradient stencil, platform rows).
PAD = 3
#: Level offsets (in G-steps per layer) tried in turn when a layer's surface trims to nothing.
FALLBACK_OFFSETS = (0.0, -0.25, -0.5, -0.75, -0.9, -0.97, -0.99)
#: Relative eigenvalue cut of the QEF's truncated pseudo-inverse (Ju et al. 2002 use 0.1).
QEF_TRUNCATION = 0.3
#: Edge fraction (of a voxel) into the empty voxel at which a crossing leaving another layer's voxel
#: at least lies: the empty voxel's interior holds no point of H (H ⊂ H̄), so the crossing is outside H
#: by this much, past trimming's SNAP (0.01 w) and ROOT_TOL, also where ∂H runs along the voxel face. Kept
#: small: every shared model's layers move with it where another layer's voxel meets the skin (0.25 moved
#: fertility 0.8 layer 13 by 0.5 mm² of area, 4.7 -> 5.8 % overlap; 0.05 keeps it at 4.6 %).
SKIN_INSET = 0.05
#: Consecutive layers that the approximation makes cross are pushed apart to this clearance (in
#: voxel widths), for at most SEPARATION_ROUNDS rounds.
CLEARANCE = 0.01
SEPARATION_ROUNDS = 8
#: Smallest extent (mm) of a kept layer triangle's bounding rectangle: trimesh's test of a degenerate triangle,
#: the one the tool-path stage cleans its layers with (``clean_surface``), so it sees the same faces.
DEGENERATE = 1e-9

# ----------------------------------------------------------------------------------------------
# 1. the continued field


@dataclass(frozen=True)
class ContinuedField:
    """G continued around H̄ (and into missed voxels) on a grid padded by :data:`PAD` voxels.

    ``values`` float (NaN where unknown), ``gradient`` (…, 3) per mm, ``domain`` nodes usable as
    cell corners, ``solid_nodes`` the voxels of H̄, ``grown`` those with G > 0, ``origin`` the centre
    of padded node (0,0,0).
    """

    values: np.ndarray
    gradient: np.ndarray
    domain: np.ndarray
    solid_nodes: np.ndarray
    grown: np.ndarray
    origin: np.ndarray
    voxel_size: float


def _one_sided_gradient(values: np.ndarray) -> np.ndarray:
    """Finite differences per voxel step: central where both neighbours are known, one-sided where
    one is, 0 where none is (NaN marks unknown)."""
    grads = []
    for axis in range(values.ndim):
        fwd = np.full(values.shape, np.nan)
        bwd = np.full(values.shape, np.nan)
        lo = [slice(None)] * values.ndim
        hi = [slice(None)] * values.ndim
        lo[axis], hi[axis] = slice(0, -1), slice(1, None)
        fwd[tuple(lo)] = values[tuple(hi)] - values[tuple(lo)]
        bwd[tuple(hi)] = fwd[tuple(lo)]
        both = np.stack([fwd, bwd])
        n = np.isfinite(both).sum(axis=0)
        grads.append(np.where(n > 0, np.nansum(both, axis=0) / np.maximum(n, 1), 0.0))
    return np.stack(grads, axis=-1)


def _extrapolate_ring(values: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Fill the ``target`` nodes that have known 26-neighbours with the weighted mean of the
    neighbours' first-order Taylor extrapolations G(n) + ∇G(n)·(x − n), weights 1/|x − n|²."""
    grad = _one_sided_gradient(values)
    known = np.isfinite(values)
    total = np.zeros(values.shape)
    weight = np.zeros(values.shape)
    size = values.shape
    for delta in itertools.product((-1, 0, 1), repeat=3):
        if delta == (0, 0, 0):
            continue
        # node x receives from its neighbour n = x + delta
        dst = tuple(slice(max(0, -d), size[a] - max(0, d)) for a, d in enumerate(delta))
        src = tuple(slice(max(0, d), size[a] - max(0, -d)) for a, d in enumerate(delta))
        ok = known[src]
        guess = values[src] - grad[src] @ np.array(delta, float)
        wgt = ok / float(np.dot(delta, delta))
        total[dst] += np.where(ok, guess, 0.0) * wgt
        weight[dst] += wgt
    fill = target & (weight > 0)
    out = values.copy()
    out[fill] = total[fill] / weight[fill]
    return out


def _grow_into(values: np.ndarray, missed: np.ndarray) -> None:
    """Give missed voxels the layer the growth would have given them next: 1 + the smallest G of
    their 18 AM-stable neighbours (Alg. 1's rule), front by front, in place."""
    footprint = np.zeros((3, 3, 3), bool)
    footprint[tuple((ASN_OFFSETS + 1).T)] = True
    footprint[1, 1, 1] = True
    while missed.any():
        known = np.where(np.isfinite(values), values, np.inf)
        nxt = ndimage.minimum_filter(known, footprint=footprint, mode="constant", cval=np.inf) + 1.0
        new = missed & np.isfinite(nxt)
        if not new.any():
            return  # pockets with no grown neighbour stay unknown
        values[new] = nxt[new]
        missed &= ~new


def continue_field(growing: np.ndarray, occupied: np.ndarray, origin: np.ndarray,
                   voxel_size: float) -> ContinuedField:
    """Pad G, give missed voxels the next layer the growth would have given them, and extrapolate
    into two rings of empty voxels around H̄; the platform rows below z = 0 are layer 0 (a boundary
    value, not a source of extrapolation)."""
    shape = np.array(growing.shape) + 2 * PAD
    occ = np.zeros(shape, bool)
    occ[PAD:-PAD, PAD:-PAD, PAD:-PAD] = occupied
    g = np.full(shape, np.nan)
    inner = g[PAD:-PAD, PAD:-PAD, PAD:-PAD]
    inner[growing > 0] = growing[growing > 0]
    grown = np.isfinite(g)  # before the missed voxels get their guessed layers: no jumps among those
    _grow_into(g, occ & ~grown)
    cube = np.ones((3, 3, 3), bool)
    near1 = ndimage.binary_dilation(occ, cube)
    near2 = ndimage.binary_dilation(near1, cube)
    below = np.zeros(shape, bool)
    below[:, :, :PAD] = True
    target = near2 & ~below & ~np.isfinite(g)
    while target.any():
        nxt = _extrapolate_ring(g, target)
        new = target & np.isfinite(nxt)
        if not new.any():
            break  # missed pockets with no known neighbour stay unknown (cells there are inactive)
        g = nxt
        target &= ~new
    g[below] = 0.0
    w = float(voxel_size)
    gradient = _one_sided_gradient(g) / w
    # Both rings are cell corners: a surface cut off by the domain ends in a cell with a corner
    # two voxels from H̄, i.e. in a cell no voxel of H̄ touches, so outside H (one ring let the
    # top layer of the tee end at dual vertices 0.2 w inside H).
    domain = near2 & np.isfinite(g)
    domain[:, :, PAD - 1] = domain[:, :, PAD]  # the platform row under the model
    domain[:, :, :PAD - 1] = False
    return ContinuedField(values=g, gradient=gradient, domain=domain, solid_nodes=occ, grown=grown,
                          origin=np.asarray(origin, float) - PAD * w, voxel_size=w)


# ----------------------------------------------------------------------------------------------
# 2. dual contouring


@dataclass(frozen=True)
class _Edges:
    """Grid edges between two domain nodes with different values, per axis (the narrow-band pool)."""

    lower: tuple[np.ndarray, np.ndarray, np.ndarray]  # linear id of the lower end node
    lo: tuple[np.ndarray, np.ndarray, np.ndarray]
    hi: tuple[np.ndarray, np.ndarray, np.ndarray]


def _edge_pool(field: ContinuedField) -> _Edges:
    v, d = field.values, field.domain
    lower, lo, hi = [], [], []
    for axis in range(3):
        a = [slice(None)] * 3
        b = [slice(None)] * 3
        a[axis], b[axis] = slice(0, -1), slice(1, None)
        va, vb = v[tuple(a)], v[tuple(b)]
        ok = d[tuple(a)] & d[tuple(b)] & (va != vb)
        idx = np.argwhere(ok)
        lower.append(np.ravel_multi_index(idx.T, v.shape))
        lo.append(np.minimum(va[ok], vb[ok]))
        hi.append(np.maximum(va[ok], vb[ok]))
    return _Edges(tuple(lower), tuple(lo), tuple(hi))


def _active_cells(field: ContinuedField) -> np.ndarray:
    """Flat bool over nodes: the cell whose lowest corner is this node has all 8 corners in the domain."""
    d = field.domain
    act = np.zeros(d.shape, bool)
    core = d[:-1, :-1, :-1].copy()
    for di in (0, 1):
        for dj in (0, 1):
            for dk in (0, 1):
                core &= d[di:d.shape[0] - 1 + di, dj:d.shape[1] - 1 + dj, dk:d.shape[2] - 1 + dk]
    act[:-1, :-1, :-1] = core
    return act.ravel()


def _solve_qef(ata: np.ndarray, atb: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """argmin Σ(n·(x − p))² by the truncated pseudo-inverse around the mass point (batched)."""
    lam, vec = np.linalg.eigh(ata)
    keep = lam > QEF_TRUNCATION * lam[:, -1:]
    inv = np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)
    r = atb - np.einsum("nij,nj->ni", ata, mass)
    return mass + np.einsum("nij,nj->ni", vec, inv * np.einsum("nji,nj->ni", vec, r))


def _outside_inset(fa: np.ndarray, fb: np.ndarray, solid_a: np.ndarray, solid_b: np.ndarray,
                   band: tuple[float, float] | None) -> np.ndarray:
    """How far (edge fraction) past the shared face a crossing on an edge leaving H̄ must lie: 0 from a
    voxel of the layer being extracted (its own top may be ∂H), :data:`SKIN_INSET` from an earlier or a
    later layer's voxel (that skin is the top or the underside of another layer, not this one's)."""
    if band is None:
        return np.zeros(len(fa))
    inner = np.where(solid_a & ~solid_b, fa, fb)
    return np.where((inner <= band[0]) | (inner > band[1]), SKIN_INSET, 0.0)


def _beside_own(field: ContinuedField, a: np.ndarray, b: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    """(n,) bool per grid edge a-b: True unless it leaves H̄ (one end a voxel, the other a ring node)
    with no voxel of the layer being extracted (G in ``band`` = (lo, hi]) among its voxel end and that
    voxel's 26 neighbours. A layer's surface is the top of its own material, so it reaches ∂H only
    beside that material; elsewhere the ring's extrapolation of a steep G (a slab's top rising two
    G-steps a voxel towards its edge) brackets the isovalues of layers with no material there, and
    their slivers survived trimming on ∂H (a leaning cylinder at 1.5 mm: layer 12, 4 voxels in all,
    had 30 faces on the slab's far edge, none within a voxel of its own)."""
    solid = field.solid_nodes.ravel()
    leaving = solid[a] != solid[b]
    out = np.ones(len(a), bool)
    if not leaving.any():
        return out
    end = np.where(solid[a], a, b)[leaving]
    shape = np.array(field.values.shape)
    ijk = np.stack(np.unravel_index(end, tuple(shape)), axis=1)
    own = np.zeros(len(end), bool)
    for d in itertools.product((-1, 0, 1), repeat=3):
        n = np.clip(ijk + d, 0, shape - 1)
        v = field.values[n[:, 0], n[:, 1], n[:, 2]]
        own |= field.solid_nodes[n[:, 0], n[:, 1], n[:, 2]] & (v > band[0]) & (v <= band[1])
    out[leaving] = own
    return out


def dual_contour(field: ContinuedField, level: float, band: tuple[float, float] | None = None, *,
                 edges: _Edges | None = None, active: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Dual contouring of the continued field at ``level``: (vertices (n,3) mm, faces (m,3)), faces
    oriented along +∇G. ``edges``/``active`` may be passed to reuse the per-field precomputation.

    With ``band`` = (lo, hi], the G values of the layer being extracted, a jump between grown
    voxels (G = a → b ≥ a + 2, no material of layers a+1 … b−1 on that edge) is used only by the
    layer owning one of its ends, with the crossing one G-step per voxel from that end (so the top
    of layer a sits on the voxel face); plain linear isosurfaces would stack b − a − 1 sheets there.
    """
    edges = _edge_pool(field) if edges is None else edges
    active = _active_cells(field) if active is None else active
    shape = field.values.shape
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    vals = field.values.ravel()
    grad = field.gradient.reshape(-1, 3)
    solid = field.solid_nodes.ravel()
    grown = field.grown.ravel()
    w = field.voxel_size
    pts, nrm, quads, up = [], [], [], []
    for axis in range(3):
        m = (edges.lo[axis] <= level) & (edges.hi[axis] > level)
        a = edges.lower[axis][m]
        b = a + strides[axis]
        fa, fb = vals[a], vals[b]
        t = (level - fa) / (fb - fa)
        if band is not None:
            f_lo, f_hi = np.minimum(fa, fb), np.maximum(fa, fb)
            jump = grown[a] & grown[b] & (f_hi - f_lo >= 2)
            lo_in = (f_lo > band[0]) & (f_lo <= band[1])
            hi_in = (f_hi > band[0]) & (f_hi <= band[1])
            # measured from the low end, one G-step per voxel, kept in the owning voxel's half
            from_lo = np.where(lo_in, np.clip(level - f_lo, 0.0, 0.5), np.clip(1 - (f_hi - level), 0.5, 1.0))
            t = np.where(jump, np.where(fa < fb, from_lo, 1 - from_lo), t)
            keep = (~jump | lo_in | hi_in) & _beside_own(field, a, b, band)
            a, b, fa, fb, t = a[keep], b[keep], fa[keep], fb[keep], t[keep]
        # a crossing on an edge leaving H̄ stays in the empty voxel's half (outside H); leaving another
        # layer's voxel it lies inside the empty voxel, off the shared face: that face is on ∂H where a
        # flat top or underside of H meets the grid (z = k·w), and another layer's skin kept there became
        # this layer's surface too (an inverted cone's top twice, an overhang's underside)
        inset = _outside_inset(vals[a], vals[b], solid[a], solid[b], band)
        t = np.where(solid[a] & ~solid[b], np.maximum(t, 0.5 + inset), t)
        t = np.where(solid[b] & ~solid[a], np.minimum(t, 0.5 - inset), t)
        ijk = np.stack(np.unravel_index(a, shape), axis=1).astype(float)
        p = field.origin + w * ijk
        p[:, axis] += w * t
        n = (1 - t)[:, None] * grad[a] + t[:, None] * grad[b]
        pts.append(p)
        nrm.append(n)
        bx, cx = strides[(axis + 1) % 3], strides[(axis + 2) % 3]
        quads.append(np.stack([a, a - bx, a - bx - cx, a - cx], axis=1))  # CCW about +axis
        up.append(fa <= level)
    p = np.concatenate(pts)
    n = np.concatenate(nrm)
    quads = np.concatenate(quads)
    up = np.concatenate(up)
    n = np.nan_to_num(n)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)

    # QEF accumulation over the active cells around every crossing edge
    cell_of = quads.ravel()
    edge_of = np.repeat(np.arange(len(p)), 4)
    ok = active[cell_of]
    cells, inv = np.unique(cell_of[ok], return_inverse=True)
    e = edge_of[ok]
    count = np.bincount(inv, minlength=len(cells)).astype(float)
    mass = np.stack([np.bincount(inv, p[e, i], len(cells)) for i in range(3)], axis=1) / count[:, None]
    nn = n[e][:, :, None] * n[e][:, None, :]
    ata = np.stack([np.bincount(inv, nn[:, i, j], len(cells)) for i in range(3) for j in range(3)],
                   axis=1).reshape(-1, 3, 3)
    nb = n[e] * np.einsum("ij,ij->i", n[e], p[e])[:, None]
    atb = np.stack([np.bincount(inv, nb[:, i], len(cells)) for i in range(3)], axis=1)
    x = _solve_qef(ata, atb, mass)
    box_lo = np.full((len(cells), 3), np.inf)
    box_hi = np.full((len(cells), 3), -np.inf)
    np.minimum.at(box_lo, inv, p[e])
    np.maximum.at(box_hi, inv, p[e])
    x = np.clip(x, box_lo, box_hi)

    full = active[quads].all(axis=1)
    q = np.searchsorted(cells, quads[full])
    q = np.where(up[full][:, None], q, q[:, ::-1])
    d02 = np.linalg.norm(x[q[:, 0]] - x[q[:, 2]], axis=1)
    d13 = np.linalg.norm(x[q[:, 1]] - x[q[:, 3]], axis=1)
    split02 = (d02 <= d13)[:, None]
    t1 = np.where(split02, q[:, [0, 1, 2]], q[:, [1, 2, 3]])
    t2 = np.where(split02, q[:, [0, 2, 3]], q[:, [1, 3, 0]])
    faces = np.concatenate([t1, t2])
    used, faces = np.unique(faces, return_inverse=True)
    return x[used], faces.reshape(-1, 3)


# ----------------------------------------------------------------------------------------------
# 4. separation of consecutive layers


def _triangles_intersect(t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """Row-wise triangle-triangle intersection by Möller's interval test (1997): each triangle must
    straddle the other's plane, and their intervals on the planes' common line must overlap.
    Coplanar pairs count as separate."""
    n1 = np.cross(t1[:, 1] - t1[:, 0], t1[:, 2] - t1[:, 0])
    n2 = np.cross(t2[:, 1] - t2[:, 0], t2[:, 2] - t2[:, 0])
    d1 = np.einsum("ikj,ij->ik", t1 - t2[:, None, 0], n2)  # t1's corners against t2's plane
    d2 = np.einsum("ikj,ij->ik", t2 - t1[:, None, 0], n1)
    straddle = ~(((d1 > 0).all(1) | (d1 < 0).all(1)) | ((d2 > 0).all(1) | (d2 < 0).all(1)))
    line = np.cross(n1, n2)
    straddle &= np.einsum("ij,ij->i", line, line) > 0

    def interval(t: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        proj = np.einsum("ikj,ij->ik", t, line)
        ends = [np.where(d[:, k] == 0, proj[:, k], np.nan) for k in range(3)]
        for i, j in ((0, 1), (1, 2), (2, 0)):
            cross = d[:, i] * d[:, j] < 0
            with np.errstate(divide="ignore", invalid="ignore"):
                at = proj[:, i] + (proj[:, j] - proj[:, i]) * d[:, i] / (d[:, i] - d[:, j])
            ends.append(np.where(cross, at, np.nan))
        ends = np.stack(ends, axis=1)
        ends[~straddle] = 0.0
        return np.nanmin(ends, axis=1), np.nanmax(ends, axis=1)

    lo1, hi1 = interval(t1, d1)
    lo2, hi2 = interval(t2, d2)
    return straddle & (np.maximum(lo1, lo2) <= np.minimum(hi1, hi2))


def _crossing_faces(earlier: trimesh.Trimesh, later_v: np.ndarray, later_f: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (face of ``earlier``, face of the later mesh) that intersect."""
    ta, tb = np.asarray(earlier.triangles, float), later_v[later_f]
    ca, cb = ta.mean(axis=1), tb.mean(axis=1)
    reach = np.linalg.norm(ta - ca[:, None], axis=2).max() + np.linalg.norm(tb - cb[:, None], axis=2).max()
    pairs = cKDTree(ca).query_ball_point(cb, reach)
    counts = np.fromiter(map(len, pairs), np.int64, len(pairs))
    ib = np.repeat(np.arange(len(tb)), counts)
    ia = np.fromiter(itertools.chain.from_iterable(pairs), np.int64, int(counts.sum()))
    overlap = ((ta[ia].min(axis=1) <= tb[ib].max(axis=1)) & (tb[ib].min(axis=1) <= ta[ia].max(axis=1))).all(axis=1)
    ia, ib = ia[overlap], ib[overlap]
    hit = _triangles_intersect(ta[ia], tb[ib])
    return ia[hit], ib[hit]


def separate_from(earlier: trimesh.Trimesh, vertices: np.ndarray, faces: np.ndarray, voxel_size: float,
                  distance: SolidDistance | None = None, sides: VoxelSides | None = None
                  ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Make a layer clear of the one before it: every later triangle crossing an earlier one gets
    its corners pushed :data:`CLEARANCE` in front of that triangle's plane (along its normal, which
    points towards later layers), repeatedly; triangles still crossing after
    :data:`SEPARATION_ROUNDS` are dropped. Returns (vertices, faces, vertices moved, faces dropped).

    Given the solid (``distance``, ``sides``), a corner is never pushed out of H: a steep earlier
    triangle's plane can lie far from a corner it crosses near ∂H (homer's top layer: a corner
    pushed 0.41 w ended 0.30 w outside H); such a corner stays, and its triangle is dropped."""
    v = np.array(vertices, float)
    if len(earlier.faces) == 0 or len(faces) == 0:
        return v, faces, 0, 0
    normals = np.asarray(earlier.face_normals, float)
    anchor = np.asarray(earlier.triangles, float)[:, 0]
    moved = np.zeros(len(v), bool)
    for _ in range(SEPARATION_ROUNDS):
        ia, ib = _crossing_faces(earlier, v, faces)
        if len(ia) == 0:
            return v, faces, int(moved.sum()), 0
        corner = faces[ib].ravel()
        n = np.repeat(normals[ia], 3, axis=0)
        lack = CLEARANCE * voxel_size - np.einsum("ij,ij->i", v[corner] - np.repeat(anchor[ia], 3, axis=0), n)
        need = lack > 0
        push = np.zeros(len(v))
        np.maximum.at(push, corner[need], lack[need])
        first = np.full(len(v), -1)
        first[corner[need][::-1]] = np.flatnonzero(need)[::-1]  # the pair that asks for a push
        hit = np.flatnonzero(push > 0)
        to = v[hit] + push[hit, None] * n[first[hit]]
        if distance is not None and len(hit):
            d, _ = sides.signed(distance, to)
            keep = d <= SNAP * voxel_size
            hit, to = hit[keep], to[keep]
        v[hit] = to
        moved[hit] = True
    _, ib = _crossing_faces(earlier, v, faces)
    keep = np.ones(len(faces), bool)
    keep[ib] = False
    return v, faces[keep], int(moved.sum()), int((~keep).sum())


# ----------------------------------------------------------------------------------------------
# the stage


def layer_levels(max_growing: int, voxel_size: float, layer_height: float | None = None) -> np.ndarray:
    """Isovalue of each layer's working surface: g_{l+1} = l·s + ½ of Eq. 3.2, s = d / w, for
    l = 1 … ⌈max G / s⌉ (see the module docstring for the indexing)."""
    step = 1.0 if layer_height is None else float(layer_height) / float(voxel_size)
    if not step > 0:
        raise CurvsliceError(f"layer height must be positive, got {layer_height}")
    count = int(np.ceil(max_growing / step - 1e-9))
    return 0.5 + step * np.arange(1, count + 1)


def extract_working_surfaces(growing: np.ndarray, origin: np.ndarray, voxel_size: float,
                             solid: trimesh.Trimesh, layer_height: float | None = None,
                             occupied: np.ndarray | None = None,
                             progress=None, executor: Executor | None = None) -> list[trimesh.Trimesh]:
    """One trimmed working surface per layer, in print order (§3.4.5).

    ``growing`` is G (int, 0 = empty/missed) on the voxel grid (``origin`` = centre of voxel
    (0,0,0), mm); ``occupied`` is H̄ (default ``growing > 0``; pass it so missed voxels are bridged);
    ``solid`` is H. Each mesh's ``metadata`` holds ``layer``, ``isovalue``, ``lowered`` (fallback
    level used), ``untrimmed_faces``, ``separated_vertices`` / ``dropped_faces`` (see
    :func:`separate_from`) and the seconds spent in ``dc_seconds`` / ``trim_seconds`` (trimming and
    separation).
    ``progress`` is an optional tqdm-like object updated once per layer. The layers are contoured and
    trimmed as independent tasks on ``executor`` (default: in-process), then separated in order.
    """
    growing = np.asarray(growing)
    if growing.ndim != 3 or not np.issubdtype(growing.dtype, np.integer):
        raise CurvsliceError("the growing field must be a 3D integer grid (field.npz 'growing')")
    occupied = growing > 0 if occupied is None else np.asarray(occupied, bool)
    if occupied.shape != growing.shape:
        raise CurvsliceError("field.npz is inconsistent: 'occupied' and 'growing' differ in shape")
    if growing.max(initial=0) < 1:
        raise CurvsliceError("the growing field is empty; run the field stage first")
    w = float(voxel_size)
    field = continue_field(growing, occupied, origin, w)
    edges, active = _edge_pool(field), _active_cells(field)
    distance = SolidDistance.of(solid)
    sides = VoxelSides.of(solid, np.asarray(origin, float), w, growing.shape)
    step = 1.0 if layer_height is None else float(layer_height) / w
    levels = layer_levels(int(growing.max()), w, layer_height)
    ex = executor if executor is not None else InProcess()
    contoured = ex.map(_contour_layer, range(len(levels)), progress=progress, levels=levels, step=step, field=field,
                       edges=edges, active=active, distance=distance, sides=sides)
    layers = []
    for i, (tv, tf, untrimmed, level, offset, dc_s, trim_s) in enumerate(contoured):
        moved = dropped = 0
        t2 = time.perf_counter()
        if layers:
            tv, tf, moved, dropped = separate_from(layers[-1], tv, tf, w, distance, sides)
        if moved:
            tf = _spanning(tv, tf)  # (a push may fold a triangle flat too)
        trim_s += time.perf_counter() - t2
        mesh = trimesh.Trimesh(tv, tf, process=False)
        mesh.metadata.update(layer=i + 1, isovalue=level, lowered=offset != 0.0, untrimmed_faces=untrimmed,
                             separated_vertices=moved, dropped_faces=dropped,
                             dc_seconds=dc_s, trim_seconds=trim_s)
        layers.append(mesh)
    return layers


def _contour_layer(i: int, levels: np.ndarray, step: float, field: ContinuedField, edges: _Edges,
                   active: np.ndarray, distance: SolidDistance, sides: VoxelSides
                   ) -> tuple[np.ndarray, np.ndarray, int, float, float, float, float]:
    """Layer ``i``'s working surface dual-contoured and trimmed by H, lowered by the fallback offsets
    while the trimmed surface is empty: independent of the other layers (a parallel task). Returns
    the trimmed vertices and faces, the untrimmed face count, the level, its offset and the seconds
    of contouring and trimming."""
    band = (float(levels[i] - step), float(levels[i]))
    dc_s = trim_s = 0.0
    for offset in FALLBACK_OFFSETS:
        level = float(levels[i] + offset * step)
        t0 = time.perf_counter()
        v, f = dual_contour(field, level, band, edges=edges, active=active)
        t1 = time.perf_counter()
        tv, tf = trim_by_solid(v, f, distance, sides)
        tf = _spanning(tv, tf)
        dc_s += t1 - t0
        trim_s += time.perf_counter() - t1
        if len(tf):
            break
    return tv, tf, len(f), level, offset, dc_s, trim_s


def _spanning(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` but those whose corners lie on one point or one line (trimming can put them there): such a
    triangle carries no surface, and no crossing test sees it through a plane it does not span (elephant 0.8:
    one of layer 104's crossed layer 103 by an edge); a layer left with only those is empty, and lowered."""
    return faces[trimesh.triangles.nondegenerate(vertices[faces], height=DEGENERATE)] if len(faces) else faces


def write_layers(outdir: str | Path, layers: list[trimesh.Trimesh]) -> list[Path]:
    """Write ``layers/layer_0001.ply …`` (binary PLY, mm, model frame) into a slice folder, and
    ``layers/layers.npz`` with the exact float64 vertices, faces and metadata of every layer (PLY stores
    float32; the pipeline resumes from the exact arrays, :func:`load_layers`)."""
    folder = Path(outdir) / "layers"
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("layer_*.ply"):
        old.unlink()
    paths = []
    for i, mesh in enumerate(layers, start=1):
        path = folder / f"layer_{i:04d}.ply"
        mesh.export(path, file_type="ply", encoding="binary")
        paths.append(path)
    counts = np.array([[len(m.vertices), len(m.faces)] for m in layers], np.int64).reshape(-1, 2)
    np.savez_compressed(
        folder / "layers.npz", counts=counts,
        vertices=np.concatenate([m.vertices for m in layers]) if layers else np.zeros((0, 3)),
        faces=np.concatenate([m.faces for m in layers]) if layers else np.zeros((0, 3), np.int64),
        metadata=np.str_(json.dumps([m.metadata for m in layers], default=float)))
    return paths


def load_layers(outdir: str | Path) -> list[trimesh.Trimesh]:
    """The layers exactly as :func:`write_layers` saved them (from ``layers/layers.npz``)."""
    with np.load(Path(outdir) / "layers" / "layers.npz") as f:
        counts, vertices, faces = f["counts"], f["vertices"], f["faces"]
        metadata = json.loads(str(f["metadata"]))
    v_at, f_at = np.r_[0, np.cumsum(counts[:, 0])], np.r_[0, np.cumsum(counts[:, 1])]
    layers = []
    for i, meta in enumerate(metadata):
        mesh = trimesh.Trimesh(vertices[v_at[i]:v_at[i + 1]], faces[f_at[i]:f_at[i + 1]], process=False)
        mesh.metadata.update(meta)
        layers.append(mesh)
    return layers
