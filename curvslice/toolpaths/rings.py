"""Iso-contours ("rings") of the boundary distance on a working surface (thesis §3.5.1, Fig. 3.9).

Rings at ``(k + FIRST_LEVEL)·w`` as closed polylines with the higher side on their left, the
band components between levels (the contour tree: a ring bounds one component below and one
above), the spacing correction :func:`contour_gap`, and the extra contours and centre lines of
peaks and slivers the regular levels miss.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from curvslice.executors import query_threads
from curvslice.geodesic import edge_keys
from curvslice.toolpaths.constants import (BEAD_MIN, BEAD_RANGE, CENTRE_BIN, DENSE_STEP, DOT_RING, FIRST_LEVEL, GAP_LEVELS,
                                           ISLAND_RISE, OPEN_GAP, PEAK_RISE, PINCH_ALONG, PINCH_LENGTH, ROUND_RING,
                                           SLIVER_TOP, THIN_LOOP)
from curvslice.toolpaths.resampling import resample
from curvslice.toolpaths.stacked import run_labels, run_offsets
from curvslice.vectors import row_norms


@dataclass
class Ring:
    """A closed iso-contour: points (k,3) with the higher distance on the left, its band comps,
    the largest distance on its higher side (``top``, where known) and the narrowest bead along it
    (``floor``, in widths: the local layer thickness)."""

    level: float
    points: np.ndarray
    below: int
    above: int
    top: float = np.inf
    floor: float = BEAD_MIN

    @property
    def length(self) -> float:
        return float(self.cumlen[-1])

    @property
    def cumlen(self) -> np.ndarray:
        closed = np.vstack([self.points, self.points[:1]])
        return np.concatenate([[0.0], np.cumsum(row_norms(np.diff(closed, axis=0)))])

    @property
    def breadth(self) -> float:
        """Mean breadth of the ring's inside: area / half the length (the vector area, i.e. the
        projection on the ring's own plane) -- the gap between the sides of a long thin loop."""
        p = self.points - self.points.mean(axis=0)
        area = 0.5 * np.linalg.norm(np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0))
        return 2.0 * area / max(self.length, 1e-300)

    @property
    def round(self) -> bool:
        """Isoperimetric ratio 4π·area / length² of at least ``ROUND_RING``."""
        return 2.0 * np.pi * self.breadth / max(self.length, 1e-300) >= ROUND_RING

    @property
    def rise(self) -> float:
        """How far the inside reaches from the ring: the distance's rise above it (``top − level``)
        on a round ring, half the mean breadth on an elongated one, whose rise may come from one
        bulge."""
        rise = self.top - self.level
        return rise if self.round else min(rise, 0.5 * self.breadth)


def thin_rise(floor: float | np.ndarray, width: float) -> float | np.ndarray:
    """:attr:`Ring.rise` below which a ring is a thin loop, printed as one pass down its middle.

    Each side of a loop owns half a width outside it and the rise ``r`` inside (half the breadth
    of a strip), a bead of ``w/2 + r``; no bead is narrower than ``floor`` (the layer thickness, in
    widths), so below ``r = (floor − ½)·w`` the sides' beads overlap, while one centre pass spans
    ``2r + w`` ≤ ``2·floor·w`` (0.3 w at the default thickness 0.8 w: a strip 0.6 w broad)."""
    return np.maximum(floor - 0.5, 0.0) * width


def lone_thin_loop(ring: Ring, width: float) -> bool:
    """Whether ``ring``, alone in its region (a spiral of one ring), is printed as one pass down its
    middle: it rises less than :func:`thin_rise` or than ``THIN_LOOP`` widths."""
    return ring.rise < max(thin_rise(ring.floor, width), THIN_LOOP * width)


def _edge_ids(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(F,3) undirected edge id of the edge from corner c to corner c+1."""
    _, inverse = np.unique(edge_keys(faces, np.roll(faces, -1, axis=1), n_vertices).ravel(), return_inverse=True)
    return inverse.reshape(faces.shape)


@dataclass
class Bands:
    """Band components: ``node_face``/``node_band``/``comp`` per (triangle, band) node, and per
    component its band index and largest distance value."""

    node_face: np.ndarray
    node_band: np.ndarray
    comp: np.ndarray
    top: np.ndarray
    band: np.ndarray


def contour_rings(vertices: np.ndarray, faces: np.ndarray, dist: np.ndarray,
                  levels: np.ndarray) -> tuple[list[Ring], Bands]:
    """Closed iso-contours of the per-vertex ``dist`` at ascending ``levels`` and band components.

    Band ``b`` holds the values in ``[levels[b-1], levels[b])``; a value equal to a level counts
    as above it. Each ring knows the band component below and above it.
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    d = np.where(np.isfinite(dist), dist, -np.inf)
    levels = np.asarray(levels, np.float64)
    nlev = len(levels)
    band = np.searchsorted(levels, d, side="right")
    fb = band[f]
    bmin, bmax = fb.min(axis=1), fb.max(axis=1)
    eid = _edge_ids(f, len(v))

    # band components: nodes (face, band) for every band a face touches, joined across edges
    width = bmax - bmin + 1
    offset = np.r_[0, np.cumsum(width)]
    n_nodes = int(offset[-1])
    fe = eid.ravel()
    order = np.argsort(fe, kind="stable")
    fe_sorted = fe[order]
    same = fe_sorted[1:] == fe_sorted[:-1]
    f1, f2 = order[:-1][same] // 3, order[1:][same] // 3
    corner = order[:-1][same] % 3
    ea, eb = band[f[f1, corner]], band[f[f1, (corner + 1) % 3]]
    lo, hi = np.minimum(ea, eb), np.maximum(ea, eb)
    cnt = hi - lo + 1
    rep = run_labels(cnt)
    bb = lo[rep] + run_offsets(cnt)
    n1 = offset[f1[rep]] + bb - bmin[f1[rep]]
    n2 = offset[f2[rep]] + bb - bmin[f2[rep]]
    graph = sp.coo_matrix((np.ones(len(n1)), (n1, n2)), shape=(n_nodes, n_nodes))
    n_comp, comp = connected_components(graph, directed=False)
    node_face = run_labels(width)
    node_band = bmin[node_face] + run_offsets(width)
    upper = np.r_[levels, np.inf][node_band]
    comp_top = np.full(n_comp, -np.inf)
    np.maximum.at(comp_top, comp, np.minimum(d[f[node_face]].max(axis=1), upper))
    comp_band = np.zeros(n_comp, np.int64)
    comp_band[comp] = node_band
    bands = Bands(node_face, node_band, comp, comp_top, comp_band)

    # one oriented segment per (face, crossed level)
    crossings = bmax - bmin
    pf = run_labels(crossings)
    if len(pf) == 0:
        return [], bands
    pk = bmin[pf] + run_offsets(crossings)
    above = d[f[pf]] >= levels[pk][:, None]
    nxt = np.roll(above, -1, axis=1)
    start_c = np.argmax(above & ~nxt, axis=1)
    end_c = np.argmax(~above & nxt, axis=1)
    rows = np.arange(len(pf))

    def crossing(c: np.ndarray) -> np.ndarray:
        p, q = f[pf, c], f[pf, (c + 1) % 3]
        t = (levels[pk] - d[p]) / (d[q] - d[p])
        return v[p] + t[:, None] * (v[q] - v[p])

    start_key = eid[pf, start_c] * nlev + pk
    end_key = eid[pf, end_c] * nlev + pk
    p_start = crossing(start_c)
    skey_order = np.argsort(start_key)
    pos = np.searchsorted(start_key[skey_order], end_key)
    pos = np.minimum(pos, len(pf) - 1)
    found = start_key[skey_order[pos]] == end_key
    nxt_seg = np.where(found, skey_order[pos], -1)
    has_prev = np.zeros(len(pf), bool)
    has_prev[nxt_seg[nxt_seg >= 0]] = True
    below_node = comp[offset[pf] + pk - bmin[pf]]
    above_node = comp[offset[pf] + pk + 1 - bmin[pf]]

    rings: list[Ring] = []
    visited = np.zeros(len(pf), bool)
    for seed in np.r_[rows[~has_prev], rows]:  # open chains (non-manifold spots) first, then cycles
        if visited[seed]:
            continue
        chain = []
        s = seed
        while s >= 0 and not visited[s]:
            visited[s] = True
            chain.append(s)
            s = nxt_seg[s]
        if len(chain) >= 3:
            idx = np.asarray(chain)
            rings.append(Ring(float(levels[pk[seed]]), p_start[idx], int(below_node[seed]), int(above_node[seed])))
    return rings, bands


def contour_gap(vertices: np.ndarray, faces: np.ndarray, dist: np.ndarray, width: float) -> float:
    """Median 3D gap between the contours of ``dist`` at adjacent levels ``width`` apart, per
    ``width`` (from each contour point, sampled every ``DENSE_STEP`` widths, to the nearest of the level
    below; the outermost ``GAP_LEVELS`` levels, which hold most of the passes); 1 when there are
    fewer than two levels.

    The heat-method distance runs along the layer's facets: on a layer dual-contoured from a
    voxel field the facets step with the voxels, and the distance grows faster than the straight
    3D gap that a bead spans (median gap 0.95-0.99 w on the kitten's and bunny's layers). Scaling
    the distance by this ratio spaces the passes one width apart in 3D (thesis §3.5.1: passes a
    path width apart), instead of laying the beads of such a layer over each other."""
    finite = dist[np.isfinite(dist)]
    levels = np.arange(FIRST_LEVEL * width, float(finite.max()) if len(finite) else 0.0, width)[:GAP_LEVELS]
    if len(levels) < 2:
        return 1.0
    rings, _ = contour_rings(vertices, faces, dist, levels)
    by_level: dict[float, list[np.ndarray]] = {}
    for r in rings:
        by_level.setdefault(r.level, []).append(resample(np.vstack([r.points, r.points[:1]]), DENSE_STEP * width))
    ordered = [np.vstack(by_level[k]) for k in sorted(by_level)]
    gaps = [cKDTree(a).query(b, workers=query_threads(len(b)))[0] for a, b in zip(ordered[:-1], ordered[1:])]
    return float(np.median(np.concatenate(gaps))) / width if gaps else 1.0


def prune_islands(rings: list[Ring], comp_top: np.ndarray, width: float) -> list[Ring]:
    """Drop rings around a peak that rises less than ``ISLAND_RISE`` widths above their level: along a
    ridge these are islands of the distance field's noise, and printing one would lay two passes
    less than half a width apart (an overlap larger than the gap it leaves)."""
    bounding: dict[int, int] = {}
    for r in rings:
        bounding[r.below] = bounding.get(r.below, 0) + 1
        bounding[r.above] = bounding.get(r.above, 0) + 1
    return [r for r in rings if not (bounding[r.above] == 1 and comp_top[r.above] - r.level < ISLAND_RISE * width)]


def peak_rings(vertices: np.ndarray, faces: np.ndarray, dist: np.ndarray, levels: np.ndarray,
               rings: list[Ring], bands: Bands, width: float,
               floor_of: Callable[[np.ndarray], float] | None = None) -> tuple[list[Ring], list[np.ndarray]]:
    """One more contour in each peak that the regular rings leave uncovered, and centre lines of
    slivers.

    A band component bounded by at most one ring, all below it, is covered up to half a width
    above that ring (or not at all when no ring bounds it: a region thinner than a bead). If its
    peak rises more than ``PEAK_RISE`` widths beyond, a contour at the mid level ``(covered + top) / 2``
    covers the rest, so peaks and regions thinner than a bead are printed too. A region less than
    half a bead wide (peak below ``SLIVER_TOP`` widths) gets one pass along its centre line instead of a loop.

    Where that contour is a thin loop (a ridge, :func:`thin_rise`), its centre line is printed
    instead, if there is room for it: the ring's beads and the centre bead each at least ``floor``
    widths (``floor_of(points)``, the narrowest bead along the contour, default ``BEAD_MIN``), i.e.
    the peak ``1.5·floor − 0.5`` widths above the ring; else the ring's beads widen
    over the ridge (:func:`~curvslice.toolpaths.beads.fit_beads`). A dot (a ring shorter than
    ``DOT_RING`` widths) inside a ring is left out where that ring's widest beads reach the
    peak: the spiral would turn on it, and its links in and out would lie side by side; alone
    in the outermost ring's band (a ridge of fragments along a strip) the dots' beads lay over the
    ring's own, which widen to the ridge anyway (cheburashka 0.8 layer 4: 18 % overlap). Where that ring
    is a thin loop without the dot, a kept dot would make the loop walked round both sides, two beads over a
    strip one centre pass covers (a vase's wall at 1.5 mm, layer 19: 7 dots along a strip 1.8 w wide on a
    layer 1 w thick, 24.3 % overlap; a cup's wall where its handle joins, a T-shaped thin loop at 1 mm, layer
    11: 7.4 %); a bulge the centre pass does not reach is left to a gap pass (rocker-arm 0.8 layer 101: 98.4
    -> 97.5 % coverage, 2.9 -> 0.2 % overlap, when a dot beyond the pass's reach stopped keeping the walk). The
    widest bead ``BEAD_RANGE[1]`` reaches ``BEAD_RANGE[1] - ½`` widths inwards from an inner ring
    (its outer half-width is shared with the ring outside) and ``BEAD_RANGE[1] - FIRST_LEVEL``
    from the outermost one (the layer's edge lies ``FIRST_LEVEL`` outside it).
    """
    bounding: dict[int, list[Ring]] = {}
    for r in rings:
        bounding.setdefault(r.below, []).append(r)
        bounding.setdefault(r.above, []).append(r)
    low = np.r_[-np.inf, levels]
    reach = (BEAD_RANGE[1] - 0.5) * width  # inwards from an inner ring, by its widest bead
    extra: list[Ring] = []
    lines: list[np.ndarray] = []
    next_comp = len(bands.top)
    for c in range(len(bands.top)):
        b = int(bands.band[c])
        around = bounding.get(c, [])
        if len(around) > 1 or any(r.below == c for r in around) or (b > 0 and not around):
            continue  # not a peak, or the peak of a pruned island
        covered = low[b] + 0.5 * width if around else 0.0
        if around and bands.top[c] - covered <= PEAK_RISE * width:
            continue  # (a region without any ring is always printed)
        level = 0.5 * (covered + bands.top[c])
        sub_faces = faces[bands.node_face[(bands.comp == c)]]
        if not around and bands.top[c] < SLIVER_TOP * width:
            lines.append(centre_line(vertices[np.unique(sub_faces)], width))
            continue
        found, sub = contour_rings(vertices, sub_faces, dist, np.array([level]))
        rise = bands.top[c] - low[b]
        for r in found:
            dot = r.length < DOT_RING * width
            r.top = float(bands.top[c])
            r.floor = floor = floor_of(r.points) if floor_of is not None else BEAD_MIN
            thin = not dot and r.rise < thin_rise(floor, width)
            if thin and around and rise < (1.5 * floor - 0.5) * width:
                continue
            line = fitting_centre_line(r) if thin else None  # (one that leaves the loop: the peak is spiralled)
            if line is not None:
                lines.append(line)
            elif around and dot and rise <= reach + (0.5 - FIRST_LEVEL) * width * (b == 1):  # the outermost reaches farther
                continue
            else:
                extra.append(Ring(r.level, r.points, c, next_comp + r.above, r.top, floor))
        next_comp += len(sub.top)
    return extra, lines


def loop_centre_line(points: np.ndarray) -> np.ndarray:
    """Centre line of a thin closed loop: its two sides between the loop's ends (the farthest
    pair of its points), paired by their share of arclength and averaged; curved loops keep their
    course (a main-axis projection would fold a U onto itself)."""
    a = int(np.argmax(row_norms(points - points[0])))
    b = int(np.argmax(row_norms(points - points[a])))
    b = (b - a) % len(points)
    if b < 1 or b >= len(points) - 1:
        return points[[0, a]] if a else points[:2]
    loop = np.roll(points, -a, axis=0)
    return _paired_mean(loop[:b + 1], np.vstack([loop[b:], loop[:1]])[::-1])


def fitting_centre_line(ring: Ring) -> np.ndarray | None:
    """:func:`loop_centre_line` of ``ring`` where it lies inside the loop -- no point of it farther from the
    loop's points than the loop's rise above its level (``top − level``) plus its mean breadth -- else ``None``.
    Pairing the sides from the loop's farthest points assumes a strip between them; a C-shaped thin loop
    (a thin wall bent round a hole) has its farthest points across the C, and the line pairing its sides
    from there crossed the hole (an unseen cup at 0.8 mm, layer 15: a bead 6.2 mm outside the solid)."""
    line = loop_centre_line(ring.points)
    reach = max(ring.top - ring.level, 0.0) + ring.breadth
    return line if not len(line) or cKDTree(ring.points).query(line)[0].max() <= reach else None


def centre_line(points: np.ndarray, width: float) -> np.ndarray:
    """Centre line of a thin region: its points averaged in bins of ``CENTRE_BIN`` widths along the main axis."""
    centre = points.mean(axis=0)
    axis = np.linalg.svd(points - centre, full_matrices=False)[2][0]
    t = (points - centre) @ axis
    bins = np.floor((t - t.min()) / (CENTRE_BIN * width)).astype(np.int64)
    counts = np.bincount(bins)
    sums = np.stack([np.bincount(bins, weights=points[:, i]) for i in range(3)], axis=1)
    line = sums[counts > 0] / counts[counts > 0, None]
    ends = points[[np.argmin(t), np.argmax(t)]]
    return np.vstack([ends[0], line, ends[1]]) if len(line) > 1 else ends




def split_pinches(rings: list[Ring], width: float,
                  min_bead: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[list[Ring], list[np.ndarray]]:
    """Rings cut where they pinch along a peninsula, and one centre pass through each pinch.

    A ring's two sides along a peninsula (or across a neck) of the layer lie ``d`` apart with half
    of ``d`` on each side's bead: :func:`thin_rise` applied along the ring instead of to its mean
    breadth. Where ``d/2`` is below ``thin_rise(floor)`` (``floor`` the local layer thickness,
    ``min_bead(points)``, in widths) the two beads overlap whatever their fit, as the sides of a thin
    loop do (rocker-arm 0.8 layers 82 and 125: inner rings whose sides run 0.6-0.9 w apart along
    arms under two beads wide, beads of 1.0 w: 5.1 → 2.6 % and 5.8 → 2.1 %), and one pass down the
    middle covers the strip with one bead ``d + 1`` widths wide -- while that is at most the widest
    bead plus the hairline either side (``d ≤ BEAD_RANGE[1] + 2·(OPEN_GAP − ½) − 1`` widths). The
    ring is cut at both ends of the pinch: the pinched sides become their centre line, the loop on the
    wide side stays a ring (closed across the pinch), and the loop on the narrow side -- the tip of a
    peninsula, too small to spiral (shorter than ``DOT_RING`` widths or itself thin) -- is left to the
    centre line's end, which the bead fit lengthens to it, or, from ``2·DOT_RING`` widths long, printed
    by its own centre line. A neck (both loops wide) is left whole: its far loop would be a region of
    its own, two more pieces and four caps at the neck's ends (kitten 0.8 at 1.5 w, layer 81: 3.5 →
    5.2 %). Sides count as across when they lie more than ``PINCH_ALONG`` widths apart
    along the ring (nearer, they are a corner's two legs), and a pinch only when they run that close
    over ``PINCH_LENGTH`` widths. Only rings with a ring outside them are cut: the outermost ring's beads
    lay their excess over the layer's edge (:func:`~curvslice.toolpaths.beads.fit_beads`), and cutting
    it only added the centre line's caps (rocker-arm 0.8 layers 50 and 101, 17 and 15 w²: 1.9 → 5.2 %
    and 2.6 → 6.3 %).
    """
    out: list[Ring] = []
    lines: list[np.ndarray] = []
    todo = list(rings)
    while todo:
        ring = todo.pop(0)  # (in order: the spirals pick among equal rings by it)
        cut = _pinch(ring, width, min_bead)
        if cut is None:
            out.append(ring)
            continue
        loops, line = cut
        kept = [p for p in loops if _spirals(p, width, min_bead)]
        thin = [Ring(0.0, p, 0, 0, 0.0) for p in loops if not any(p is k for k in kept)]
        centres = [fitting_centre_line(t) for t in thin if t.length >= 2.0 * DOT_RING * width]
        if len(kept) != 1 or any(c is None for c in centres):
            # a thin loop but for its tips (the thin-loop rules print it), a neck, or a thin loop whose
            # centre line would leave it (fitting_centre_line): left whole
            out.append(ring)
            continue
        lines += centres  # a thin loop: its own centre line
        for t in thin:
            p = t.points
            if t.length < 2.0 * DOT_RING * width:  # a tip: the centre line's end nearest to it reaches its far point
                at_start = row_norms(p - line[0]).min() < row_norms(p - line[-1]).min()
                tip = p[np.argmax(row_norms(p - (line[0] if at_start else line[-1])))]
                line = np.vstack([tip, line]) if at_start else np.vstack([line, tip])
        lines.append(line)
        new = [Ring(ring.level, kept[0], ring.below, ring.above, ring.top, ring.floor)]
        todo.extend(new)
    return out, lines


def _spirals(points: np.ndarray, width: float, min_bead: Callable[[np.ndarray], np.ndarray] | None) -> bool:
    """Whether a loop cut off at a pinch is printed as a ring: long enough not to be a dot and not
    thin (half its mean breadth at least :func:`thin_rise`)."""
    loop = Ring(0.0, points, 0, 0)
    floor = max(float(np.median(min_bead(points))) / width, BEAD_MIN) if min_bead is not None else BEAD_MIN
    return loop.length >= DOT_RING * width and 0.5 * loop.breadth >= thin_rise(floor, width)


def _pinch(ring: Ring, width: float,
           min_bead: Callable[[np.ndarray], np.ndarray] | None) -> tuple[list[np.ndarray], np.ndarray] | None:
    """The longest pinch of ``ring`` (:func:`split_pinches`): the two loops either side of it (points)
    and the centre line of its sides, or ``None``."""
    if ring.length < DOT_RING * width or ring.level <= FIRST_LEVEL * width:
        return None
    q = resample(np.vstack([ring.points, ring.points[:1]]), DENSE_STEP * width)[:-1]
    n = len(q)
    s = np.r_[0.0, np.cumsum(row_norms(np.diff(q, axis=0)))]
    total = s[-1] + np.linalg.norm(q[0] - q[-1])
    floor = np.maximum(min_bead(q) / width, BEAD_MIN) if min_bead is not None else np.full(n, BEAD_MIN)
    # the widest centre bead d + 1 w may leave a hairline either side
    reach = np.minimum(2.0 * thin_rise(floor, width), (BEAD_RANGE[1] + 2.0 * (OPEN_GAP - 0.5) - 1.0) * width)
    if reach.max() <= 0:
        return None
    pairs = cKDTree(q).query_pairs(float(reach.max()), output_type="ndarray")
    if not len(pairs):
        return None
    i, j = np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]]
    along = np.abs(s[i] - s[j])
    along = np.minimum(along, total - along)
    d = row_norms(q[i] - q[j])
    ok = (along > PINCH_ALONG * width) & (d < reach[i])
    if not ok.any():
        return None
    i, j, d = i[ok], j[ok], d[ok]
    order = np.lexsort((d, i))
    i, j = i[order], j[order]
    first = np.r_[True, i[1:] != i[:-1]]
    partner = np.full(n, -1)
    partner[i[first]] = j[first]
    pinched = partner >= 0
    if pinched.all():
        return None  # a thin loop all round: the thin-loop rules print it
    # the longest run of pinched points (cyclic), rolled to start at index 0
    start = int(np.argmax(~pinched))  # an unpinched point
    roll = np.roll(np.arange(n), -start)
    p = pinched[roll]
    edges = np.diff(np.r_[0, p.astype(np.int8), 0])
    run_start, run_stop = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
    k = int(np.argmax(run_stop - run_start))
    a = roll[run_start[k]:run_stop[k]]  # side A, in ring order
    if (s[a[-1]] - s[a[0]]) % total < PINCH_LENGTH * width:
        return None
    rel = (partner[a] - a[0]) % n  # the partners' positions after A's start
    b_lo, b_hi = int(rel.min()), int(rel.max())
    if b_lo < len(a) or b_hi - b_lo >= n - len(a):
        return None  # partners overlap side A: no clean cut
    idx = (a[0] + np.arange(n)) % n  # ring order from A's start
    side_a, side_b = q[idx[:len(a)]], q[idx[b_lo:b_hi + 1]][::-1]
    loops = [q[idx[len(a) - 1:b_lo + 1]], q[idx[b_hi:]]]
    return loops, _paired_mean(side_a, side_b)


def _paired_mean(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean of two polylines paired by their share of arclength (a centre line between two sides)."""
    shares = []
    for side in (a, b):
        cum = np.r_[0.0, np.cumsum(row_norms(np.diff(side, axis=0)))]
        shares.append(cum / max(cum[-1], 1e-300))
    t = np.unique(np.r_[shares[0], shares[1]])
    halves = [np.column_stack([np.interp(t, sh, side[:, c]) for c in range(3)]) for sh, side in zip(shares, (a, b))]
    return 0.5 * (halves[0] + halves[1])
