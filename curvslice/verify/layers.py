"""Re-check the working surfaces (``layers/layer_XXXX.ply``) against ``solid.stl`` and ``field.npz``
(thesis §3.4.5, Fig. 3.8; spacing histogram as in Fig. 3.18), independently of the code that made them:

* one file per layer of G, and a non-empty surface for every layer whose voxels hold material of
  H (an empty layer passes only if a lattice of samples finds less than :data:`EMPTY_MATERIAL`
  voxel volumes of H in each connected piece of its voxels — pieces of voxels that only graze ∂H:
  what a piece holds is deposited in one place, so a layer of many grazing voxels apart from each
  other is judged piece by piece, not by their sum);
* every layer vertex lies inside H — generalized winding number ≥ ½ (solid angles, Barill et al.
  2018; the nonzero rule, which the voxelizer follows too) — or within :data:`TOLERANCE` of ∂H
  (trimesh's closest point); the message counts the violations, not the vertices on ∂H, and how
  many vertices off ∂H the parity of a vertical ray (vectorized over xy buckets) classifies
  otherwise: none on a closed ∂H that does not cross itself, those of a doubly covered region
  (winding number 2) where it does (the cow);
* every boundary vertex of a layer lies on ∂H within :data:`TOLERANCE`, or where the layer's
  material ends inside H: next to a jump of the field (two face-adjacent voxels of H̄ whose G differ
  by 2 or more, a missed voxel counting as G = 0) or inside a region of missed voxels, where G gives no
  layer at all (the working surfaces cross it on guessed layers, and one may end there: the pinion at
  0.8 mm, 29 vertices 1-1.7 w deep in a pocket of its 635 missed voxels);
* consecutive layers do not intersect (exact triangle-triangle tests on AABB-overlapping pairs);
* each file lies on the voxels of its layer of G (print order as in the field), or on missed voxels;
* normals point towards later layers, and the spacing between layers (distance from area-uniform
  samples of layer l to the nearest of the few layers before it, perpendicular feet only) is
  reported in voxel widths; its mean must be plausible (:data:`SPACING_RANGE`) over the layers at
  their own level: those report.json lists as lowered (their interface lies outside H, so they were
  extracted up to a step lower: the top of the part) are left out (a 2 mm plate at 1.5 mm voxels:
  two layers, the second lowered to 0.25 w above the first).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree

from curvslice.geodesic import boundary_edges
from curvslice.verify import Check, layer_list

STAGE = "layers"
#: Distance to ∂H (voxel widths) within which a vertex counts as on the boundary (issue 3).
TOLERANCE = 0.05
#: Material (voxel volumes of H) below which a connected piece of a layer's voxels may have no surface:
#: half of what one voxel-long bead deposits on a layer one voxel thick.
EMPTY_MATERIAL = 0.5
#: Samples per voxel edge for the material estimate of an empty layer.
MATERIAL_LATTICE = 4
#: Share of layer samples that must lie within one voxel of a voxel of their own layer of G.
OWN_VOXELS_SHARE = 0.99
#: Share of spacing samples whose normals must agree with the print order.
ORIENTATION_SHARE = 0.95
#: Samples a layer pair needs before its own share is judged (it must agree in the majority).
PAIR_SAMPLES = 10
#: Spacing is measured to the union of this many earlier layers (tiny layers interleave in
#: governed fields), over perpendicular feet nearer than SPACING_REACH voxel widths.
EARLIER = 4
SPACING_REACH = 3.0
#: Plausible mean layer spacing (voxel widths per G-step of a layer); the thesis measured about
#: 1.25 w (Fig. 3.18).
SPACING_RANGE = (0.5, 2.5)
SAMPLES_PER_W2 = 1.0
MAX_SAMPLES = 2000
BATCH = 200_000
#: Winding-number tree: triangles per leaf, and the distance (in node radii) beyond which a node
#: counts by its dipole alone (Barill et al. 2018: error well under the ½ that decides inside).
WINDING_LEAF = 16
WINDING_FAR = 2.0
#: Points per call of trimesh's closest-point query (:func:`closest_on`): on the pinion at 70 mm (CGAL data, 1,300
#: triangles up to 20 mm across) one call took 4.0 GB and the layer checks peaked at 4.1 GB resident, 1.5 GB (the
#: winding numbers') with 4,096 points a call, and 49 s instead of 58.
CLOSEST_CHUNK = 4096
#: (point, triangle) pairs :func:`winding_numbers` evaluates at once (about 0.3 GB of temporaries).
WINDING_PAIRS = 1_000_000


def _xy_buckets(tri: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """CSR lists of the triangles whose xy bounding box overlaps each square bucket."""
    lo_xy = tri[:, :, :2].min(axis=(0, 1))
    b_lo = np.floor((tri[:, :, :2].min(axis=1) - lo_xy) / size).astype(np.int64)
    b_hi = np.floor((tri[:, :, :2].max(axis=1) - lo_xy) / size).astype(np.int64)
    dims = (int(b_hi[:, 0].max()) + 1, int(b_hi[:, 1].max()) + 1)
    span = b_hi - b_lo + 1
    owner = np.repeat(np.arange(len(tri)), span[:, 0] * span[:, 1])
    local = np.arange(len(owner)) - np.repeat(np.cumsum(span[:, 0] * span[:, 1]) - span[:, 0] * span[:, 1],
                                               span[:, 0] * span[:, 1])
    bx = b_lo[owner, 0] + local // span[owner, 1]
    by = b_lo[owner, 1] + local % span[owner, 1]
    bucket = bx * dims[1] + by
    order = np.argsort(bucket, kind="stable")
    starts = np.searchsorted(bucket[order], np.arange(dims[0] * dims[1] + 1))
    return owner[order], starts, lo_xy, dims


def inside_by_ray_parity(solid: trimesh.Trimesh, points: np.ndarray, seed: int = 0) -> np.ndarray:
    """Point-in-solid by the parity of +z ray crossings (xy jittered by 1e-7 of the model size,
    seeded, so rays miss mesh edges)."""
    tri = np.asarray(solid.triangles, float)
    scale = float(np.ptp(tri.reshape(-1, 3), axis=0).max())
    xy_ext = np.ptp(tri[:, :, :2], axis=1).max(axis=1)
    size = max(2.0 * float(np.median(xy_ext)), 1e-3 * scale)
    members, starts, lo_xy, dims = _xy_buckets(tri, size)
    rng = np.random.default_rng(seed)
    p = np.asarray(points, float) + np.c_[rng.uniform(-1e-7, 1e-7, (len(points), 2)) * scale, np.zeros(len(points))]
    cell = np.floor((p[:, :2] - lo_xy) / size).astype(np.int64)
    ok = (cell >= 0).all(axis=1) & (cell[:, 0] < dims[0]) & (cell[:, 1] < dims[1])
    bucket = np.where(ok, cell[:, 0] * dims[1] + cell[:, 1], 0)
    counts = np.where(ok, starts[bucket + 1] - starts[bucket], 0)
    parity = np.zeros(len(p), np.int64)
    chunk_end = np.searchsorted(np.cumsum(counts), np.arange(BATCH, counts.sum() + BATCH, BATCH))
    begin = 0
    for end in np.unique(np.r_[chunk_end, len(p)]):
        if end <= begin:
            continue
        idx = np.arange(begin, end)
        c = counts[idx]
        own = np.repeat(idx, c)
        pos = np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c) + np.repeat(starts[bucket[idx]], c)
        t = tri[members[pos]]
        q = p[own]
        a, b, cc = t[:, 0], t[:, 1], t[:, 2]
        e0 = (b[:, 0] - a[:, 0]) * (q[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (q[:, 0] - a[:, 0])
        e1 = (cc[:, 0] - b[:, 0]) * (q[:, 1] - b[:, 1]) - (cc[:, 1] - b[:, 1]) * (q[:, 0] - b[:, 0])
        e2 = (a[:, 0] - cc[:, 0]) * (q[:, 1] - cc[:, 1]) - (a[:, 1] - cc[:, 1]) * (q[:, 0] - cc[:, 0])
        hit = ((e0 > 0) & (e1 > 0) & (e2 > 0)) | ((e0 < 0) & (e1 < 0) & (e2 < 0))
        area = e0 + e1 + e2
        with np.errstate(divide="ignore", invalid="ignore"):
            z = (e1 * a[:, 2] + e2 * b[:, 2] + e0 * cc[:, 2]) / area
        above = hit & (z > q[:, 2])
        parity += np.bincount(own[above] - 0, minlength=len(p))[: len(p)]
        begin = end
    return parity % 2 == 1


def _solid_angles(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Signed solid angle of triangles with corners a, b, c relative to the origin (Van Oosterom &
    Strackee 1983)."""
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    det = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb
           + np.einsum("ij,ij->i", b, c) * la)
    return 2.0 * np.arctan2(det, den)


def closest_on(mesh: trimesh.Trimesh, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``trimesh.proximity.closest_point`` (closest points, distances, triangle ids) :data:`CLOSEST_CHUNK` points at
    a time: its candidate arrays grow with the points times the triangles whose boxes each falls in."""
    pts = np.asarray(points, float).reshape(-1, 3)
    if len(pts) <= CLOSEST_CHUNK:
        return trimesh.proximity.closest_point(mesh, pts)
    parts = [trimesh.proximity.closest_point(mesh, pts[a:a + CLOSEST_CHUNK]) for a in range(0, len(pts), CLOSEST_CHUNK)]
    return tuple(np.concatenate([part[i] for part in parts]) for i in range(3))


def winding_numbers(solid: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Generalized winding number of ∂H at each point (1 inside, 0 outside a closed outward mesh):
    the sum of the triangles' solid angles / 4π, over a median-split tree of the triangles whose
    nodes far from a point (beyond :data:`WINDING_FAR` radii) count by their area-weighted normal
    (dipole) alone (Barill et al., "Fast Winding Numbers for Soups and Clouds", 2018)."""
    tri = np.asarray(solid.triangles, float)
    p = np.asarray(points, float).reshape(-1, 3)
    centroid = tri.mean(axis=1)
    order = np.arange(len(tri))
    lo, hi, left, right = [0], [len(tri)], [-1], [-1]
    stack = [0]
    while stack:  # median splits along the widest axis of the centroids
        k = stack.pop()
        a, b = lo[k], hi[k]
        if b - a <= WINDING_LEAF:
            continue
        idx = order[a:b]
        axis = int(np.argmax(np.ptp(centroid[idx], axis=0)))
        m = (b - a) // 2
        order[a:b] = idx[np.argpartition(centroid[idx, axis], m)]
        left[k], right[k] = len(lo), len(lo) + 1
        for x, y in ((a, a + m), (a + m, b)):
            lo.append(x)
            hi.append(y)
            left.append(-1)
            right.append(-1)
            stack.append(len(lo) - 1)
    lo, hi, left, right = (np.asarray(x) for x in (lo, hi, left, right))
    t = tri[order]
    vec_area = 0.5 * np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    area = np.linalg.norm(vec_area, axis=1)

    def node_sum(x: np.ndarray) -> np.ndarray:
        c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
        return c[hi] - c[lo]

    dipole = node_sum(vec_area)
    centre = node_sum(area[:, None] * t.mean(axis=1)) / np.maximum(node_sum(area), 1e-300)[:, None]
    corners = t.reshape(-1, 3)
    radius = np.array([np.sqrt(((corners[3 * a:3 * b] - c) ** 2).sum(axis=1).max()) for a, b, c in zip(lo, hi, centre)])
    total = np.zeros(len(p))
    pid, node = np.arange(len(p)), np.zeros(len(p), np.int64)
    while len(pid):
        d = centre[node] - p[pid]
        r = np.linalg.norm(d, axis=1)
        far = r > WINDING_FAR * radius[node]
        total += np.bincount(pid[far], np.einsum("ij,ij->i", dipole[node[far]], d[far]) / r[far] ** 3, len(p))
        leaf = ~far & (left[node] < 0)
        leaf_pid, leaf_node = pid[leaf], node[leaf]
        count = hi[leaf_node] - lo[leaf_node]
        # the (point, triangle) pairs of the leaves near a point, about WINDING_PAIRS at a time: near large
        # triangles (a CAD part's flat faces) every point is near every leaf (couplingdown 70 mm: 110 M pairs, 24 GB)
        cuts = np.flatnonzero(np.diff(np.cumsum(count) // WINDING_PAIRS)) + 1
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(count)]):
            c = count[a:b]
            own = np.repeat(leaf_pid[a:b], c)
            ti = np.repeat(lo[leaf_node[a:b]], c) + np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c)
            q = p[own]
            total += np.bincount(own, _solid_angles(t[ti, 0] - q, t[ti, 1] - q, t[ti, 2] - q), len(p))
        split = ~far & (left[node] >= 0)
        pid, node = np.r_[pid[split], pid[split]], np.r_[left[node[split]], right[node[split]]]
    return total / (4.0 * np.pi)


def _segment_hits_triangle(p0: np.ndarray, p1: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Möller-Trumbore, row by row: does the closed segment p0-p1 cross the triangle?"""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    d = p1 - p0
    h = np.cross(d, e2)
    a = np.einsum("ij,ij->i", e1, h)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = 1.0 / a
        s = p0 - tri[:, 0]
        u = f * np.einsum("ij,ij->i", s, h)
        q = np.cross(s, e1)
        v = f * np.einsum("ij,ij->i", d, q)
        t = f * np.einsum("ij,ij->i", e2, q)
        return (np.abs(a) > 1e-15) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def crossing_pairs(a: trimesh.Trimesh, b: trimesh.Trimesh) -> int:
    """Number of intersecting triangle pairs between two meshes (exact edge-triangle tests on
    pairs whose bounding boxes overlap)."""
    if len(a.faces) == 0 or len(b.faces) == 0:
        return 0
    ta, tb = np.asarray(a.triangles, float), np.asarray(b.triangles, float)
    ca, cb = ta.mean(axis=1), tb.mean(axis=1)
    ra = np.linalg.norm(ta - ca[:, None], axis=2).max()
    rb = np.linalg.norm(tb - cb[:, None], axis=2).max()
    tree = cKDTree(cb)
    hits = tree.query_ball_point(ca, ra + rb)
    counts = np.fromiter(map(len, hits), np.int64, len(hits))
    if counts.sum() == 0:
        return 0
    ia = np.repeat(np.arange(len(ta)), counts)
    ib = np.concatenate([np.asarray(h, np.int64) for h in hits if len(h)])
    lo_a, hi_a, lo_b, hi_b = ta.min(axis=1), ta.max(axis=1), tb.min(axis=1), tb.max(axis=1)
    keep = ((lo_a[ia] <= hi_b[ib]) & (lo_b[ib] <= hi_a[ia])).all(axis=1)
    ia, ib = ia[keep], ib[keep]
    x = np.zeros(len(ia), bool)
    for k in range(3):
        x |= _segment_hits_triangle(ta[ia, k], ta[ia, (k + 1) % 3], tb[ib])
        x |= _segment_hits_triangle(tb[ib, k], tb[ib, (k + 1) % 3], ta[ia])
    return int(x.sum())


def layer_spacing(earlier: trimesh.Trimesh, later: trimesh.Trimesh, voxel_size: float,
                  seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Distances (mm) from area-uniform samples of ``later`` to ``earlier`` where the foot is
    perpendicular and nearer than :data:`SPACING_REACH`, and for each whether both layers' normals
    point from earlier to later."""
    n = int(np.clip(later.area * SAMPLES_PER_W2 / voxel_size**2, 1, MAX_SAMPLES))
    pts, fid = trimesh.sample.sample_surface(later, n, seed=seed)
    foot, dist, tid = closest_on(earlier, pts)
    vec = pts - foot
    n_early = earlier.face_normals[tid]
    perpendicular = np.abs(np.einsum("ij,ij->i", vec, n_early)) >= 0.99 * dist
    agree = (np.einsum("ij,ij->i", vec, n_early) > 0) & (np.einsum("ij,ij->i", vec, later.face_normals[fid]) > 0)
    sel = perpendicular & (dist > 0) & (dist <= SPACING_REACH * voxel_size)
    return dist[sel], agree[sel]


def layer_voxels(growing: np.ndarray, layer: int, step: float) -> np.ndarray:
    """Voxels printed in ``layer`` when each layer spans ``step`` values of G (Eq. 3.2, d = step·w)."""
    return (growing > (layer - 1) * step + 0.5) & (growing <= layer * step + 0.5)


def layer_material(solid: trimesh.Trimesh, voxels: np.ndarray, origin: np.ndarray, voxel_size: float) -> np.ndarray:
    """Volume of H inside each connected piece (26-neighbourhood) of the given voxels (in voxel
    volumes, largest first), from a lattice of samples; empty when there are no voxels."""
    labels, count = ndimage.label(voxels, structure=np.ones((3, 3, 3), bool))
    ijk = np.argwhere(labels > 0)
    if len(ijk) == 0:
        return np.zeros(0)
    k = MATERIAL_LATTICE
    offs = (np.stack(np.meshgrid(*[np.arange(k)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) / k - 0.5
    pts = (origin + voxel_size * (ijk[:, None, :] + offs[None])).reshape(-1, 3)
    inside = inside_by_ray_parity(solid, pts).reshape(len(ijk), len(offs)).sum(axis=1)
    piece = labels[ijk[:, 0], ijk[:, 1], ijk[:, 2]] - 1
    return np.sort(np.bincount(piece, weights=inside, minlength=count) / len(offs))[::-1]


def jump_voxels(growing: np.ndarray, occupied: np.ndarray) -> np.ndarray:
    """Voxels of H̄ with a face neighbour in H̄ whose G differs by 2 or more (missed voxels: G = 0)."""
    out = np.zeros(growing.shape, bool)
    g = growing.astype(np.int64)
    for axis in range(3):
        a = [slice(None)] * 3
        b = [slice(None)] * 3
        a[axis], b[axis] = slice(0, -1), slice(1, None)
        jump = occupied[tuple(a)] & occupied[tuple(b)] & (np.abs(g[tuple(a)] - g[tuple(b)]) >= 2)
        out[tuple(a)] |= jump
        out[tuple(b)] |= jump
    return out


def _near_own_voxels(mesh: trimesh.Trimesh, voxels: np.ndarray, origin: np.ndarray, w: float,
                     seed: int = 0) -> np.ndarray:
    """For area-uniform samples of a layer file: is a voxel of that layer within one voxel
    (Chebyshev) of the sample's nearest voxel?"""
    n = int(np.clip(mesh.area * SAMPLES_PER_W2 / w**2, 1, MAX_SAMPLES))
    return _within_one_voxel(trimesh.sample.sample_surface(mesh, n, seed=seed)[0], voxels, origin, w)


def _within_one_voxel(points: np.ndarray, voxels: np.ndarray, origin: np.ndarray, w: float) -> np.ndarray:
    """Per point: is one of ``voxels`` (a grid mask) within one voxel (Chebyshev) of the point's nearest voxel?"""
    mask = np.pad(voxels, 1)
    base = np.rint((points - origin) / w).astype(np.int64) + 1
    hit = np.zeros(len(points), bool)
    for d in np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3):
        ijk = np.clip(base + d, 0, np.array(mask.shape) - 1)
        hit |= mask[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
    return hit


def checks(outdir: Path) -> list[Check] | None:
    folder = Path(outdir) / "layers"
    files = sorted(folder.glob("layer_*.ply"))
    if not folder.is_dir() or (Path(outdir) / "parts.json").exists():
        return None  # no layers, or a RoboFDM folder's planar layers (re-checked by verify.decompose)
    results: list[Check] = []
    solid_path, field_path = Path(outdir) / "solid.stl", Path(outdir) / "field.npz"
    if not solid_path.exists() or not field_path.exists():
        return [Check(STAGE, "inputs", False, "missing", "layers need solid.stl and field.npz beside them")]
    with np.load(field_path) as f:
        growing, w, origin = f["growing"], float(f["voxel_size"]), np.asarray(f["origin"], float)
        occupied = f["occupied"] if "occupied" in f else growing > 0
    missed = occupied & (growing == 0)  # no layer of G there: the surfaces cross them on guessed layers
    report = Path(outdir) / "report.json"
    step, lowered = 1.0, set()
    if report.exists():
        section = json.loads(report.read_text()).get("layers", {})
        height = section.get("layer_height_mm")
        step = float(height) / w if height else 1.0
        lowered = set(section.get("lowered", []))
    expected = int(np.ceil(int(growing.max()) / step - 1e-9))
    solid = trimesh.load(solid_path, force="mesh")
    layers = [trimesh.load(p, force="mesh", process=False) for p in files]
    results.append(Check(STAGE, "one file per layer", len(files) == expected,
                         f"{len(files)} of {expected}", "" if len(files) == expected else "layers missing"))
    empty = [i + 1 for i, m in enumerate(layers) if len(m.faces) == 0]
    material = {layer: layer_material(solid, layer_voxels(growing, layer, step), origin, w) for layer in empty}
    lost = [layer for layer in empty if material[layer][:1].sum() >= EMPTY_MATERIAL]
    detail = ", ".join(f"{layer}: {material[layer].sum():.2f} voxels of material in {len(material[layer])} pieces"
                       f" (largest {material[layer][:1].sum():.2f})" for layer in empty[:10])
    results.append(Check(STAGE, "a surface for every layer with material", not lost,
                         f"{len(empty)} empty, {len(lost)} with material", detail))
    live = [m for m in layers if len(m.faces)]
    if not live:
        return results

    numbers = [i + 1 for i, m in enumerate(layers) if len(m.faces)]
    verts = np.concatenate([m.vertices for m in live])
    vert_layer = np.repeat(numbers, [len(m.vertices) for m in live])
    parity = inside_by_ray_parity(solid, verts)
    winding = winding_numbers(solid, verts) > 0.5
    doubt = ~parity | ~winding  # outside by either test: how far off ∂H?
    off = np.zeros(len(verts))
    if doubt.any():
        off[doubt] = closest_on(solid, verts[doubt])[1] / w
    outside = ~winding & (off > TOLERANCE)
    disagree = int(np.sum((parity != winding) & (off > TOLERANCE)))
    worst = float(off[outside].max()) if outside.any() else 0.0
    out_layers = np.unique(vert_layer[outside])
    where = f" on layers {layer_list(out_layers)}" if len(out_layers) else ""
    results.append(Check(STAGE, "vertices inside H", not outside.any(), f"{int(outside.sum())} outside by > {TOLERANCE} w",
                         f"of {len(verts)} vertices (max {worst:.3g} w{where}; "
                         f"{int(np.sum(~winding & ~outside))} more on ∂H within {TOLERANCE} w); ray parity differs "
                         f"off ∂H on {disagree}"
                         + (" (∂H crosses itself: winding number 2 where parity is even)" if disagree else ""),
                         out_layers))

    ends = [np.unique(boundary_edges(m.faces)) for m in live]
    bnd = np.concatenate([m.vertices[e] for m, e in zip(live, ends)])
    bnd_layer = np.repeat(numbers, [len(e) for e in ends])
    bd = closest_on(solid, bnd)[1] / w if len(bnd) else np.zeros(0)
    interior = bnd[bd > TOLERANCE]
    near_jump = (_within_one_voxel(interior, jump_voxels(growing, occupied) | missed, origin, w) if len(interior)
                 else np.zeros(0, bool))
    unexplained = int((~near_jump).sum())
    stray = bd[bd > TOLERANCE][~near_jump]
    stray_layers = np.unique(bnd_layer[bd > TOLERANCE][~near_jump])
    results.append(Check(STAGE, "boundary on ∂H or at a field jump", unexplained == 0,
                         f"{len(bnd) - len(interior)} on ∂H, {int(near_jump.sum())} at jumps or missed voxels, "
                         f"{unexplained} else",
                         f"median distance of those on ∂H {np.median(bd[bd <= TOLERANCE]) if len(bd) else 0:.1g} w"
                         + (f"; the others up to {stray.max():.3g} w off ∂H on layers {layer_list(stray_layers)}"
                            if unexplained else ""), stray_layers))

    crossings = [crossing_pairs(layers[i], layers[i + 1]) for i in range(len(layers) - 1)]
    bad = [i + 1 for i, c in enumerate(crossings) if c]
    results.append(Check(STAGE, "consecutive layers do not cross", not bad, f"{sum(crossings)} pairs",
                         f"between layers {bad[:10]} and the next" if bad else "", bad))

    near = {i + 1: _near_own_voxels(m, layer_voxels(growing, i + 1, step) | missed, origin, w)
            for i, m in enumerate(layers) if len(m.faces)}
    share = float(np.mean(np.concatenate(list(near.values()))))
    worst_layer = min(near, key=lambda k: near[k].mean())
    results.append(Check(STAGE, "each layer lies on its own voxels", share >= OWN_VOXELS_SHARE,
                         f"{100 * share:.2f}%", f"of samples within one voxel of a voxel of their layer or a missed one; "
                         f"worst layer {worst_layer}: {100 * near[worst_layer].mean():.0f}%"))

    dists, agree, worst = [], [], (np.inf, 0)
    for i in range(1, len(layers)):
        earlier = [m for m in layers[max(0, i - EARLIER):i] if len(m.faces)]
        if earlier and len(layers[i].faces):
            d, a = layer_spacing(trimesh.util.concatenate(earlier), layers[i], w, seed=i)
            dists.append(d if i + 1 not in lowered else d[:0])
            agree.append(a)
            if len(a) >= PAIR_SAMPLES and a.mean() < worst[0]:  # the least agreeing layer
                worst = (float(a.mean()), i + 1)
    if dists:
        d = np.concatenate(dists) / w
        a = np.concatenate(agree)
        share = float(a.mean()) if len(a) else 0.0
        ok = share >= ORIENTATION_SHARE and (worst[0] > 0.5)
        results.append(Check(STAGE, "normals towards later layers", ok, f"{100 * share:.1f}%",
                             f"of {len(a)} spacing samples; worst layer {worst[1]}: {100 * min(worst[0], 1.0):.0f}%"))
        if len(d):
            hist, edges = np.histogram(d, bins=np.arange(0, SPACING_REACH + 0.01, 0.25))
            shares = ", ".join(f"{lo:g}-{hi:g}: {100 * h / len(d):.1f}%" for lo, hi, h in zip(edges[:-1], edges[1:], hist))
            mean = float(d.mean())
            results.append(Check(STAGE, "layer spacing", SPACING_RANGE[0] * step <= mean <= SPACING_RANGE[1] * step,
                                 f"mean {mean:.3f} w, std {d.std():.3f} w",
                                 f"histogram (w): {shares}; {len(lowered)} lowered layers left out"))
        else:
            results.append(Check(STAGE, "layer spacing", True, "no layer above another at its own level",
                                 f"{len(lowered)} lowered layers left out"))
    return results
