"""Beads: every pass centred in the strip of surface nearest to it, with a bead as wide as that
strip (the passes tile the layer despite uneven spacing, thesis §3.7), redundant slivers and dots
dropped, beads widened over what the fit leaves past tips and corners."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from curvslice.executors import query_threads
from curvslice.orientation import closest_points, triangle_reach
from curvslice.toolpaths.constants import (AHEAD_ANGLE, BEAD_RANGE, END_DEPTH, FIT_HALF, FIT_MARGIN, FIT_SAMPLE, FIT_STEP, MAX_SHIFT, MINOR_SHARE,
                                           OPEN_GAP, REDUNDANT_LENGTH, SAME_PASS_BEADS, SEAM_CHORD)
from curvslice.toolpaths.passes import gap_passes, split_off_layer
from curvslice.toolpaths.resampling import resample
from curvslice.toolpaths.stacked import concat_ranges, piece_labels, run_labels, run_offsets
from curvslice.vectors import pair_distances, row_norms


def layer_beads(surface: trimesh.Trimesh, vertices: np.ndarray, faces: np.ndarray, passes: list[np.ndarray],
                width: float, min_bead: Callable[[np.ndarray], np.ndarray] | None,
                fill_gaps: bool, samples: tuple[np.ndarray, np.ndarray, np.ndarray], bridge: np.ndarray | None = None
                ) -> tuple[list[np.ndarray], list[np.ndarray], int, int]:
    """The beads of one layer's ``passes`` over ``surface`` (its bridged, possibly subdivided mesh
    ``vertices``/``faces`` for the gap search; ``samples``: its :func:`surface_samples`, which do not depend
    on the passes; ``bridge``: the vertices of its bridges' fans only): the passes cut where a link leaves the layer (:func:`split_off_layer`, by the layer's
    closest points), every pass fitted to its strip (:func:`fit_beads`),
    :func:`gap_passes` through what even the widest beads leave open when ``fill_gaps`` (then all
    refitted), redundant pieces dropped and the others refitted over their strips
    (:func:`needed_pieces`; without take-over when a refit falls short), loops' seams trimmed
    (:func:`trim_seams`: it moves pass ends, so it stays here). Returns the pieces, their
    per-vertex bead widths (mm), how many gap passes were kept and how many links were cut. The caller's
    last step is widening the beads over the slivers (:func:`fill_slivers`): it changes widths only, never a piece or where it
    ends, so it need not run where the pieces are made (a layer's pieces decide where the next layer
    starts, :func:`curvslice.toolpaths.plan.plan_toolpaths`)."""
    projector = _Projector(surface)
    cut = split_off_layer(passes, lambda x: projector(x)[1], width)
    links = len(cut) - len(passes)
    passes = [p for p in cut if len(p) > 1 and np.ptp(p, axis=0).max() > 1e-9]
    owners = _Owners(samples[0], [resample(p, FIT_STEP * width) for p in passes])
    pieces, widths = _fit_owned(surface, samples, owners, width, min_bead, projector)
    fill = gap_passes(vertices, faces, pieces, width, widths, bridge=bridge) if fill_gaps and len(faces) else []
    if fill:  # what even the widest beads leave open gets passes of its own, then all are refitted
        owners.add([resample(p, FIT_STEP * width) for p in fill])
        pieces, widths = _fit_owned(surface, samples, owners, width, min_bead, projector)
    is_gap = np.arange(len(pieces)) >= len(pieces) - len(fill)
    needed = needed_pieces(pieces, widths, width, samples[0], is_gap, take_over=True)
    if len(needed) < len(pieces):  # the others take over the strips of the redundant ones
        kept = owners.kept(needed)
        refit = _fit_owned(surface, samples, kept, width, min_bead, projector)
        label = piece_labels(pieces)
        orphans = samples[0][~np.isin(label[owners.j], needed)]
        if _faults(orphans, *refit, width) - _faults(orphans, pieces, widths, width) > MINOR_SHARE * len(samples[0]):
            # a refitted bead fell short of what it was to take over (a corner, a pass end)
            needed = needed_pieces(pieces, widths, width, samples[0], is_gap, take_over=False)
            kept = owners.kept(needed)
            refit = _fit_owned(surface, samples, kept, width, min_bead, projector)
        pieces, widths = refit
    pieces, widths = trim_ends(*trim_seams(pieces, widths, width), width)
    return pieces, widths, int(is_gap[needed].sum()), links


def _window(values: np.ndarray, start: np.ndarray, stop: np.ndarray, half: int, how: str) -> np.ndarray:
    """Running max, min, mean or sum of ``values`` over ``±half`` entries, never across the pieces
    whose entries run from ``start`` to ``stop`` (exclusive), one pair per entry."""
    i = np.arange(len(values))
    lo, hi = np.maximum(i - half, start), np.minimum(i + half + 1, stop)
    if how in ("mean", "sum"):
        c = np.r_[0.0, np.cumsum(values)]
        return (c[hi] - c[lo]) / (hi - lo if how == "mean" else 1)
    pick, none = (np.maximum, -np.inf) if how == "max" else (np.minimum, np.inf)
    out = values.copy()
    for k in range(1, half + 1):  # half is a handful of entries
        out = pick(out, np.where(i - k >= lo, values[np.maximum(i - k, 0)], none))
        out = pick(out, np.where(i + k < hi, values[np.minimum(i + k, len(values) - 1)], none))
    return out


def needed_pieces(pieces: list[np.ndarray], widths: list[np.ndarray], width: float,
                  samples: np.ndarray, gap: np.ndarray | None = None, take_over: bool = True) -> list[int]:
    """Indices of the pieces to keep: a piece shorter than ``REDUNDANT_LENGTH`` widths is dropped when
    more of the surface ``samples`` (points, evenly spread) under its bead lie under other kept
    beads than under its own alone -- it would add more overlap than coverage. Typical of the
    slivers and dots of tiny layers, where every bead is at least as wide as the layer is thick;
    the kept neighbours are refitted over what it leaves. A short gap pass (``gap``: a mask of
    the pieces) is also dropped when what it alone covers is under ``MINOR_SHARE`` of the layer: a
    jump is not worth that. With ``take_over``, samples under its bead alone do not count for it
    where the nearest other kept pass can take them over once refitted: its bead, grown towards
    them by a shift of at most half a width, stays within the widest bead (``BEAD_RANGE``) --
    the caller checks the refit (:func:`_faults`). Shortest first."""
    keep = list(range(len(pieces)))
    length = [float(row_norms(np.diff(p, axis=0)).sum()) for p in pieces]
    short = [k for k in sorted(keep, key=lambda i: length[i]) if length[k] < REDUNDANT_LENGTH * width]
    if not short or len(pieces) < 2 or len(samples) == 0:
        return keep
    pts = np.vstack(pieces)
    label = piece_labels(pieces)
    half = 0.5 * np.concatenate(widths)
    # the samples under the short beads, and every piece whose bead covers each of them
    counts = np.array([len(p) for p in pieces])
    stop = np.cumsum(counts)
    own = concat_ranges(stop[short] - counts[short], counts[short])
    reach = float(half.max())
    short_tree = cKDTree(pts[own])
    close = np.nonzero(np.isfinite(short_tree.query(samples, distance_upper_bound=reach, workers=query_threads(len(samples)))[0]))[0]
    under = short_tree.sparse_distance_matrix(cKDTree(samples[close]), reach, output_type="ndarray")
    near = close[np.unique(under["j"][under["v"] <= half[own][under["i"]]])]
    if len(near) == 0:
        return keep
    widest = BEAD_RANGE[1] * width
    hits = cKDTree(samples[near]).sparse_distance_matrix(cKDTree(pts), max(reach, widest), output_type="ndarray")
    hit_row, hit_col, hit_gap = hits["i"], hits["j"], hits["v"]
    # the nearest point of every piece within the widest bead of each sample
    first = _nearest_per_group(hit_row * len(pieces) + label[hit_col], hit_gap)
    first = first[np.lexsort((hit_gap[first], hit_row[first]))]  # by sample, nearest piece first
    row, piece_of, gap_of, half_of = hit_row[first], label[hit_col[first]], hit_gap[first], half[hit_col[first]]
    inside = gap_of <= half_of
    pair = row[inside] * len(pieces) + piece_of[inside]  # (sample, covering piece), unique
    by_piece = np.argsort(pair % len(pieces), kind="stable")
    sample, piece = pair[by_piece] // len(pieces), pair[by_piece] % len(pieces)
    bounds = np.searchsorted(piece, np.arange(len(pieces) + 1))
    count = np.bincount(sample, minlength=len(near))
    kept = np.ones(len(pieces), bool)
    row_bounds = np.searchsorted(row, np.arange(len(near) + 1))  # each sample's block of (piece, distance)
    for k in short:
        if len(keep) == 1:
            break
        mine = sample[bounds[k]:bounds[k + 1]]
        alone = mine[count[mine] == 1]
        # what the nearest other kept pass takes over once refitted: its bead grows towards the
        # sample, up to the widest bead and by a shift of at most half a width
        block = concat_ranges(row_bounds[alone], row_bounds[alone + 1] - row_bounds[alone])
        block = block[(piece_of[block] != k) & kept[piece_of[block]]]
        o_row, o_gap, o_half = row[block], gap_of[block], half_of[block]
        nearest = np.r_[True, o_row[1:] != o_row[:-1]] if len(o_row) else np.zeros(0, bool)
        taken = (o_gap + o_half <= widest) & (o_gap <= 2.0 * MAX_SHIFT * width + o_half) & take_over
        only = len(alone) - int(np.sum(taken[nearest]))
        if len(mine) - len(alone) >= only or (gap is not None and gap[k] and only < MINOR_SHARE * len(samples)):
            keep.remove(k)
            kept[k] = False
            count[mine] -= 1
    return keep


def fit_beads(surface: trimesh.Trimesh, pieces: list[np.ndarray], width: float,
              min_bead: Callable[[np.ndarray], np.ndarray] | None = None,
              samples: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Centre every pass in the strip of surface nearest to it and make its bead as wide as that
    strip (thesis §3.7: the gaps and overlaps that iso-distance spirals leave where their
    contours meet or bunch up; the width is set through the extrusion, as the thesis compensates
    the layer thickness through the feed).

    The passes are re-sampled every ``FIT_STEP`` widths; every surface sample (a lattice, one per
    ``FIT_SAMPLE`` w², plus the boundary every ``FIT_STEP`` widths) belongs to its nearest pass
    point and lies on its left or right (by the layer normal × tangent), at its 3D distance off
    the pass. A point's extent to either side -- the farthest sample it owns, closed (running max
    then min over ``±FIT_HALF`` points), scaled by (k+1)/k for k samples, averaged over
    ``±FIT_HALF`` points so the bead changes smoothly, plus ``FIT_MARGIN``, and never past the
    bisector with another pass (:func:`_bisectors`: that edge is known exactly, and the estimate overran
    it by ~0.015 w, more where a wider strip beside was smoothed in) -- gives the bead ``e_l + e_r`` and
    a shift ``(e_l - e_r)/2`` sideways, so the bead lies over its strip: the beads tile the layer
    instead of overlapping by the spacing error. Beads stay within
    ``BEAD_RANGE`` widths and never narrower than ``min_bead`` (the local layer thickness: a bead
    is at least as wide as it is high) nor, on layers thicker than 0.8 w, wider than twice that
    thickness (the widest strip :func:`~curvslice.toolpaths.rings.thin_rise` leaves to one pass). A pass end also owns what lies ahead of it and is
    lengthened until its round end reaches that far. Where the floor makes a bead wider than its
    strip and one side of the strip is the layer's edge, the excess goes over that edge instead of
    over the neighbour. Returns the fitted pieces and their per-vertex bead widths (mm).
    ``samples`` (points, normals, edge mask) of :func:`surface_samples` may be passed in when
    several fits share one surface.
    """
    fine = [resample(p, FIT_STEP * width) for p in pieces]
    fine = [p for p in fine if len(p) >= 2]
    if not fine or surface.area <= 0:
        return fine, [np.full(len(p), width) for p in fine]
    samples = samples if samples is not None else surface_samples(surface, width)
    return _fit_owned(surface, samples, _Owners(samples[0], fine), width, min_bead)


def _fit_owned(surface: trimesh.Trimesh, samples: tuple[np.ndarray, np.ndarray, np.ndarray], owners: _Owners, width: float,
               min_bead: Callable[[np.ndarray], np.ndarray] | None, projector: _Projector | None = None
               ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """:func:`fit_beads` of the passes ``owners`` holds (already sampled every ``FIT_STEP``
    widths, with the samples' nearest points); unfitted, one width, without any surface."""
    if not owners.fine or surface.area <= 0:
        return owners.fine, [np.full(len(p), width) for p in owners.fine]
    pieces, beads = _fit_strips(samples[0], samples[1], owners.fine, width, min_bead, owners.j, samples[2])
    return _onto_layer(projector or _Projector(surface), samples[0], owners.j, pieces, beads, width)


class _Projector:
    """Closest points on one layer (Eq. 3.3) for :func:`_onto_layer`, with what every call of a layer's
    fits shares: the centroid KD-tree and the triangles' reaches, the boundary edges, and the answers for
    points already asked (a refit keeps most passes' points exactly as they were), sorted by a hash of
    their coordinates' bits and matched exactly (a point whose hash another one holds is computed anew:
    each point's answer is its own, :func:`~curvslice.orientation.closest_points`)."""

    def __init__(self, surface: trimesh.Trimesh):
        self.tri = surface.triangles
        self.tree = cKDTree(self.tri.mean(axis=1))
        self.reach = triangle_reach(self.tri, self.tree)
        self.edge = np.zeros((len(self.tri), 3), bool)  # edge (c, c+1) of each face on the boundary
        border = trimesh.grouping.group_rows(surface.edges_sorted, require_count=1)
        self.edge[border // 3, border % 3] = True
        self.keys, self.pts = np.zeros(0, np.uint64), np.zeros((0, 3))
        self.on, self.moved, self.face = np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64)

    def __call__(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pts = np.ascontiguousarray(pts, np.float64).reshape(-1, 3)
        keys = _point_hash(pts)
        at = np.minimum(np.searchsorted(self.keys, keys), max(len(self.keys) - 1, 0))
        if len(self.keys):
            known = (self.keys[at] == keys) & np.all(self.pts[at] == pts, axis=1)
            on, moved, face = self.on[at], self.moved[at], self.face[at]
        else:
            known = np.zeros(len(pts), bool)
            on, moved, face = np.zeros((len(pts), 3)), np.zeros(len(pts)), np.zeros(len(pts), np.int64)
        ask = np.flatnonzero(~known)
        if len(ask):
            on[ask], moved[ask], face[ask] = closest_points(pts[ask], self.tri, self.tree, reach=self.reach)
            order = np.argsort(np.concatenate([self.keys, keys[ask]]), kind="stable")
            self.keys, self.pts = np.concatenate([self.keys, keys[ask]])[order], np.concatenate([self.pts, pts[ask]])[order]
            self.on, self.moved, self.face = (np.concatenate([self.on, on[ask]])[order], np.concatenate([self.moved, moved[ask]])[order],
                                              np.concatenate([self.face, face[ask]])[order])
        return on, moved, face


def _point_hash(pts: np.ndarray) -> np.ndarray:
    """One uint64 per point of (n, 3) float64 ``pts``: its coordinates' bits mixed by odd multipliers (sorting
    and searching these is several times faster than the points' 24 bytes)."""
    bits = pts.view(np.uint64)  # (array arithmetic wraps modulo 2**64)
    return bits[:, 0] * np.uint64(0x9E3779B97F4A7C15) ^ bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F) ^ bits[:, 2] * np.uint64(0x165667B19E3779F9)


def _onto_layer(layer: _Projector, x: np.ndarray, j: np.ndarray, pieces: list[np.ndarray],
                beads: list[np.ndarray], width: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Fitted passes moved onto the layer (their closest points: the nozzle runs on the surface, and the
    samples are projected there anyway before printing, Eq. 3.3), the beads widened over the surface
    samples ``x`` a pass point (``j``: the nearest of each) reached where the fit put it and no longer
    does (:func:`fill_slivers`: short of the other passes' beads).

    The fit shifts a pass sideways in the tangent plane and lengthens its ends along their tangents;
    on a strongly curved layer (the tip of a part, folded through 80-110° within a few widths) that
    lifts the points a fifth of a width off the surface, over the middle of the fold, where every
    sample is nearer in 3D than from the fold's floor: projected back, the beads fell short of the
    fold's sides (rocker-arm 0.8 layer 94: 99.0 → 89.8 % coverage; now 96.9 %, homer 0.8 layer 75
93.5 → 99.98 %). Only points within ``MAX_SHIFT``
    of the layer move -- the farthest a shift can lift them; farther ones are chords of links across
    a bend, which would land on another part of the layer (they are put back when printed, as
    before). On a flat layer no point moves and no bead changes."""
    pts, bead = np.vstack(pieces), np.concatenate(beads)
    tri, edge = layer.tri, layer.edge
    on, moved, face = layer(pts)
    # a point past the layer's edge (a bead the fit spills over it, a lengthened end) has its closest
    # point on a boundary edge: it stays where the fit put it (the print pulls it onto the edge, as before)
    with np.errstate(all="ignore"):
        bary = trimesh.triangles.points_to_barycentric(tri[face], on)
    past = np.any(edge[face] & (np.roll(bary, -2, axis=1) < 1e-6), axis=1)  # edge c is opposite corner c + 2
    lifted = (moved > 1e-9) & (moved <= MAX_SHIFT * width) & ~past
    if not len(x) or not lifted.any():
        return pieces, beads
    on[~lifted] = pts[~lifted]
    stop = np.cumsum([len(p) for p in pieces])[:-1]
    for a, b in zip(np.r_[0, stop], np.r_[stop, len(pts)]):  # a sliver's dot may fall onto one point
        if np.ptp(on[a:b], axis=0).max() <= 1e-9:
            on[a:b] = pts[a:b]
    # (a sample of a point left where it was is not lost: the same distance is not both within and past its bead)
    lost = np.zeros(len(x), bool)
    at = np.nonzero(np.any(on != pts, axis=1)[j])[0]
    xa, ja = np.take(x, at, axis=0), j[at]
    radius = 0.5 * bead[ja]
    lost[at] = (row_norms(xa - np.take(pts, ja, axis=0)) <= radius) & (row_norms(xa - np.take(on, ja, axis=0)) > radius)
    pieces = np.split(on, stop)
    return pieces, fill_slivers(x[lost], pieces, beads, width, (OPEN_GAP - 0.5) * width)


def _nearest_per_group(code: np.ndarray, gap: np.ndarray) -> np.ndarray:
    """Per distinct ``code``, in rising code order, the index of its smallest ``gap`` (the first such index
    on a tie): ``np.lexsort((gap, code))`` cut to each code's first entry, with one integer sort instead of two."""
    order = np.argsort(code, kind="stable")
    if not len(order):
        return order
    c, g = code[order], gap[order]
    start = np.r_[True, c[1:] != c[:-1]]
    group = np.cumsum(start) - 1
    lowest = np.flatnonzero(g == np.minimum.reduceat(g, np.flatnonzero(start))[group])  # (every group has one)
    return order[lowest[np.r_[True, group[lowest][1:] != group[lowest][:-1]]]]


class _Owners:
    """The nearest pass point of every surface sample ``x`` (index into the stacked ``fine``
    passes) while passes are added and dropped: the nearest of the remaining passes stays the
    nearest, so only the new passes or the orphaned samples are searched (one KD query each)."""

    def __init__(self, x: np.ndarray, fine: list[np.ndarray]):
        self.x, self.fine = x, []
        self.d, self.j = np.full(len(x), np.inf), np.zeros(len(x), np.int64)
        self.add(fine)

    def add(self, fine: list[np.ndarray]) -> None:
        if fine and len(self.x):
            d, j = nearest_below(cKDTree(np.vstack(fine)), self.x, self.d)  # (only a nearer point changes an owner)
            better = d < self.d
            self.d[better], self.j[better] = d[better], sum(len(p) for p in self.fine) + j[better]
        self.fine = self.fine + list(fine)

    def kept(self, indices: list[int]) -> "_Owners":
        """The owners once only the passes ``indices`` remain (this one unchanged)."""
        counts = np.array([len(p) for p in self.fine], np.int64)
        start = np.cumsum(counts) - counts
        renumber = np.full(int(counts.sum()), -1, np.int64)
        renumber[concat_ranges(start[indices], counts[indices])] = np.arange(counts[indices].sum())
        out = _Owners(self.x, [])
        out.fine, out.d, out.j = [self.fine[i] for i in indices], self.d.copy(), renumber[self.j]
        orphan = np.nonzero(out.j < 0)[0]
        if len(orphan):
            out.d[orphan], out.j[orphan] = cKDTree(np.vstack(out.fine)).query(self.x[orphan], workers=query_threads(len(orphan)))
        return out


def nearest_below(tree: cKDTree, points: np.ndarray, cap: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance and index of the nearest point of ``tree`` to each of ``points`` (``cKDTree.query``) where that
    distance is below the point's ``cap``; elsewhere the same or ``inf`` and ``tree.n``. The points whose caps are
    among the lowest ``_CAPPED`` are searched no farther than the highest of those caps (the search of a point
    far from every point of ``tree`` then stops at once), the others as far as it takes."""
    d, j = np.full(len(points), np.inf), np.full(len(points), tree.n, np.int64)
    if not len(points):
        return d, j
    bound = np.partition(cap, int(_CAPPED * (len(cap) - 1)))[int(_CAPPED * (len(cap) - 1))]
    low = cap <= bound
    for group, upper in ((low, bound * (1.0 + 1e-9)), (~low, np.inf)):  # (a margin: a capped point is found)
        if group.any():
            d[group], j[group] = tree.query(points[group], distance_upper_bound=upper,
                                             workers=query_threads(int(group.sum())))
    return d, j


#: Share of the points that :func:`nearest_below` searches no farther than their group's highest cap.
_CAPPED = 0.9


def _faults(x: np.ndarray, pieces: list[np.ndarray], widths: list[np.ndarray], width: float) -> int:
    """How many of the points ``x`` are open (farther than ``OPEN_GAP - 0.5`` widths beyond every
    bead, as :func:`gap_passes` has it) or under the beads of two pieces or more (``widths``: the
    pieces' vertex bead widths; sampled every ``FIT_STEP`` widths, as the fits' lengthened ends
    are not)."""
    if not pieces:
        return len(x)
    dense = [resample(np.c_[p, b], FIT_STEP * width) for p, b in zip(pieces, widths)]
    label = piece_labels(dense)
    dense = np.vstack(dense)
    pts, half = dense[:, :3], 0.5 * dense[:, 3]
    tree = cKDTree(pts)
    d, j = tree.query(x, workers=query_threads(len(x)))
    near = cKDTree(x).sparse_distance_matrix(tree, float(half.max()), output_type="ndarray")
    inside = near["v"] <= half[near["j"]]
    beads = np.bincount(np.unique(near["i"][inside] * len(pieces) + label[near["j"][inside]]) // len(pieces),
                        minlength=len(x))
    return int(np.sum((d > half[j] + (OPEN_GAP - 0.5) * width) | (beads > 1)))


def fill_slivers(x: np.ndarray, pieces: list[np.ndarray], widths: list[np.ndarray], width: float,
                 beyond: float | None = None, inner: np.ndarray | None = None) -> list[np.ndarray]:
    """Bead widths (one array per piece) widened over what the beads leave open: surface samples ``x``
    beyond every bead -- past a tip or a corner, where the fitted extent is a running mean, under a
    loop's seam, between passes whose strips the fit fell short of. Each open sample is reached by the bead
    whose edge lies nearest to it (of the pass points nearest to it) among those the widest bead
    (``BEAD_RANGE``) lets reach it; that bead grows towards it, up to the edge of every other pass's
    bead as that one stands once grown by its own claim: what it asks for, but at most up to the halfway
    line of the free space between the two (``(d + b_q/2 - b_p/2) / 2`` from q for centres ``d``
    apart). So two grown beads never overlap, two that both ask for a strip split it at its middle, and a
    bead that asks for nothing (or cannot grow) leaves the strip to its neighbour up to its own edge (the
    old rule stopped 0.15 w beyond a bead and a margin short of the neighbour as it stood: cheburashka 0.8
    layer 56, a loop whose beads fell short of its middle and its seam, 94.6 % coverage). "Another pass"
    is another piece, or the same piece more than ``SAME_PASS_BEADS`` beads away along it (a spiral's next
    ring). A lattice sample stands for the surface around it (``inner``: the samples off the layer's
    boundary, each for a disc of ``FIT_SAMPLE`` area, clipped at the layer's edge), so a bead grows that
    much past it and a sample that close to a bead's edge counts as open. ``beyond``: only samples at most
    this far (mm) beyond every bead (the fits' own widening over their lost samples stays a hairline,
    ``OPEN_GAP - 0.5`` widths, and leaves wider strips to :func:`gap_passes`); ``None``: every open
    sample within reach (the last step of a layer, once its gap passes are placed)."""
    if not pieces or not len(x):
        return widths
    pts, half = np.vstack(pieces), 0.5 * np.concatenate(widths)
    label = piece_labels(pieces)
    key = np.concatenate([np.r_[0.0, np.cumsum(row_norms(np.diff(p, axis=0)))] for p in pieces])
    widest = 0.5 * BEAD_RANGE[1] * width
    tree = cKDTree(pts)
    # the radius of the surface a lattice sample stands for (its FIT_SAMPLE area as a disc): past the
    # layer's edge there is none, so a boundary sample stands for itself
    x_all = x
    own = np.where(inner, np.sqrt(FIT_SAMPLE / np.pi) * width, 0.0) if inner is not None else np.zeros(len(x))
    # a sample deeper than that inside the bead of its nearest pass point is covered whatever the others
    d1, j1 = tree.query(x, workers=query_threads(len(x)))
    ask = np.nonzero(d1 - half[j1] > -own)[0]
    if not len(ask):
        return widths
    x, own = x[ask], own[ask]
    if inner is not None and (~inner).any() and len(x):  # ... and only as far as the layer reaches
        # (a boundary sample farther than every radius changes none: the search stops there)
        own = np.minimum(own, cKDTree(x_all[~inner]).query(x, distance_upper_bound=2.0 * own.max(),
                                                           workers=query_threads(len(x)))[0])
    # the nearest bead edge among the nearest pass points (a narrower bead nearer than a wider one)
    k = min(_EDGE_CANDIDATES, len(pts))
    d, j = tree.query(x, k=k, distance_upper_bound=widest + float(half.max()), workers=query_threads(len(x)))
    d, j = d.reshape(len(x), k), j.reshape(len(x), k)
    gap = np.where(j < len(pts), d - half[np.minimum(j, len(pts) - 1)], np.inf)
    rows = np.arange(len(x))
    nearest = gap[rows, np.argmin(gap, axis=1)]
    # of the beads that can grow to it (the widest reaches it), else of all
    reach = np.where(d <= widest, gap, np.inf)
    pick = np.where(np.isfinite(reach.min(axis=1)), np.argmin(reach, axis=1), np.argmin(gap, axis=1))
    d, j = d[rows, pick], j[rows, pick]
    sliver = (nearest > -own) & np.isfinite(nearest) & (nearest <= (np.inf if beyond is None else beyond))
    if not sliver.any():
        return widths
    # the radius each bead asks for: its own, or out past its farthest open sample by the radius of the
    # surface a sample stands for (its FIT_SAMPLE area as a disc): the samples are a lattice, and a bead
    # stopping at the last one leaves the strip up to the next one open
    want = half.copy()
    np.maximum.at(want, j[sliver], np.minimum(d[sliver] + own[sliver], widest))
    # as far as its neighbours along the pass ask (±FIT_HALF points, as the fit smooths a bead): the
    # open samples are a lattice about 0.14 w apart, so a point between two that reached one would stay
    # narrow, and the re-sampled path (1 mm) would average the single wide points away
    if beyond is None:
        counts = np.array([len(p) for p in pieces])
        stop = np.cumsum(counts)
        want = np.maximum(_window(want, np.repeat(stop - counts, counts), np.repeat(stop, counts), FIT_HALF, "max"), half)
    owners = np.nonzero(want > half)[0]
    if not len(owners):
        return widths
    # (a bead claims at most what it asks for, so beads farther apart than twice the largest ask never meet;
    # nearly every point asks, so each pair is found once and taken both ways)
    a, b = tree.query_pairs(float(2.0 * want.max()), output_type="ndarray").T
    apart = np.abs(key[a] - key[b])
    across = label[a] != label[b]
    keep = across | (apart > SAME_PASS_BEADS * width)  # (most pairs lie along one pass)
    a, b, apart, across = a[keep], b[keep], apart[keep], across[keep]
    a_asks = (want[a] > half[a]) & (across | (apart > 2.0 * SAME_PASS_BEADS * half[b]))
    b_asks = (want[b] > half[b]) & (across | (apart > 2.0 * SAME_PASS_BEADS * half[a]))
    owner, other = np.r_[a[a_asks], b[b_asks]], np.r_[b[a_asks], a[b_asks]]
    dist = pair_distances(pts, a, b)
    dist = np.r_[dist[a_asks], dist[b_asks]]
    # up to the other bead's edge as it stands once grown by what it claims: what it asks for, at most
    # up to the halfway line of the free space between the two (so two beads that both ask for it split it)
    halfway = 0.5 * (dist + half[other] - half[owner])
    claim = np.maximum(half[other], np.minimum(want[other], halfway))
    limit = np.full(len(pts), np.inf)
    np.minimum.at(limit, owner, dist - claim)
    grown = half.copy()
    # never narrower than fitted: a thick layer's fit may reach past BEAD_RANGE (twice the thickness, _fit_strips),
    # and clipping to the widest cut such a bead back to 1.6 w (a 1.8 w strip on a layer 1 w thick: 92 % coverage)
    grown[owners] = np.maximum(np.minimum(np.minimum(want[owners], limit[owners]), widest), half[owners])
    return np.split(2.0 * grown, np.cumsum([len(p) for p in pieces])[:-1])


#: :func:`fill_slivers` compares the bead edges of this many nearest pass points (sampled every ``FIT_STEP``
#: widths): about ±0.4 w of the nearest pass, and another pass's points where they lie as near. A wider bead
#: whose centre lies farther than these but whose edge is nearer is not found; the sample then goes to the
#: nearest centre's bead, as it did before the edges were compared. (A search cap, not a tuned value: 16
#: gave the same coverage within 0.05 % on kitten 0.8 layers 82 and 89, for more query time.)
_EDGE_CANDIDATES = 8


def _bisectors(pts: np.ndarray, side: np.ndarray, owner: np.ndarray, extent: np.ndarray) -> np.ndarray:
    """How far each pass point's strip may reach to its left and right (rows 0 and 1, as ``extent``) before
    the bisector with another pass: among the ``_BISECTOR_NEIGHBOURS`` pass points nearest to the end of
    the strip as ``extent`` has it, each ``q`` on another pass (or on the same pass more than
    ``SAME_PASS_BEADS`` widths along it) puts the bisector at ``|v|² / (2 v·s)`` along the point's sideways
    line ``s`` (``v`` from the point to ``q``); inf where none does. A strip reaching past a bisector has the
    other pass nearer to its end than its own, so those are the points found."""
    n = len(pts)
    k = min(_BISECTOR_NEIGHBOURS, n)
    s = np.stack([side, -side])  # (2, n, 3): the sideways line to the left, to the right
    # q lies nearer than the bisector at the strip's end e exactly when |q - (p + e s)| < e
    d, q = cKDTree(pts).query((pts + extent[..., None] * s).reshape(-1, 3), k=k, distance_upper_bound=float(extent.max()),
                              workers=query_threads(2 * n))
    d, q = d.reshape(2, n, k), np.minimum(q.reshape(2, n, k), n - 1)
    i = np.arange(n)[:, None]
    other = (d < extent[..., None]) & ((owner[q] != owner[i]) | (np.abs(q - i) * FIT_STEP > SAME_PASS_BEADS))
    v = np.take(pts, q, axis=0) - pts[i]
    lat = np.einsum("rikj,rij->rik", v, s)
    ok = other & (lat > 1e-9)
    return np.min(np.where(ok, np.einsum("rikj,rikj->rik", v, v) / (2.0 * np.where(ok, lat, 1.0)), np.inf), axis=2)


#: Pass points :func:`_bisectors` looks among for another pass near the end of a strip: the nearest is the other
#: pass's, or inside a bend its own pass's with the other's next (three or eight gave the same coverage and
#: overlap on the kitten 2.5 mm and the five corpus cases the cap was for, at more cost).
_BISECTOR_NEIGHBOURS = 2


def _group_max(index: np.ndarray, values: np.ndarray, n: int, order: np.ndarray) -> np.ndarray:
    """Largest of ``values`` per ``index`` in ``range(n)``, at least 0 (``np.maximum.at``, sorted), over the
    entries ``order``: some or all positions, in a stable order of ``index``."""
    out = np.zeros(n)
    if len(order):
        idx = index[order]
        starts = np.r_[0, np.nonzero(np.diff(idx))[0] + 1]
        out[idx[starts]] = np.maximum(np.maximum.reduceat(values[order], starts), 0.0)
    return out


def surface_samples(surface: trimesh.Trimesh, width: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points of ``surface`` on a barycentric lattice of each triangle, about one per
    ``FIT_SAMPLE`` w² (even, unlike random samples: no voids to under-estimate a strip by), and
    on its boundary every ``FIT_STEP`` widths, with the normals of their triangles and a mask
    of the boundary ones."""
    tri = surface.triangles
    order = np.maximum(np.ceil(np.sqrt(2.0 * surface.area_faces / (FIT_SAMPLE * width**2))), 1).astype(np.int64)
    points, normals = [], []
    for m in np.unique(order):
        faces = np.nonzero(order == m)[0]
        i, j = np.triu_indices(m + 1)
        bary = np.c_[m - j, j - i, i] / m  # (m+1)(m+2)/2 lattice points, the corners and edges included
        points.append(np.einsum("pk,fkd->fpd", bary, tri[faces]).reshape(-1, 3))
        normals.append(np.repeat(surface.face_normals[faces], len(bary), axis=0))
    edges = trimesh.grouping.group_rows(surface.edges_sorted, require_count=1)
    if len(edges):
        a, b = surface.vertices[surface.edges[edges, 0]], surface.vertices[surface.edges[edges, 1]]
        k = np.maximum(np.ceil(row_norms(b - a) / (FIT_STEP * width)), 1).astype(np.int64)
        e = run_labels(k)
        u = run_offsets(k) / k[e]
        points.append(a[e] + u[:, None] * (b[e] - a[e]))
        normals.append(surface.face_normals[surface.edges_face[edges][e]])
    points = np.vstack(points)
    edge = np.zeros(len(points), bool)
    edge[len(points) - (int(k.sum()) if len(edges) else 0):] = True
    return points, np.vstack(normals), edge


def _fit_strips(x: np.ndarray, xn: np.ndarray, fine: list[np.ndarray], width: float,
                min_bead: Callable[[np.ndarray], np.ndarray] | None,
                j: np.ndarray, edge: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """:func:`fit_beads` on passes sampled every ``FIT_STEP`` widths and surface samples ``x``
    (triangle normals ``xn``; ``j`` the nearest pass point of each, :class:`_Owners`; ``edge``
    the samples on the layer's boundary): the shifted passes and their beads."""
    counts = np.array([len(p) for p in fine])
    pts = np.vstack(fine)
    n = len(pts)
    stop = np.cumsum(counts)
    start = stop - counts
    owner = run_labels(counts)
    lo, hi = start[owner], stop[owner]
    i = np.arange(n)
    tan = pts[np.minimum(i + 1, hi - 1)] - pts[np.maximum(i - 1, lo)]
    tan /= np.maximum(row_norms(tan)[..., None], 1e-300)
    first, last = i == lo, i == hi - 1

    normal = np.stack([np.bincount(j, weights=xn[:, c], minlength=n) for c in range(3)], axis=1)
    normal = np.stack([_window(normal[:, c], lo, hi, 2 * FIT_HALF, "mean") for c in range(3)], axis=1)
    side = np.cross(normal, tan)
    norm = row_norms(side)[..., None]
    side = np.where(norm > 1e-9, side / np.maximum(norm, 1e-300), 0.0)

    off, tan_j = x - np.take(pts, j, axis=0), np.take(tan, j, axis=0)  # (take: 4x numpy's row indexing)
    along = np.einsum("ij,ij->i", off, tan_j)
    # distance off the pass in 3D (the chord across a curved strip, as the bead must reach),
    # on the side the layer's tangent plane puts it
    left = np.einsum("ij,ij->i", off, np.take(side, j, axis=0)) >= 0
    lateral = row_norms(off - along[:, None] * tan_j) * np.where(left, 1.0, -1.0)
    # one sort for the three group maxima (as 16-bit keys where they fit: numpy's radix sort, the same order)
    by_point = np.argsort(j.astype(np.uint16) if n <= 1 << 16 else j, kind="stable")
    extent = np.stack([_group_max(j, lateral, n, by_point[left[by_point]]), _group_max(j, -lateral, n, by_point[~left[by_point]])])
    owned = np.stack([np.bincount(j[left], minlength=n), np.bincount(j[~left], minlength=n)]).astype(np.float64)
    reach = _group_max(j, np.where(last[j], along, np.where(first[j], -along, 0.0)), n, by_point)  # ahead of an end
    # the farthest of k samples spread evenly over [0, e] lies at e·k/(k+1) on average
    # closing (running max, then min): fills the dips where no sample happened to lie near the
    # strip's edge without spreading a wide stretch into a narrow one; the farthest of k samples
    # spread evenly over [0, e] lies at e·k/(k+1); a running mean smooths the bead
    closed = [_window(_window(e, lo, hi, FIT_HALF, "max"), lo, hi, FIT_HALF, "min") for e in extent]
    ends = first | last  # a pass end keeps the extent of all it owns (its cap, not to be eroded)
    extent = np.stack([np.where(ends, np.maximum(m, e), m) for m, e in zip(
        [_window(e * (1 + 1 / np.maximum(_window(c, lo, hi, FIT_HALF, "sum"), 1)), lo, hi, FIT_HALF, "mean")
         for e, c in zip(closed, owned)], extent)]) + FIT_MARGIN * width
    extent = np.minimum(extent, _bisectors(pts, side, owner, extent))
    floor = np.full(n, BEAD_RANGE[0] * width)
    widest = np.full(n, BEAD_RANGE[1] * width)
    if min_bead is not None:
        thick = min_bead(pts)
        floor = np.clip(thick, floor, widest)
        # a pass down a strip too narrow for two beads as high as the layer is thick spans up to twice
        # that height (thin_rise's rule): on layers thicker than the default 0.8 w, wider than BEAD_RANGE
        widest = np.maximum(widest, 2.0 * thick)
    bead = np.clip(extent.sum(axis=0), floor, widest)
    # a bead wider than its strip (the floor) spills over the layer's edge where it has one
    spill = np.stack([_window(np.bincount(j[s & edge], minlength=n).astype(np.float64), lo, hi, FIT_HALF, "max") > 0
                      for s in (left, ~left)])
    excess = np.maximum(bead - extent.sum(axis=0), 0.0)
    shift = np.clip(0.5 * (extent[0] - extent[1]) + 0.5 * excess * (spill[0].astype(float) - spill[1]),
                    -MAX_SHIFT * width, MAX_SHIFT * width)
    pts = pts + shift[:, None] * side
    grow = np.maximum(reach - 0.5 * bead, 0.0)
    pts[first] -= grow[first, None] * tan[first]
    pts[last] += grow[last, None] * tan[last]
    return np.split(pts, stop[:-1]), np.split(bead, stop[:-1])


def trim_seams(pieces: list[np.ndarray], widths: list[np.ndarray], width: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Pieces whose two ends meet head-on across a seam (a loop's walk: the path, continued past
    its end, would run into its start, more than two beads away along it) trimmed back equally at
    both ends, by at most half their mean end bead, until the chord between the ends is
    ``SEAM_CHORD`` of that bead: the round caps then cover as much surface twice as they leave
    open between them. The fit widens the end beads of a small loop up to the widest bead, while
    its walk stops one width short of its start, so the caps overlapped (homer 0.8 layer 91: a
    loop 4.6 w long, 1.6 w end beads 0.95 w apart, 7.6 % overlap)."""
    out_p, out_w = [], []
    for p, b in zip(pieces, widths):
        out_p.append(p)
        out_w.append(b)
        if len(p) < 3:
            continue
        cum = np.r_[0.0, np.cumsum(row_norms(np.diff(p, axis=0)))]
        total, gap = cum[-1], p[0] - p[-1]
        # each end's heading over half a width of its walk (its last segment alone may be a fit's hook)
        reach = min(0.5 * width, 0.5 * total)
        behind = np.stack([np.interp([reach, total - reach], cum, p[:, i]) for i in range(3)], axis=-1)
        head_on = np.dot(gap, p[-1] - behind[1]) > 0 and np.dot(gap, behind[0] - p[0]) > 0
        if not head_on or total <= 2.0 * max(float(b.max()), width) + np.linalg.norm(gap):
            continue
        trims = np.linspace(0.0, 0.25 * (b[0] + b[-1]), 51)
        s = np.stack([trims, total - trims], axis=1)
        ends = np.stack([np.interp(s, cum, p[:, i]) for i in range(3)], axis=-1)
        bead = np.interp(s, cum, b)
        apart = row_norms(ends[:, 1] - ends[:, 0]) >= SEAM_CHORD * bead.mean(axis=1)
        if apart[0] or not apart.any():
            continue
        k = int(np.argmax(apart))
        keep = (cum > trims[k]) & (cum < total - trims[k])
        out_p[-1] = np.vstack([ends[k, :1], p[keep], ends[k, 1:]])
        out_w[-1] = np.r_[bead[k, 0], b[keep], bead[k, 1]]
    return out_p, out_w



def trim_ends(pieces: list[np.ndarray], widths: list[np.ndarray], width: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Pass ends trimmed back along their pieces until their round caps stop where they touch the bead
    of another pass (another piece, or the same piece more than ``SAME_PASS_BEADS`` beads away along it from
either end: a loop's seam is :func:`trim_seams`'):
    half the end's bead from that bead's side. The fit lengthens an end over all it owns ahead and keeps
    that fan's whole lateral extent, so where a pass or a gap pass ends at the side of another bead (a
    T-junction), its cap ran into that bead (kitten 0.8 at 0.6 w layer 65: 6.7 % overlap). Only beads ahead
    of the end count (within ``AHEAD_ANGLE`` of its direction): trimming does not take an end away from a
    bead beside it (two chords to and fro lost their ends to each other: a disc 1.9 w across 97 -> 86 %
    coverage). An end is trimmed by at most its bead and a third of its piece, as far as that takes the
    overlap; the ends in order, each against the pieces as trimmed so far."""
    if not pieces:
        return pieces, widths
    pts, bead = np.vstack(pieces), np.concatenate(widths)
    label = piece_labels(pieces)
    cums = [np.r_[0.0, np.cumsum(row_norms(np.diff(p, axis=0)))] for p in pieces]
    key = np.concatenate(cums)
    alive = np.ones(len(pts), bool)
    tree = cKDTree(pts)
    reach = float(bead.max())
    start = np.r_[0, np.cumsum([len(p) for p in pieces])[:-1]]
    out_p, out_w = list(pieces), list(widths)
    for i, (p, b, cum) in enumerate(zip(pieces, widths, cums)):
        total = cum[-1]
        if len(p) < 2 or total <= 0:
            continue
        span = [0.0, total]  # the piece's arclengths kept
        for tail in (0, 1):
            near = np.array(tree.query_ball_point(p[-1] if tail else p[0], reach), np.int64)
            if len(near) == 0:
                continue
            end, inward = (p[-1], p[-2]) if tail else (p[0], p[1])
            ahead = pts[near] - end
            out = (end - inward) / max(float(np.linalg.norm(end - inward)), 1e-300)
            # the same piece counts away from this end and from its other one (a seam, trim_seams')
            along = SAME_PASS_BEADS * np.maximum(width, bead[near])
            near = near[alive[near] & ((label[near] != i) | ((np.abs(key[near] - span[tail]) > along)
                                                             & (np.abs(key[near] - span[1 - tail]) > along)))
                        & (ahead @ out >= np.cos(AHEAD_ANGLE) * row_norms(ahead))]
            if len(near) == 0:
                continue
            trims = np.linspace(0.0, min(float(b[-tail]), total / 3.0), 21)
            s = span[1] - trims if tail else span[0] + trims
            ends = np.column_stack([np.interp(s, cum, p[:, c]) for c in range(3)])
            end_bead = np.interp(s, cum, b)
            depth = (0.5 * (end_bead[:, None] + bead[near][None])
                     - row_norms(ends[:, None] - pts[near][None])).max(axis=1)
            clear = np.nonzero(depth <= END_DEPTH * end_bead)[0]
            k = int(clear[0]) if len(clear) else int(np.argmin(depth))
            span[tail] = float(s[k])
        if span == [0.0, total]:
            continue
        keep = (cum > span[0]) & (cum < span[1])
        alive[start[i]:start[i] + len(p)] = keep
        ends = np.column_stack([np.interp(span, cum, p[:, c]) for c in range(3)])
        out_p[i] = np.vstack([ends[:1], p[keep], ends[1:]])
        out_w[i] = np.r_[np.interp(span[0], cum, b), b[keep], np.interp(span[1], cum, b)]
    return out_p, out_w
