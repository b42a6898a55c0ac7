"""Re-sampling of passes at the path step (thesis §3.5.2) and extrusion per segment (volume
conservation, :func:`curvslice.flow.filament_length`)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from curvslice.flow import filament_length
from curvslice.toolpaths.constants import CORNER_ANGLE, SAME_PASS_BEADS
from curvslice.toolpaths.stacked import run_labels, run_offsets
from curvslice.vectors import row_norms


def resample(polyline: np.ndarray, step: float, value_weight: float = 0.0, turn_weight: float = 0.0) -> np.ndarray:
    """Uniform re-sampling at spacing ≤ ``step`` (thesis §3.5.2: 1 mm) keeping sharp corners.

    Columns after the first three (x, y, z) are per-vertex values interpolated along the way.
    With ``value_weight`` > 0 the spacing is uniform in ``√(ds² + (value_weight·dv)²)`` instead of
    the arclength ``ds``, so where a value (a bead width) changes, samples come closer and its
    profile survives the linear interpolation between them. ``turn_weight`` adds that much length
    per radian the path turns (below the kept corners), so bends keep their samples."""
    p = np.asarray(polyline, np.float64)
    seg = row_norms(np.diff(p[:, :3], axis=0))
    p = p[np.concatenate([[True], seg > 1e-9])]  # (np.concatenate: np.r_ costs more than the rest at a few points)
    if len(p) < 2:
        return p[:1].copy()
    d = np.diff(p[:, :3], axis=0)
    u = d / row_norms(d)[..., None]
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", u[:-1], u[1:]), -1, 1))
    keep = np.concatenate([[0], np.nonzero(turn > CORNER_ANGLE)[0] + 1, [len(p) - 1]])
    bend = np.concatenate([[0.0], np.where(turn > CORNER_ANGLE, 0.0, turn), [0.0]])
    cum = np.concatenate([[0.0], np.cumsum(row_norms(np.concatenate([d, value_weight * np.diff(p[:, 3:], axis=0)], axis=1))
                                           + turn_weight * 0.5 * (bend[:-1] + bend[1:]))])
    # every run between kept corners in n equal steps (the corners themselves are knots of cum)
    start, span = cum[keep[:-1]], cum[keep[1:]] - cum[keep[:-1]]
    n = np.maximum(np.ceil(span / step - 1e-9), 1).astype(np.int64)
    run = run_labels(n)
    s = np.concatenate([start[run] + span[run] * run_offsets(n) / n[run], cum[-1:]])
    return np.column_stack([np.interp(s, cum, p[:, i]) for i in range(p.shape[1])])


def extrusion_amounts(positions: np.ndarray, path_id: np.ndarray, thickness: np.ndarray, width,
                      filament_diameter: float, layer: np.ndarray | None = None) -> np.ndarray:
    """Filament length per segment (0 at each piece's first sample): the thickness averaged on it, the
    bead width (a number or one per sample) too, raised where a sample's width would be laid by neither
    of its segments; a bead is never narrower than it is high.

    A segment is laid at one width, so a sample's width is what its wider segment lays there. At the mean
    of its ends, a sample wider than both its neighbours -- the end of a pass whose fit widened it to reach
    a tip (:func:`~curvslice.toolpaths.beads.fit_beads`), a bead widened over a sliver
    (:func:`~curvslice.toolpaths.beads.fill_slivers`) -- was laid narrower than fitted, and the surface it
    was widened for stayed open (kitten 0.8 mm at path width 1.5 w, layer 82: 94.7 % coverage; the small
    loops of fertility and cheburashka 0.8). Such a sample's width is laid by its one segment whose other
    end is wider (less material beyond what the fit asked for; a pass end: its only segment), short of the
    beads of the other passes as the means lay them (another piece of its ``layer``, or the same one more
    than ``SAME_PASS_BEADS`` beads along it), as :func:`~curvslice.toolpaths.beads.fill_slivers` widens."""
    pos = np.asarray(positions, np.float64)
    seg = np.r_[0.0, row_norms(np.diff(pos, axis=0))]
    h = np.r_[thickness[0], 0.5 * (thickness[1:] + thickness[:-1])]
    w = np.broadcast_to(np.asarray(width, np.float64), h.shape)
    first = np.r_[True, path_id[1:] != path_id[:-1]]
    # segment k ends at sample k (none at a piece's first sample): laid at the mean of its two ends
    b = np.where(first, 0.0, np.r_[w[0], 0.5 * (w[1:] + w[:-1])])
    after = np.r_[b[1:], 0.0]  # the segment leaving each sample (0: none)
    short = np.nonzero((w > b) & (w > after))[0]
    if len(short):
        prev_w = np.where(first, -np.inf, np.r_[-np.inf, w[:-1]])[short]
        next_w = np.where(np.r_[first[1:], True], -np.inf, np.r_[w[1:], -np.inf])[short]
        target = np.minimum(w[short], bead_room(pos, seg, first, b, short, w[short], layer))
        k = np.where(prev_w >= next_w, short, short + 1)  # the segment towards the wider neighbour
        ok = (target > b[np.minimum(k, len(b) - 1)]) & (k < len(b)) & ((k == short) | ~np.r_[first, True][k])
        b = b.copy()
        np.maximum.at(b, k[ok], target[ok])
    e = filament_length(seg, np.maximum(b, h), h, filament_diameter)
    e[first] = 0.0
    return e


def bead_room(pos: np.ndarray, seg: np.ndarray, first: np.ndarray, laid: np.ndarray, at: np.ndarray, want: np.ndarray,
              layer: np.ndarray | None) -> np.ndarray:
    """Twice the room from each sample ``at`` (asking for widths ``want``) to the nearest edge of another
    pass's bead as ``laid`` per segment (another piece of the same ``layer``, or the same piece
    more than ``SAME_PASS_BEADS`` of that bead along it): the widest bead laid there without covering
    another pass. Segments are cut into parts of at most half the median bead, each found by its middle."""
    inner = ~first
    part = 0.5 * float(np.median(laid[inner])) if inner.any() else 1.0
    arclen = np.cumsum(np.where(inner, seg, 0.0))  # along each piece, from its first sample
    n = np.where(inner, np.maximum(np.ceil(seg / part), 1), 0).astype(np.int64)
    k = run_labels(n)  # the segment of each part (ends at sample k)
    if not len(k):
        return np.full(len(at), np.inf)
    t0, t1 = run_offsets(n) / n[k], (run_offsets(n) + 1) / n[k]
    a = pos[k - 1] + t0[:, None] * (pos[k] - pos[k - 1])
    ab = (t1 - t0)[:, None] * (pos[k] - pos[k - 1])
    length2 = np.einsum("ij,ij->i", ab, ab)
    piece = np.cumsum(first) - 1
    lay = np.zeros(len(pos), np.int64) if layer is None else np.asarray(layer)
    reach = 0.5 * (float(want.max()) + float(laid.max())) + 0.5 * float(np.sqrt(length2.max()))
    apart = 2.0 * reach * lay  # a fourth coordinate: other layers lie out of reach
    pairs = cKDTree(np.c_[pos[at], apart[at]]).sparse_distance_matrix(cKDTree(np.c_[a + 0.5 * ab, apart[k]]), reach,
                                                                      output_type="coo_matrix")
    i, j = pairs.row, pairs.col
    s, d = at[i], k[j]
    rel, abj = pos[s] - a[j], ab[j]
    u = np.clip(np.einsum("ij,ij->i", rel, abj) / np.maximum(length2[j], 1e-300), 0.0, 1.0)
    along = np.abs(arclen[d - 1] + (t0[j] + u * (t1[j] - t0[j])) * seg[d] - arclen[s])  # to the part's closest point
    other = (piece[d] != piece[s]) | (along > SAME_PASS_BEADS * laid[d])
    gap = row_norms(rel[other] - u[other, None] * abj[other]) - 0.5 * laid[d[other]]
    room = np.full(len(at), np.inf)
    np.minimum.at(room, i[other], gap)
    return 2.0 * np.maximum(room, 0.0)
