"""Orientation of material accumulation along the tool-paths (thesis §3.5.2).

For a sample ``q`` on layer ``S_i`` the orientation is ``t_q = q - c_q`` with ``c_q`` the closest
point on the layers printed before (Eq. 3.3; the platform top ``z = 0`` counts as printed), so
the bead is stacked on the material under it. Samples whose orientation differs from a
neighbour's by more than 10° are low-pass filtered; where a crest still leaves a larger jump
the segment is subdivided and the new samples get slerp-interpolated orientations. Finally no
orientation may point into printed material: the angle to the layer normal (which points
towards later layers) is kept below ``max_tilt``.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from trimesh.triangles import closest_point as _closest_on_triangles

from curvslice.executors import query_threads
from curvslice.vectors import row_norms


def closest_points(points: np.ndarray, triangles: np.ndarray, tree: cKDTree | None = None,
                   candidates: int = 12, reach: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest point on a triangle soup (T,3,3) for each point (Eq. 3.3), its distance and triangle.

    Candidates are the ``candidates`` triangles with the nearest centroids (``tree`` over the
    centroids may be passed in); the exact point-triangle distance decides among them. It is computed
    for the nearest centroid's triangle and for the candidates that may come nearer than that one: no
    triangle is nearer than its centroid less its ``reach`` (:func:`triangle_reach`, computed when not
    given), so the others cannot be the closest and need no test (the same answer, bit for bit: each
    point-triangle pair is computed on its own).
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    tri = np.asarray(triangles, np.float64).reshape(-1, 3, 3)
    tree = tree if tree is not None else cKDTree(tri.mean(axis=1))
    reach = reach if reach is not None else triangle_reach(tri, tree)
    k = min(candidates, len(tri))
    centre, idx = tree.query(pts, k=k, workers=query_threads(len(pts)))
    centre, idx = centre.reshape(len(pts), k), idx.reshape(len(pts), k)
    rows = np.arange(len(pts))
    first = _closest_on_triangles(np.take(tri, idx[:, 0], axis=0), pts)  # (take: 4x numpy's row indexing)
    dist = np.full((len(pts), k), np.inf)
    dist[:, 0] = row_norms(first - pts)
    # (a margin far above rounding: a candidate is skipped only when it is surely farther)
    row, col = np.nonzero(centre[:, 1:] - reach[idx[:, 1:]] <= dist[:, :1] + _SURELY_FARTHER)
    col += 1
    at = np.take(pts, row, axis=0)
    other = _closest_on_triangles(np.take(tri, idx[row, col], axis=0), at)
    dist[row, col] = row_norms(other - at)
    best = np.argmin(dist, axis=1)
    out = first.copy()
    won = best[row] == col
    out[row[won]] = other[won]
    return out, dist[rows, best], idx[rows, best]


#: Distance (mm) by which :func:`closest_points` requires a candidate's lower bound to exceed the best
#: distance found before skipping it: far above the rounding of either (1e-13 mm at a metre).
_SURELY_FARTHER = 1e-9


def triangle_reach(triangles: np.ndarray, tree: cKDTree) -> np.ndarray:
    """Each triangle's farthest corner from its point in ``tree`` (its centroid): no point of the
    triangle lies farther from it (:func:`closest_points`)."""
    return row_norms(np.asarray(triangles, np.float64).reshape(-1, 3, 3) - tree.data[:, None, :]).max(axis=1)


def surface_normals(mesh: trimesh.Trimesh, points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit layer normals at ``points`` (lying on triangles ``faces`` of ``mesh``), interpolated
    from the vertex normals: continuous across edges, unlike the flipped slivers a contoured
    surface may contain."""
    tri = mesh.triangles[faces]
    with np.errstate(all="ignore"):
        bary = trimesh.triangles.points_to_barycentric(tri, points)
    bary[~np.isfinite(bary).all(axis=1)] = 1.0 / 3.0
    return _unit(np.einsum("ij,ijk->ik", bary, mesh.vertex_normals[mesh.faces[faces]]))


def accumulation_directions(points: np.ndarray, closest: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Unit ``t_q = c_q q`` (Eq. 3.3 and below); ``fallback`` where ``q`` touches ``c_q``."""
    t = np.asarray(points, np.float64) - closest
    n = row_norms(t)[..., None]
    return np.where(n > 1e-9, t / np.where(n > 1e-9, n, 1.0), fallback)


def angles_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (rad) between the rows of ``a`` and ``b`` (any lengths; atan2, exact near 0 and π)."""
    return np.arctan2(row_norms(np.cross(a, b)), np.einsum("ij,ij->i", a, b))


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.maximum(row_norms(x)[..., None], 1e-300)


def low_pass(normals: np.ndarray, path_id: np.ndarray, max_angle: float = np.radians(10.0),
             iterations: int = 50) -> np.ndarray:
    """Average ``(t_{i-1} + 2 t_i + t_{i+1}) / 4`` on samples that differ from a neighbour on
    the same path by more than ``max_angle``, repeatedly, until none is left (§3.5.2)."""
    t = _unit(np.asarray(normals, np.float64).copy())
    pid = np.asarray(path_id)
    same = pid[1:] == pid[:-1]
    for _ in range(iterations):
        jump = same & (angles_between(t[1:], t[:-1]) > max_angle)
        if not jump.any():
            break
        flag = np.zeros(len(t), bool)
        flag[:-1] |= jump
        flag[1:] |= jump
        prev = np.vstack([t[:1], t[:-1]])
        nxt = np.vstack([t[1:], t[-1:]])
        prev[1:][~same] = t[1:][~same]  # no smoothing across a travel
        nxt[:-1][~same] = t[:-1][~same]
        t[flag] = _unit(prev[flag] + 2 * t[flag] + nxt[flag])
    return t


def limit_tilt(normals: np.ndarray, surface_normals: np.ndarray, max_tilt: float) -> np.ndarray:
    """Rotate each orientation towards the layer normal until their angle is ≤ ``max_tilt``, so
    the nozzle never points into the printed side of the working surface."""
    t = _unit(np.asarray(normals, np.float64))
    n = _unit(np.asarray(surface_normals, np.float64))
    ang = angles_between(t, n)
    bad = ang > max_tilt
    if bad.any():
        side = t[bad] - np.einsum("ij,ij->i", t[bad], n[bad])[:, None] * n[bad]
        norm = row_norms(side)[..., None]
        any_perp = np.cross(n[bad], np.where(np.abs(n[bad][:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
        side = np.where(norm > 1e-9, side / np.maximum(norm, 1e-300), _unit(any_perp))
        t[bad] = np.cos(max_tilt) * n[bad] + np.sin(max_tilt) * side
    return t


def slerp(a: np.ndarray, b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation between unit vectors (rows), parameter ``u`` in [0, 1]."""
    omega = angles_between(a, b)[:, None]
    u = np.asarray(u, np.float64).reshape(-1, 1)
    small = omega < 1e-8
    s = np.where(small, 1.0, np.sin(omega))
    wa = np.where(small, 1 - u, np.sin((1 - u) * omega) / s)
    wb = np.where(small, u, np.sin(u * omega) / s)
    return _unit(wa * a + wb * b)


def slerp_subdivide(positions: np.ndarray, normals: np.ndarray, path_id: np.ndarray,
                    max_angle: float = np.radians(10.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Subdivide segments whose orientations differ by more than ``max_angle`` (crests, §3.5.2).

    Returns new positions and normals plus, per new sample, the index of the original sample
    that starts its segment and the fraction along it (to interpolate other per-sample data).
    """
    p = np.asarray(positions, np.float64)
    t = _unit(np.asarray(normals, np.float64))
    pid = np.asarray(path_id)
    ang = np.r_[angles_between(t[1:], t[:-1]), 0.0]
    pieces = np.where(np.r_[pid[1:] == pid[:-1], False], np.ceil(ang / max_angle - 1e-9), 1).astype(np.int64)
    pieces = np.maximum(pieces, 1)
    parent = np.repeat(np.arange(len(p)), pieces)
    fraction = np.arange(len(parent)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    fraction = fraction / pieces[parent]
    nxt = np.minimum(parent + 1, len(p) - 1)
    pos = p[parent] + fraction[:, None] * (p[nxt] - p[parent])
    nrm = slerp(t[parent], t[nxt], fraction)
    return pos, nrm, parent, fraction


#: :func:`smooth_along_paths` weighs neighbours up to this many σ of arc length away
SMOOTHING_REACH = 3.0


def smooth_along_paths(positions: np.ndarray, normals: np.ndarray, path_id: np.ndarray, sigma: float,
                       max_angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit axes low-passed along each path: the Gaussian-weighted mean (σ = ``sigma`` mm of arc
    length, up to :data:`SMOOTHING_REACH` σ, never across paths) of the unit ``normals``, each moved
    at most ``max_angle`` from its own (slerp back towards it). The stronger counterpart of
    :func:`low_pass` (§3.5.2) that a robot's tool axis wants: Eq. 3.3's closest points on a faceted
    layer turn the axis by up to 10° from one sample to the next. Returns the axes (m, 3) and their
    angles to ``normals`` (m,) rad."""
    p = np.asarray(positions, np.float64)
    t = _unit(np.asarray(normals, np.float64))
    m = len(t)
    if m < 2 or sigma <= 0 or max_angle <= 0:
        return t, np.zeros(m)
    pid = np.asarray(path_id)
    pid = np.cumsum(np.r_[0, pid[1:] != pid[:-1]])  # runs: a path id met again later is another path
    step = np.r_[0.0, row_norms(np.diff(p, axis=0))]
    step[1:][pid[1:] != pid[:-1]] = 0.0
    s = np.cumsum(step)  # arc length (it restarts nowhere, but pairs across paths are never weighed)
    acc = t.copy()
    reach = SMOOTHING_REACH * sigma
    for k in range(1, m):
        gap = s[k:] - s[:-k]
        near = (gap <= reach) & (pid[k:] == pid[:-k])
        if not near.any():
            break
        i = np.flatnonzero(near)
        w = np.exp(-0.5 * (gap[i] / sigma) ** 2)[:, None]
        acc[i] += w * t[i + k]  # (i is distinct within one k)
        acc[i + k] += w * t[i]
    axes = _unit(acc)
    angle = angles_between(axes, t)
    far = angle > max_angle
    if far.any():
        axes[far] = slerp(t[far], axes[far], max_angle / angle[far])
        angle[far] = angles_between(axes[far], t[far])
    return axes, angle
