"""Continuous tool-paths on a curved working surface: connected Fermat spirals (thesis §3.5.1).

Per layer (thesis §3.3.2 "surface covering", §3.5.1, Fig. 3.9):

1. the geodesic distance ``d`` from the layer boundary (:mod:`curvslice.geodesic`), scaled so
   that its contours lie a width apart in 3D (:func:`contour_gap`);
2. iso-contours ("rings") of ``d`` at ``(k + 0.45)·w`` for path width ``w``, extracted on the mesh
   as closed polylines with the higher side on their left; every band between consecutive levels
   is split into connected *band components*, which gives the exact contour tree: a ring bounds
   one component below and one above;
3. connected Fermat spirals (Zhao et al., SIGGRAPH 2016, the thesis's ref. [2]): a chain of
   nested rings is cut (2-3 widths) near a common cut line and rerouted into one in-and-out spiral (inwards
   on rings 0, 2, 4, ..., outwards on 1, 3, 5, ..., both ends next to each other on the outer
   ring); where the contour tree branches, each child spiral is spliced into the ring that
   hosts it through a gap, so a connected region is one continuous piece unless a splice has no
   room (then the child becomes its own piece, counted as a jump);
4. every pass centred in the strip of surface nearest to it, with a bead as wide as that strip
   (:func:`fit_beads`: the passes tile the layer despite uneven spacing), gap passes where the
   widest beads still leave surface open, redundant slivers dropped (:func:`needed_pieces`),
   beads widened over what the fit leaves past tips and corners (:func:`fill_slivers`),
   self-crossings removed;
5. re-sampling at ``step`` (1 mm in the thesis, §3.5.2), keeping sharp corners, bends and the
   bead width profile;
6. extrusion per segment from length × bead width × local layer thickness (volume
   conservation, :func:`curvslice.flow.filament_length`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from time import perf_counter

import numpy as np
import scipy.sparse as sp
import trimesh
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from curvslice import orientation as ori
from curvslice.errors import CurvsliceError
from curvslice.exporters.gcode6 import write_gcode6
from curvslice.flow import filament_length
from curvslice.geodesic import boundary_distance, edge_keys

#: Rings shorter than this many path widths are printed as one short bead along their diameter.
_DOT_RING = 4.0
#: A lone ring whose inside is narrower than this many widths (:attr:`Ring.breadth`) is printed as
#: one pass along its centre line: its region, ``2·_FIRST`` widths wider, takes one bead of at most
#: ``_BEAD_RANGE[1]`` widths, while its two sides would lie closer than a bead.
_THIN_RING = 0.6
#: A mesh vertex more than ``_GAP - 0.5`` path widths beyond the edge of every bead is open (a
#: gap): with beads of one width, this many widths from every path; hairlines do not count.
_GAP = 0.65
#: Level of the outermost contour in path widths: a little under half a width, so the bead still
#: reaches a jagged layer boundary (the contour smooths its notches) and the distance field's error.
_FIRST = 0.45
#: Final guard on the orientation's angle to the layer normal, after smoothing (radians).
_HARD_TILT = float(np.radians(85.0))
#: Holes of a layer narrower than this many path widths (perimeter < π·_BRIDGE·w) are bridged.
_BRIDGE = 3.0
#: Sharp corners (turn above this angle, radians) are kept as samples when re-sampling.
_CORNER = np.radians(30.0)
#: A connected region whose largest boundary distance is below this many path widths (narrower
#: than 2·_THIN widths) is printed as one pass along its ridge with the bead as wide as the region
#: (a loop there would lay its two sides less than a width apart, a centre pass of one width
#: would leave both edges open).
_THIN = 0.8
#: Narrowest bead of such a pass, in path widths (a thinner region is over-filled, not skipped).
_BEAD_MIN = 0.5
#: A thin region whose ridge is shorter than this many widths is a blob, left to the contours.
_WALL = 2.0
#: Rounds of ridge passes through the branches of a thin region that earlier ridges leave open.
_BRANCHES = 3
#: Bead widths the extruder lays by flow alone, in path widths (narrowest, widest): see :func:`fit_beads`.
_BEAD_RANGE = (_BEAD_MIN, 2.0 * _THIN)
#: :func:`fit_beads`: spacing of the fitted pass points and of the boundary samples (widths), surface
#: area per lattice sample (widths²), half-window of the running max / min / mean in pass points
#: (the normal uses twice as many).
_FIT_STEP = 0.1
_FIT_SAMPLE = 0.02
_FIT_HALF = 3
#: Pieces shorter than this many widths are dropped when the other beads already cover them.
_REDUNDANT = 4.0
#: Share of a layer that a short gap pass must cover on its own to be worth its jump.
_MINOR = 0.005
#: Re-sampling of the fitted passes: a bead width change counts this many times its size as path
#: length, so a cap or a narrowing is not averaged away over a 1 mm step (:func:`resample`).
_WIDTH_WEIGHT = 5.0
#: Added to each side of a fitted strip (widths): the lattice samples still fall short of its edge.
_FIT_MARGIN = 0.01
#: Re-sampling of the fitted passes: a radian of turn counts as this many widths of path length,
#: so a bend keeps its samples and the 1 mm chords do not cut the corners of wavy passes.
_TURN_WEIGHT = 0.5
#: Cut of a Fermat spiral (thesis §3.5.1; Zhao et al. 2016): each ring of a chain of three or more
#: opens over ``length / _CUT_SHARE``, between ``_CUT`` widths; the links in and out of the
#: spiral cross the rings there, ``(g/2)·2w/√(4w² + g²)`` apart (0.71 w at g = 2 w, 0.83 w at 3 w).
_CUT = (2.0, 3.0)
_CUT_SHARE = 6.0
#: :func:`contour_gap` within this of 1 is the measure's own error (a flat square 0.995, a flat
#: disc 1.007): the distance is left as it is.
_GAP_NOISE = 0.01
_GAP_LEVELS = 5


@dataclass
class Ring:
    """A closed iso-contour: points (k,3) with the higher distance on the left, its band comps."""

    level: float
    points: np.ndarray
    below: int
    above: int

    @property
    def length(self) -> float:
        return float(self.cumlen[-1])

    @property
    def cumlen(self) -> np.ndarray:
        closed = np.vstack([self.points, self.points[:1]])
        return np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))]

    @property
    def breadth(self) -> float:
        """Mean breadth of the ring's inside: area / half the length (the vector area, i.e. the
        projection on the ring's own plane) -- the gap between the sides of a long thin loop."""
        p = self.points - self.points.mean(axis=0)
        area = 0.5 * np.linalg.norm(np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0))
        return 2.0 * area / max(self.length, 1e-300)


@dataclass
class LayerPaths:
    """Tool-path pieces of one layer (polylines, print order), each vertex's bead width (mm),
    and how they were made."""

    pieces: list[np.ndarray]
    widths: list[np.ndarray] = field(default_factory=list)
    thin_passes: int = 0  #: ridge passes of thin walls (bead as wide as the wall)
    rings: int = 0
    regions: int = 0
    splices: int = 0
    failed_splices: int = 0
    closed_components: int = 0
    gap_passes: int = 0  #: passes through what the others leave open, kept after needed_pieces
    bridged_holes: int = 0
    travel: float = 0.0
    max_distance: float = 0.0

    @property
    def jumps(self) -> int:
        return max(len(self.pieces) - 1, 0)


# ----------------------------------------------------------------------------- iso-contours


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
    rep = np.repeat(np.arange(len(lo)), cnt)
    bb = lo[rep] + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
    n1 = offset[f1[rep]] + bb - bmin[f1[rep]]
    n2 = offset[f2[rep]] + bb - bmin[f2[rep]]
    graph = sp.coo_matrix((np.ones(len(n1)), (n1, n2)), shape=(n_nodes, n_nodes))
    n_comp, comp = connected_components(graph, directed=False)
    node_face = np.repeat(np.arange(len(f)), width)
    node_band = bmin[node_face] + (np.arange(n_nodes) - offset[node_face])
    upper = np.r_[levels, np.inf][node_band]
    comp_top = np.full(n_comp, -np.inf)
    np.maximum.at(comp_top, comp, np.minimum(d[f[node_face]].max(axis=1), upper))
    comp_band = np.zeros(n_comp, np.int64)
    comp_band[comp] = node_band
    bands = Bands(node_face, node_band, comp, comp_top, comp_band)

    # one oriented segment per (face, crossed level)
    crossings = bmax - bmin
    pf = np.repeat(np.arange(len(f)), crossings)
    if len(pf) == 0:
        return [], bands
    pk = bmin[pf] + (np.arange(len(pf)) - np.repeat(np.cumsum(crossings) - crossings, crossings))
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
    ``width`` (from each contour point, sampled every 0.1 widths, to the nearest of the level
    below; the outermost ``_GAP_LEVELS`` levels, which hold most of the passes); 1 when there are
    fewer than two levels.

    The heat-method distance runs along the layer's facets: on a layer dual-contoured from a
    voxel field the facets step with the voxels, and the distance grows faster than the straight
    3D gap that a bead spans (median gap 0.95-0.99 w on the kitten's and bunny's layers). Scaling
    the distance by this ratio spaces the passes one width apart in 3D (thesis §3.5.1: passes a
    path width apart), instead of laying the beads of such a layer over each other."""
    finite = dist[np.isfinite(dist)]
    levels = np.arange(_FIRST * width, float(finite.max()) if len(finite) else 0.0, width)[:_GAP_LEVELS]
    if len(levels) < 2:
        return 1.0
    rings, _ = contour_rings(vertices, faces, dist, levels)
    by_level: dict[float, list[np.ndarray]] = {}
    for r in rings:
        by_level.setdefault(r.level, []).append(resample(np.vstack([r.points, r.points[:1]]), 0.1 * width))
    ordered = [np.vstack(by_level[k]) for k in sorted(by_level)]
    gaps = [cKDTree(a).query(b, workers=-1)[0] for a, b in zip(ordered[:-1], ordered[1:])]
    return float(np.median(np.concatenate(gaps))) / width if gaps else 1.0


def prune_islands(rings: list[Ring], comp_top: np.ndarray, width: float) -> list[Ring]:
    """Drop rings around a peak that rises less than a quarter width above their level: along a
    ridge these are islands of the distance field's noise, and printing one would lay two passes
    less than half a width apart (an overlap larger than the gap it leaves)."""
    bounding: dict[int, int] = {}
    for r in rings:
        bounding[r.below] = bounding.get(r.below, 0) + 1
        bounding[r.above] = bounding.get(r.above, 0) + 1
    return [r for r in rings if not (bounding[r.above] == 1 and comp_top[r.above] - r.level < 0.25 * width)]


def peak_rings(vertices: np.ndarray, faces: np.ndarray, dist: np.ndarray, levels: np.ndarray,
               rings: list[Ring], bands: Bands, width: float) -> tuple[list[Ring], list[np.ndarray]]:
    """One more contour in each peak that the regular rings leave uncovered, and centre lines of
    slivers.

    A band component bounded by at most one ring, all below it, is covered up to half a width
    above that ring (or not at all when no ring bounds it: a region thinner than a bead). If its
    peak rises more than ``0.15·width`` beyond, a contour at the mid level ``(covered + top) / 2``
    covers the rest, so peaks and regions thinner than a bead are printed too. A region less than
    half a bead wide (peak below ``width/4``) gets one pass along its centre line instead of a loop.
    """
    bounding: dict[int, list[Ring]] = {}
    for r in rings:
        bounding.setdefault(r.below, []).append(r)
        bounding.setdefault(r.above, []).append(r)
    low = np.r_[-np.inf, levels]
    extra: list[Ring] = []
    lines: list[np.ndarray] = []
    next_comp = len(bands.top)
    for c in range(len(bands.top)):
        b = int(bands.band[c])
        around = bounding.get(c, [])
        if len(around) > 1 or any(r.below == c for r in around) or (b > 0 and not around):
            continue  # not a peak, or the peak of a pruned island
        covered = low[b] + 0.5 * width if around else 0.0
        if around and bands.top[c] - covered <= 0.15 * width:
            continue  # (a region without any ring is always printed)
        level = 0.5 * (covered + bands.top[c])
        sub_faces = faces[bands.node_face[(bands.comp == c)]]
        if not around and bands.top[c] < 0.25 * width:
            lines.append(_centre_line(vertices[np.unique(sub_faces)], width))
            continue
        found, sub = contour_rings(vertices, sub_faces, dist, np.array([level]))
        for r in found:
            extra.append(Ring(r.level, r.points, c, next_comp + r.above))
        next_comp += len(sub.top)
    return extra, lines


def _centre_line(points: np.ndarray, width: float) -> np.ndarray:
    """Centre line of a thin region: its points averaged in bins of ``width/2`` along the main axis."""
    centre = points.mean(axis=0)
    axis = np.linalg.svd(points - centre, full_matrices=False)[2][0]
    t = (points - centre) @ axis
    bins = np.floor((t - t.min()) / (0.5 * width)).astype(np.int64)
    counts = np.bincount(bins)
    sums = np.stack([np.bincount(bins, weights=points[:, i]) for i in range(3)], axis=1)
    line = sums[counts > 0] / counts[counts > 0, None]
    ends = points[[np.argmin(t), np.argmax(t)]]
    return np.vstack([ends[0], line, ends[1]]) if len(line) > 1 else ends


# ----------------------------------------------------------------------------- ring geometry


def _arc(ring: Ring, s_from: float, s_to: float, direction: int) -> np.ndarray:
    """Points of ``ring`` from arclength ``s_from`` to ``s_to`` walking in ``direction`` (±1)."""
    cum = ring.cumlen
    total = cum[-1]
    pts = np.vstack([ring.points, ring.points[:1]])
    if total <= 0:
        return ring.points[:1].copy()
    s_from %= total
    s_to %= total
    span = (s_to - s_from) % total if direction > 0 else (s_from - s_to) % total
    inner = cum[1:-1]
    rel = ((inner - s_from) % total) if direction > 0 else ((s_from - inner) % total)
    pick = np.nonzero((rel > 1e-9) & (rel < span - 1e-9))[0]
    pick = pick[np.argsort(rel[pick])]
    ends = [_point_at(pts, cum, s_from), _point_at(pts, cum, s_to)]
    return np.vstack([ends[0], pts[1:-1][pick], ends[1]])


def _point_at(closed_pts: np.ndarray, cum: np.ndarray, s: float) -> np.ndarray:
    i = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(cum) - 2))
    seg = cum[i + 1] - cum[i]
    t = 0.0 if seg <= 0 else (s - cum[i]) / seg
    return closed_pts[i] + t * (closed_pts[i + 1] - closed_pts[i])


def _closest_s(ring: Ring, point: np.ndarray) -> tuple[float, float]:
    """Arclength of the point of ``ring`` closest to ``point`` and that distance."""
    a = ring.points
    b = np.roll(a, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", point - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0, 1)
    proj = a + t[:, None] * ab
    dist = np.linalg.norm(proj - point, axis=1)
    i = int(np.argmin(dist))
    cum = ring.cumlen
    return float(cum[i] + t[i] * (cum[i + 1] - cum[i])), float(dist[i])


def _tangent(ring: Ring, s: float, span: float) -> np.ndarray:
    cum = ring.cumlen
    pts = np.vstack([ring.points, ring.points[:1]])
    total = cum[-1]
    return _point_at(pts, cum, (s + span) % total) - _point_at(pts, cum, (s - span) % total)


def _reversed(ring: Ring) -> Ring:
    return Ring(ring.level, ring.points[::-1].copy(), ring.below, ring.above)


# ----------------------------------------------------------------------------- Fermat spirals


@dataclass
class _Tree:
    rings: list[Ring]
    child_rings: dict[int, list[int]]  # band component -> rings entered from it
    child_comp: dict[int, int]  # ring -> band component on its far side (if not visited before)


def _contour_tree(rings: list[Ring], root: int) -> tuple[_Tree, list[int]]:
    """BFS over the ring/component graph from ``root``; returns the tree and the rings reached."""
    by_comp: dict[int, list[int]] = {}
    for i, r in enumerate(rings):
        by_comp.setdefault(r.below, []).append(i)
        by_comp.setdefault(r.above, []).append(i)
    seen_comp, seen_ring = {root}, set()
    child_rings: dict[int, list[int]] = {}
    child_comp: dict[int, int] = {}
    queue, order = [root], []
    while queue:
        c = queue.pop(0)
        for i in by_comp.get(c, []):
            if i in seen_ring:
                continue
            seen_ring.add(i)
            order.append(i)
            child_rings.setdefault(c, []).append(i)
            other = rings[i].above if rings[i].below == c else rings[i].below
            if other not in seen_comp:
                seen_comp.add(other)
                child_comp[i] = other
                queue.append(other)
    return _Tree(rings, child_rings, child_comp), order


class _Builder:
    """Builds one connected-Fermat-spiral piece per subtree, splicing children where they fit."""

    def __init__(self, tree: _Tree, width: float):
        self.tree = tree
        self.w = width
        self.gap = _CUT[0] * width
        self.extra_pieces: list[np.ndarray] = []
        self.splices = 0
        self.failed = 0

    def chain_from(self, ring_id: int) -> list[int]:
        chain = [ring_id]
        while True:
            comp = self.tree.child_comp.get(chain[-1])
            kids = self.tree.child_rings.get(comp, []) if comp is not None else []
            if len(kids) != 1:
                return chain
            chain.append(kids[0])

    def piece(self, ring_id: int, anchor: np.ndarray, host_tangent: np.ndarray | None,
              siblings: list[int] = ()) -> np.ndarray:
        """Fermat spiral of the chain starting at ``ring_id``, cut next to ``anchor``."""
        chain = self.chain_from(ring_id)
        rings = [self.tree.rings[i] for i in chain]
        cuts: list[float] = []
        point = anchor
        tangent = host_tangent
        for k, ring in enumerate(rings):
            s, _ = _closest_s(ring, point)
            if tangent is not None and ring.length > 0 and np.dot(_tangent(ring, s, self.w), tangent) < 0:
                ring = _reversed(ring)
                s = ring.length - s
            rings[k] = ring
            cuts.append(s)
            point = _point_at(np.vstack([ring.points, ring.points[:1]]), ring.cumlen, s)
            tangent = _tangent(ring, s, self.w)
        dots = [r.length < _DOT_RING * self.w for r in rings]
        # children hosted by the innermost ring (branches), root siblings by ring 0
        hosted: dict[int, list[int]] = {}
        last_comp = self.tree.child_comp.get(chain[-1])
        if last_comp is not None and len(self.tree.child_rings.get(last_comp, [])) > 1:
            hosted[len(chain) - 1] = list(self.tree.child_rings[last_comp])
        if siblings:
            hosted.setdefault(0, []).extend(siblings)
        if len(rings) == 1 and not hosted and rings[0].breadth < _THIN_RING * self.w:
            # a loop whose sides lie closer than a bead: one pass down its middle, the bead as wide
            # as the region (fit_beads), instead of two sides printed over each other
            return _centre_line(rings[0].points, self.w)
        arcs: list[np.ndarray] = []
        n = len(rings)
        order = list(range(0, n, 2)) + list(range(n - 1 if n % 2 == 0 else n - 2, 0, -2))
        for k in order:
            ring, s = rings[k], cuts[k]
            if dots[k]:  # a bead-sized ring: its centre, reached by the links (alone: its diameter)
                centre = ring.points[np.argmin(np.linalg.norm(ring.points - ring.points.mean(axis=0), axis=1))]
                far = ring.points[np.argmax(np.linalg.norm(ring.points - centre, axis=1))]
                arcs.append(centre[None] if n > 1 else np.vstack([centre, far]))
                for child in hosted.get(k, []):
                    self._separate(child)
                continue
            g = float(np.clip(ring.length / _CUT_SHARE, _CUT[0] * self.w, _CUT[1] * self.w)) if n >= 3 else self.gap
            if k % 2 == 0:
                start, end, direction = s - g / 2, s + g / 2, -1
            else:
                start, end, direction = s + g / 2, s - g / 2, +1
            arcs.append(self._ring_walk(ring, start, end, direction, hosted.get(k, []), s))
        return np.vstack(arcs)

    def _separate(self, ring_id: int) -> None:
        self.failed += 1
        first = self.tree.rings[ring_id].points[0]
        self.extra_pieces.append(self.piece(ring_id, first, None))

    def _ring_walk(self, ring: Ring, start: float, end: float, direction: int,
                   children: list[int], cut: float) -> np.ndarray:
        """Walk ``ring`` from ``start`` to ``end`` splicing in the spirals of ``children``."""
        total = ring.length
        span = (end - start) % total if direction > 0 else (start - end) % total
        g = self.gap
        closed = np.vstack([ring.points, ring.points[:1]])
        cum = ring.cumlen
        placed: list[tuple[float, int]] = []  # (offset along the walk, child)
        for child in children:
            s_child, dist = _closest_s(ring, self._nearest_point(child, ring))
            offset = (s_child - start) % total if direction > 0 else (start - s_child) % total
            taken = [o for o, _ in placed]
            ok_pos = None
            for shift in np.r_[0.0, np.repeat(np.arange(1, 9) * 0.5 * self.w, 2) * np.tile([1, -1], 8)]:
                o = offset + shift
                if g <= o <= span - g and all(abs(o - t) >= 2 * g for t in taken):
                    ok_pos = o
                    break
            if ok_pos is None or dist > 3.0 * self.w:
                self._separate(child)
                continue
            placed.append((ok_pos, child))
        placed.sort()
        parts = []
        cursor = 0.0
        for o, child in placed:
            s_at = start + direction * o
            parts.append(_arc(ring, start + direction * cursor, s_at - direction * g / 2, direction))
            anchor = _point_at(closed, cum, s_at % total)
            tangent = direction * _tangent(ring, s_at % total, self.w)
            sub = self.piece(child, anchor, tangent)
            leave = _point_at(closed, cum, (s_at + direction * g / 2) % total)
            arrive = parts[-1][-1]
            if (np.linalg.norm(sub[-1] - arrive) + np.linalg.norm(sub[0] - leave)
                    < np.linalg.norm(sub[0] - arrive) + np.linalg.norm(sub[-1] - leave)):
                sub = sub[::-1]  # the pairing of gap ends and spiral ends that does not cross
            parts.append(sub)
            self.splices += 1
            cursor = o + g / 2
        parts.append(_arc(ring, start + direction * cursor, end, direction))
        return np.vstack(parts)

    def _nearest_point(self, child: int, host: Ring) -> np.ndarray:
        pts = self.tree.rings[child].points
        a = host.points
        dist, idx = cKDTree(a).query(pts)
        return a[idx[np.argmin(dist)]]


# ----------------------------------------------------------------------------- layers


def clean_surface(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Merge duplicate vertices and drop degenerate or repeated triangles (no other change)."""
    m = trimesh.Trimesh(np.asarray(mesh.vertices, np.float64).reshape(-1, 3), np.asarray(mesh.faces, np.int64).reshape(-1, 3),
                        process=True, validate=False)
    m.update_faces(m.nondegenerate_faces(height=1e-9))
    m.update_faces(m.unique_faces())
    m.remove_unreferenced_vertices()
    return m


def bridge_small_holes(vertices: np.ndarray, faces: np.ndarray, max_perimeter: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Close boundary loops shorter than ``max_perimeter`` by a triangle fan to their centroid.

    Pin-holes of a contoured, trimmed layer (a voxel wide) would each become a source of the
    boundary distance and break the spirals into fragments; a bead bridges them instead.
    Returns the new vertices and faces and the number of holes closed.
    """
    f = np.asarray(faces, np.int64)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    n_v = int(f.max()) + 1 if len(f) else 1
    _, inverse, counts = np.unique(edge_keys(directed[:, 0], directed[:, 1], n_v), return_inverse=True,
                                   return_counts=True)
    border = directed[counts[inverse.ravel()] == 1]
    if len(border) == 0:
        return vertices, f, 0
    n = len(vertices)
    graph = sp.coo_matrix((np.ones(len(border)), (border[:, 0], border[:, 1])), shape=(n, n))
    _, loop = connected_components(graph, directed=False)
    loop_of_edge = loop[border[:, 0]]
    length = np.linalg.norm(vertices[border[:, 0]] - vertices[border[:, 1]], axis=1)
    perimeter = np.bincount(loop_of_edge, weights=length)
    # the longest loop of each connected piece is its outer boundary, never a hole
    mesh_graph = sp.coo_matrix((np.ones(len(directed)), (directed[:, 0], directed[:, 1])), shape=(n, n))
    _, piece = connected_components(mesh_graph, directed=False)
    loops = np.unique(loop_of_edge)
    first_edge = np.zeros(len(perimeter), np.int64)
    first_edge[loop_of_edge[::-1]] = np.arange(len(border))[::-1]
    loop_piece = piece[border[first_edge[loops], 0]]
    outer = np.zeros(len(perimeter), bool)
    order = np.lexsort((-perimeter[loops], loop_piece))
    first_of_piece = np.r_[True, loop_piece[order][1:] != loop_piece[order][:-1]]
    outer[loops[order][first_of_piece]] = True
    small = np.nonzero((perimeter > 0) & (perimeter < max_perimeter) & ~outer)[0]
    if len(small) == 0:
        return vertices, f, 0
    pick = np.isin(loop_of_edge, small)
    new_index = np.full(len(perimeter), -1)
    new_index[small] = n + np.arange(len(small))
    counts_v = np.bincount(loop_of_edge[pick], minlength=len(perimeter))[small]
    centres = np.stack([np.bincount(loop_of_edge[pick], weights=vertices[border[pick, 0], i],
                                    minlength=len(perimeter))[small] for i in range(3)], axis=1) / counts_v[:, None]
    fan = np.c_[border[pick, 1], border[pick, 0], new_index[loop_of_edge[pick]]]
    return np.vstack([vertices, centres]), np.vstack([f, fan]), len(small)


def layer_paths(mesh: trimesh.Trimesh, width: float, start: np.ndarray | None = None,
                fill_gaps: bool = True, min_bead: Callable[[np.ndarray], np.ndarray] | None = None) -> LayerPaths:
    """Connected-Fermat-spiral pieces covering one working surface (thesis §3.5.1), plus
    :func:`gap_passes` through what they leave open when ``fill_gaps``. Holes narrower than
    ``_BRIDGE`` widths are bridged (:func:`bridge_small_holes`); a mesh coarser than half a width
    is subdivided once (1 → 4 triangles) so the distance field and contours resolve the passes.
    Regions narrower than ``2·_THIN`` widths get one ridge pass of their own width
    (:func:`thin_passes`). Every pass is then freed of self-crossings (:func:`uncross`) and its
    bead fitted to the strip of surface it covers (:func:`fit_beads`; ``min_bead(points)`` gives
    the narrowest bead there, the local layer thickness), and widened over the slivers the fit
    leaves past tips and corners (:func:`fill_slivers`)."""
    surface = clean_surface(mesh)
    v, f, bridged = bridge_small_holes(surface.vertices, surface.faces, _BRIDGE * np.pi * width)
    if len(f) and np.linalg.norm(v[f[:, 1]] - v[f[:, 0]], axis=1).mean() > 0.5 * width:
        v, f = trimesh.remesh.subdivide(v, f)  # finer heat step (t = h²) and contours than the voxels
    if len(f) == 0:
        return LayerPaths(pieces=[])
    dist = boundary_distance(v, f)
    gap = contour_gap(v, f, dist, width)
    if abs(gap - 1.0) > _GAP_NOISE:
        dist = dist * gap
    f, thin = thin_passes(v, f, dist, width)
    closed = int(np.isnan(dist).any())
    finite = dist[np.isfinite(dist)]
    top = float(finite.max()) if len(finite) else 0.0
    levels = np.arange(_FIRST * width, top, width)
    rings, bands = contour_rings(v, f, dist, levels)
    rings = prune_islands(rings, bands.top, width)
    extra, lines = peak_rings(v, f, dist, levels, rings, bands, width)
    rings += extra
    out = LayerPaths(pieces=[], rings=len(rings), closed_components=closed, max_distance=top,
                     bridged_holes=bridged, thin_passes=len(thin))
    remaining = set(range(len(rings)))
    builder = _Builder(_Tree(rings, {}, {}), width)
    cursor = np.asarray(start, float) if start is not None else (rings[0].points[0] if rings else None)
    while remaining:
        # root: the band-0 component of the outermost ring nearest to the cursor
        outer = [i for i in remaining if rings[i].level == _FIRST * width] or list(remaining)
        first = min(outer, key=lambda i: _closest_s(rings[i], cursor)[1])
        root = rings[first].below
        tree, order = _contour_tree(rings, root)
        remaining -= set(order)
        builder.tree = tree
        roots = tree.child_rings.get(root, [])
        main = max(roots, key=lambda i: rings[i].length)
        piece = builder.piece(main, cursor, None, siblings=[i for i in roots if i != main])
        out.pieces.append(piece)
        out.regions += 1
        cursor = piece[-1]
    out.pieces.extend(builder.extra_pieces + lines)
    out.regions += len(lines) + len(thin)
    passes = [p for p in out.pieces + thin if len(p) > 1 and np.ptp(p, axis=0).max() > 1e-9]
    samples = surface_samples(surface, width)
    owners = _Owners(samples[0], [resample(p, _FIT_STEP * width) for p in passes])
    pieces, widths = _fit_owned(surface, samples, owners, width, min_bead)
    fill = gap_passes(v, f, pieces, width, widths) if fill_gaps and len(f) else []
    if fill:  # what even the widest beads leave open gets passes of its own, then all are refitted
        owners.add([resample(p, _FIT_STEP * width) for p in fill])
        pieces, widths = _fit_owned(surface, samples, owners, width, min_bead)
    is_gap = np.arange(len(pieces)) >= len(pieces) - len(fill)
    needed = needed_pieces(pieces, widths, width, samples[0], is_gap, take_over=True)
    if len(needed) < len(pieces):  # the others take over the strips of the redundant ones
        kept = owners.kept(needed)
        refit = _fit_owned(surface, samples, kept, width, min_bead)
        label = np.repeat(np.arange(len(pieces)), [len(p) for p in pieces])
        orphans = samples[0][~np.isin(label[owners.j], needed)]
        if _faults(orphans, *refit, width) - _faults(orphans, pieces, widths, width) > _MINOR * len(samples[0]):
            # a refitted bead fell short of what it was to take over (a corner, a pass end)
            needed = needed_pieces(pieces, widths, width, samples[0], is_gap, take_over=False)
            kept = owners.kept(needed)
            refit = _fit_owned(surface, samples, kept, width, min_bead)
        owners, (pieces, widths) = kept, refit
    widths = fill_slivers(samples[0], pieces, widths, width)
    out.gap_passes = int(is_gap[needed].sum())
    out.splices, out.failed_splices = builder.splices, builder.failed
    orders = [uncross(p, width) for p in pieces]
    pieces, widths = [p[o] for p, o in zip(pieces, orders)], [b[o] for b, o in zip(widths, orders)]
    out.pieces, out.widths = _order_pieces(pieces, widths, start)
    out.travel = float(sum(np.linalg.norm(b[0] - a[-1]) for a, b in zip(out.pieces[:-1], out.pieces[1:])))
    return out


def thin_passes(vertices: np.ndarray, faces: np.ndarray, dist: np.ndarray,
                width: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """Passes along the ridge of each connected region narrower than ``2·_THIN`` widths.

    Closes the medial-axis gap of thin walls (thesis §3.7) by varying the bead width through the
    extrusion amount: the ridge of the boundary distance ``d`` is the region's centre line and
    ``2·d`` there (the largest ``d`` within half a width) its local width, the bead it needs (clamped to
    ``[_BEAD_MIN, 2·_THIN]`` widths; :func:`fit_beads` sets the final one). A ridge is the longest of the shortest paths over mesh
    edges weighted by ``length / d²`` (cheap along the ridge); branches it leaves open (vertices
    more than a quarter width beyond half a bead of it) get their own ridges, up to ``_BRANCHES`` rounds. Returns the faces of the other regions and the passes.
    """
    f = np.asarray(faces, np.int64)
    n = len(vertices)
    pairs = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    code = np.unique(edge_keys(pairs[:, 0], pairs[:, 1], n))
    edges = np.c_[code // n, code % n]
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    top = np.full(label.max() + 1, np.inf)
    finite = np.isfinite(dist)
    top[np.unique(label[finite])] = -np.inf
    np.maximum.at(top, label[finite], dist[finite])
    thin_label = np.nonzero(top < _THIN * width)[0]
    passes, widths = [], []
    if len(thin_label) == 0:
        return f, passes
    thin_v = np.nonzero(np.isin(label, thin_label))[0]  # the thin regions' own graph (small)
    e = np.searchsorted(thin_v, edges[np.isin(label[edges[:, 0]], thin_label)])
    mid = np.maximum(0.5 * (dist[thin_v[e[:, 0]]] + dist[thin_v[e[:, 1]]]), 0.05 * width)
    cost = np.linalg.norm(vertices[thin_v[e[:, 0]]] - vertices[thin_v[e[:, 1]]], axis=1) / mid**2
    weighted = sp.coo_matrix((cost, (e[:, 0], e[:, 1])), shape=(len(thin_v),) * 2).tocsr()
    weighted = weighted + weighted.T
    done = []
    for c in thin_label:
        todo = np.nonzero(label[thin_v] == c)[0]
        mine = len(passes)
        for _ in range(_BRANCHES):
            if len(todo) < 3:
                break
            sub = weighted[todo][:, todo]
            n_patch, patch = connected_components(sub, directed=False)
            for k in range(n_patch):
                members = todo[patch == k]
                if len(members) < 3:
                    continue
                ridge = thin_v[members[_longest_path(weighted[members][:, members])]]
                pts = vertices[ridge].copy()
                if len(passes) == mine and np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() < _WALL * width:
                    break  # a blob, not a wall: the contours print it
                if len(pts) > 2:
                    pts[1:-1] = (pts[:-2] + pts[1:-1] + pts[2:]) / 3.0  # the edge path's zigzag smoothed
                near = cKDTree(pts).sparse_distance_matrix(cKDTree(vertices[thin_v[members]]), 0.5 * width,
                                                           output_type="coo_matrix")
                half = dist[ridge].copy()  # the ridge of d near each point: an edge path runs beside it
                np.maximum.at(half, near.row, dist[thin_v[members[near.col]]])
                passes.append(pts)
                widths.append(np.clip(2.0 * half, _BEAD_MIN * width, 2.0 * _THIN * width))
            if len(passes) == mine:
                break
            done.append(c)
            dense = np.vstack([resample(np.c_[p, b], 0.1 * width) for p, b in zip(passes[mine:], widths[mine:])])
            gap, nearest = cKDTree(dense[:, :3]).query(vertices[thin_v[todo]])
            todo = todo[gap > 0.5 * dense[nearest, 3] + 0.25 * width]
    keep = ~np.isin(label[f[:, 0]], done)
    return f[keep], passes


def _longest_path(graph: sp.csr_matrix) -> np.ndarray:
    """Node indices of the longest shortest path found by two Dijkstra sweeps."""
    d0 = dijkstra(graph, indices=0)
    far = int(np.argmax(np.where(np.isfinite(d0), d0, -1)))
    d1, pred = dijkstra(graph, indices=far, return_predecessors=True)
    node = int(np.argmax(np.where(np.isfinite(d1), d1, -1)))
    chain = [node]
    while pred[node] >= 0:
        node = int(pred[node])
        chain.append(node)
    return np.asarray(chain)


def gap_passes(vertices: np.ndarray, faces: np.ndarray, pieces: list[np.ndarray], width: float,
               widths: list[np.ndarray] | None = None, min_vertices: int = 3) -> list[np.ndarray]:
    """Extra passes through what the spirals leave open: narrow strips (thinner than a bead, where
    no contour exists) and the medial-axis gaps between contour families (thesis §3.7).

    Vertices more than ``_GAP - 0.5`` widths beyond the edge of every bead (``widths``: each piece
    vertex's bead, default ``width``) form connected patches; each patch at least
    ``min_vertices`` vertices and half a width long -- down to the tips of a layer that its outermost
    contour cuts short -- gets one pass along its longest shortest path (two Dijkstra sweeps on its
    mesh edges), which runs down the middle of a strip. (:func:`needed_pieces` then drops those
    that add more overlap than coverage.)
    """
    v = np.asarray(vertices, np.float64)
    if not pieces:
        open_v = np.ones(len(v), bool)
    else:
        widths = widths if widths is not None else [np.full(len(p), width) for p in pieces]
        dense = np.vstack([resample(np.c_[p, b], 0.1 * width) for p, b in zip(pieces, widths)])
        gap, nearest = cKDTree(dense[:, :3]).query(v, workers=-1)
        open_v = gap > 0.5 * dense[nearest, 3] + (_GAP - 0.5) * width
    ring = np.roll(faces, -1, axis=1)
    inside = open_v[faces] & open_v[ring]
    code = np.unique(edge_keys(faces[inside], ring[inside], len(v)))
    edges = np.c_[code // len(v), code % len(v)]
    if len(edges) == 0:
        return []
    length = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
    graph = sp.coo_matrix((length, (edges[:, 0], edges[:, 1])), shape=(len(v), len(v))).tocsr()
    graph = graph + graph.T
    n_comp, label = connected_components(graph, directed=False)
    sizes = np.bincount(label[open_v], minlength=n_comp)
    passes = []
    for c in np.nonzero(sizes >= min_vertices)[0]:
        members = np.nonzero((label == c) & open_v)[0]
        chain = members[_longest_path(graph[members][:, members])]
        if np.linalg.norm(np.diff(v[chain], axis=0), axis=1).sum() >= 0.5 * width:
            passes.append(v[chain])
    return passes


def uncross(piece: np.ndarray, width: float, rounds: int = 100) -> np.ndarray:
    """Order of a piece's points without the places where it crosses itself (2-opt: reverse the
    stretch between two crossing segments, so their ends are joined the other way round; the
    path stays one piece over the same points and gets shorter, so this ends).

    Contour arcs never cross each other; the links between them -- from ring to ring, into a
    spliced child spiral -- can, where the cuts of neighbouring rings drift apart (Zhao et al.
    2016 align them on one cut line) or once :func:`fit_beads` has moved the passes sideways.
    Two segments cross when they come within ``0.01·width`` of each other at inner points, more
    than 15° apart. Crossings whose stretches do not overlap are undone in the same round.
    """
    order = np.arange(len(piece))
    for _ in range(rounds):
        p = np.asarray(piece, np.float64)[order]
        if len(p) < 4:
            return order
        a, b = p[:-1], p[1:]
        length = np.linalg.norm(b - a, axis=1)
        mid = 0.5 * (a + b)
        tree = cKDTree(mid)
        typical = float(np.percentile(length, 99)) + 1e-9
        pairs = [tree.query_pairs(typical, output_type="ndarray")]
        for k in np.nonzero(length > typical)[0]:  # the few long links, against everything near
            near = np.asarray(tree.query_ball_point(mid[k], 0.5 * (length[k] + length.max()) + 1e-9), np.int64)
            pairs.append(np.c_[np.full(len(near), k), near])
        pairs = np.vstack(pairs)
        i, j = pairs.min(axis=1), pairs.max(axis=1)
        keep = j > i + 1
        i, j = i[keep], j[keep]
        if len(i) == 0:
            return order
        u, v, w0 = b[i] - a[i], b[j] - a[j], a[i] - a[j]
        uu, uv, vv = np.einsum("ij,ij->i", u, u), np.einsum("ij,ij->i", u, v), np.einsum("ij,ij->i", v, v)
        uw, vw = np.einsum("ij,ij->i", u, w0), np.einsum("ij,ij->i", v, w0)
        den = uu * vv - uv * uv
        with np.errstate(all="ignore"):
            s = np.clip((uv * vw - vv * uw) / den, 0, 1)
            t = np.clip((uu * vw - uv * uw) / den, 0, 1)
        gap = np.linalg.norm(w0 + s[:, None] * u - t[:, None] * v, axis=1)
        sin = np.sqrt(np.maximum(den, 0)) / np.maximum(np.sqrt(uu * vv), 1e-300)
        hit = (gap < 0.01 * width) & (s > 0.0) & (s < 1.0) & (t > 0.0) & (t < 1.0) & (sin > np.sin(np.radians(15)))
        if not hit.any():
            return order
        last = -2
        for a_k, b_k in sorted(zip(i[hit].tolist(), j[hit].tolist())):  # crossings whose stretches
            if a_k > last:  # do not overlap are undone in the same round
                order[a_k + 1:b_k + 1] = order[a_k + 1:b_k + 1][::-1].copy()
                last = b_k + 1
    return order


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
    """Indices of the pieces to keep: a piece shorter than ``_REDUNDANT`` widths is dropped when
    more of the surface ``samples`` (points, evenly spread) under its bead lie under other kept
    beads than under its own alone -- it would add more overlap than coverage. Typical of the
    slivers and dots of tiny layers, where every bead is at least as wide as the layer is thick;
    the kept neighbours are refitted over what it leaves. A short gap pass (``gap``: a mask of
    the pieces) is also dropped when what it alone covers is under ``_MINOR`` of the layer: a
    jump is not worth that. With ``take_over``, samples under its bead alone do not count for it
    where the nearest other kept pass can take them over once refitted: its bead, grown towards
    them by a shift of at most half a width, stays within the widest bead (``_BEAD_RANGE``) --
    the caller checks the refit (:func:`_faults`). Shortest first."""
    keep = list(range(len(pieces)))
    length = [float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) for p in pieces]
    short = [k for k in sorted(keep, key=lambda i: length[i]) if length[k] < _REDUNDANT * width]
    if not short or len(pieces) < 2 or len(samples) == 0:
        return keep
    pts = np.vstack(pieces)
    label = np.repeat(np.arange(len(pieces)), [len(p) for p in pieces])
    half = 0.5 * np.concatenate(widths)
    # the samples under the short beads, and every piece whose bead covers each of them
    stop = np.cumsum([len(p) for p in pieces])
    own = np.concatenate([np.arange(stop[k] - len(pieces[k]), stop[k]) for k in short])
    reach = float(half.max())
    short_tree = cKDTree(pts[own])
    close = np.nonzero(np.isfinite(short_tree.query(samples, distance_upper_bound=reach, workers=-1)[0]))[0]
    under = short_tree.sparse_distance_matrix(cKDTree(samples[close]), reach, output_type="coo_matrix")
    near = close[np.unique(under.col[under.data <= half[own][under.row]])]
    if len(near) == 0:
        return keep
    widest = _BEAD_RANGE[1] * width
    hits = cKDTree(samples[near]).sparse_distance_matrix(cKDTree(pts), max(reach, widest), output_type="coo_matrix")
    # the nearest point of every piece within the widest bead of each sample
    code = hits.row * len(pieces) + label[hits.col]
    first = np.lexsort((hits.data, code))
    first = first[np.r_[True, code[first][1:] != code[first][:-1]]]
    first = first[np.lexsort((hits.data[first], hits.row[first]))]  # by sample, nearest piece first
    row, piece_of, gap_of, half_of = hits.row[first], label[hits.col[first]], hits.data[first], half[hits.col[first]]
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
        n = row_bounds[alone + 1] - row_bounds[alone]
        block = np.repeat(row_bounds[alone], n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        block = block[(piece_of[block] != k) & kept[piece_of[block]]]
        o_row, o_gap, o_half = row[block], gap_of[block], half_of[block]
        nearest = np.r_[True, o_row[1:] != o_row[:-1]] if len(o_row) else np.zeros(0, bool)
        taken = (o_gap + o_half <= widest) & (o_gap <= width + o_half) & take_over
        only = len(alone) - int(np.sum(taken[nearest]))
        if len(mine) - len(alone) >= only or (gap is not None and gap[k] and only < _MINOR * len(samples)):
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

    The passes are re-sampled every ``_FIT_STEP`` widths; every surface sample (a lattice, one per
    ``_FIT_SAMPLE`` w², plus the boundary every ``_FIT_STEP`` widths) belongs to its nearest pass
    point and lies on its left or right (by the layer normal × tangent), at its 3D distance off
    the pass. A point's extent to either side -- the farthest sample it owns, closed (running max
    then min over ``±_FIT_HALF`` points), scaled by (k+1)/k for k samples, averaged over
    ``±_FIT_HALF`` points so the bead changes smoothly, plus ``_FIT_MARGIN`` -- gives the bead
    ``e_l + e_r`` and a shift ``(e_l - e_r)/2`` sideways, so the bead lies over its strip: the beads
    tile the layer instead of overlapping by the spacing error. Beads stay within
    ``_BEAD_RANGE`` widths and never narrower than ``min_bead`` (the local layer thickness: a bead
    is at least as wide as it is high). A pass end also owns what lies ahead of it and is
    lengthened until its round end reaches that far. Where the floor makes a bead wider than its
    strip and one side of the strip is the layer's edge, the excess goes over that edge instead of
    over the neighbour. Returns the fitted pieces and their per-vertex bead widths (mm).
    ``samples`` (points, normals, edge mask) of :func:`surface_samples` may be passed in when
    several fits share one surface.
    """
    fine = [resample(p, _FIT_STEP * width) for p in pieces]
    fine = [p for p in fine if len(p) >= 2]
    if not fine or surface.area <= 0:
        return fine, [np.full(len(p), width) for p in fine]
    samples = samples if samples is not None else surface_samples(surface, width)
    return _fit_owned(surface, samples, _Owners(samples[0], fine), width, min_bead)


def _fit_owned(surface: trimesh.Trimesh, samples: tuple[np.ndarray, np.ndarray, np.ndarray], owners: _Owners, width: float,
               min_bead: Callable[[np.ndarray], np.ndarray] | None) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """:func:`fit_beads` of the passes ``owners`` holds (already sampled every ``_FIT_STEP``
    widths, with the samples' nearest points); unfitted, one width, without any surface."""
    if not owners.fine or surface.area <= 0:
        return owners.fine, [np.full(len(p), width) for p in owners.fine]
    return _fit_strips(samples[0], samples[1], owners.fine, width, min_bead, owners.j, samples[2])


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
            d, j = cKDTree(np.vstack(fine)).query(self.x, workers=-1)
            better = d < self.d
            self.d[better], self.j[better] = d[better], sum(len(p) for p in self.fine) + j[better]
        self.fine = self.fine + list(fine)

    def kept(self, indices: list[int]) -> "_Owners":
        """The owners once only the passes ``indices`` remain (this one unchanged)."""
        counts = np.array([len(p) for p in self.fine], np.int64)
        start = np.cumsum(counts) - counts
        renumber = np.full(int(counts.sum()), -1, np.int64)
        renumber[np.concatenate([np.arange(start[i], start[i] + counts[i]) for i in indices])] = np.arange(counts[indices].sum())
        out = _Owners(self.x, [])
        out.fine, out.d, out.j = [self.fine[i] for i in indices], self.d.copy(), renumber[self.j]
        orphan = np.nonzero(out.j < 0)[0]
        if len(orphan):
            out.d[orphan], out.j[orphan] = cKDTree(np.vstack(out.fine)).query(self.x[orphan], workers=-1)
        return out


def _faults(x: np.ndarray, pieces: list[np.ndarray], widths: list[np.ndarray], width: float) -> int:
    """How many of the points ``x`` are open (farther than ``_GAP - 0.5`` widths beyond every
    bead, as :func:`gap_passes` has it) or under the beads of two pieces or more (``widths``: the
    pieces' vertex bead widths; sampled every ``_FIT_STEP`` widths, as the fits' lengthened ends
    are not)."""
    if not pieces:
        return len(x)
    dense = [resample(np.c_[p, b], _FIT_STEP * width) for p, b in zip(pieces, widths)]
    label = np.repeat(np.arange(len(pieces)), [len(q) for q in dense])
    dense = np.vstack(dense)
    pts, half = dense[:, :3], 0.5 * dense[:, 3]
    tree = cKDTree(pts)
    d, j = tree.query(x, workers=-1)
    near = cKDTree(x).sparse_distance_matrix(tree, float(half.max()), output_type="coo_matrix")
    inside = near.data <= half[near.col]
    beads = np.bincount(np.unique(near.row[inside] * len(pieces) + label[near.col[inside]]) // len(pieces),
                        minlength=len(x))
    return int(np.sum((d > half[j] + (_GAP - 0.5) * width) | (beads > 1)))


def fill_slivers(x: np.ndarray, pieces: list[np.ndarray], widths: list[np.ndarray], width: float) -> list[np.ndarray]:
    """Bead widths (one array per piece) widened over the slivers the fit leaves: surface samples
    ``x`` at most ``_GAP - 0.5`` widths beyond every bead (farther is open, for
    :func:`gap_passes`) -- past a tip or a corner, where the fitted extent is a running mean. The
    nearest pass point's bead grows to reach them, short of the bead of any other pass (another
    piece, or the same piece more than two beads away along it: a spiral's next ring), and within
    the widest bead (``_BEAD_RANGE``)."""
    if not pieces or not len(x):
        return widths
    pts, half = np.vstack(pieces), 0.5 * np.concatenate(widths)
    label = np.repeat(np.arange(len(pieces)), [len(p) for p in pieces])
    key = np.concatenate([np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))] for p in pieces])
    tree = cKDTree(pts)
    d, j = tree.query(x, workers=-1)
    sliver = (d > half[j]) & (d <= half[j] + (_GAP - 0.5) * width)
    if not sliver.any():
        return widths
    owners = np.unique(j[sliver])
    want = np.zeros(len(pts))
    np.maximum.at(want, j[sliver], d[sliver])
    # the edge of the nearest bead of another pass (another piece, or the same one more than two
    # beads along it) bounds the growth
    pairs = cKDTree(pts[owners]).sparse_distance_matrix(tree, float(want.max() + half.max()), output_type="coo_matrix")
    owner, other = owners[pairs.row], pairs.col
    far = (label[other] != label[owner]) | (np.abs(key[other] - key[owner]) > 2.0 * np.maximum(width, 2.0 * half[other]))
    limit = np.full(len(pts), np.inf)
    np.minimum.at(limit, owner[far], pairs.data[far] - half[other[far]])
    grown = half.copy()
    grown[owners] = np.clip(np.minimum(want[owners], limit[owners] - _FIT_MARGIN * width), half[owners],
                            0.5 * _BEAD_RANGE[1] * width)
    return np.split(2.0 * grown, np.cumsum([len(p) for p in pieces])[:-1])


def _group_max(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Largest of ``values`` per ``index`` in ``range(n)``, at least 0 (``np.maximum.at``, sorted)."""
    out = np.zeros(n)
    if len(index):
        order = np.argsort(index, kind="stable")
        idx = index[order]
        starts = np.r_[0, np.nonzero(np.diff(idx))[0] + 1]
        out[idx[starts]] = np.maximum(np.maximum.reduceat(values[order], starts), 0.0)
    return out


def surface_samples(surface: trimesh.Trimesh, width: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points of ``surface`` on a barycentric lattice of each triangle, about one per
    ``_FIT_SAMPLE`` w² (even, unlike random samples: no voids to under-estimate a strip by), and
    on its boundary every ``_FIT_STEP`` widths, with the normals of their triangles and a mask
    of the boundary ones."""
    tri = surface.triangles
    order = np.maximum(np.ceil(np.sqrt(2.0 * surface.area_faces / (_FIT_SAMPLE * width**2))), 1).astype(np.int64)
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
        k = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / (_FIT_STEP * width)), 1).astype(np.int64)
        e = np.repeat(np.arange(len(edges)), k)
        u = (np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)) / k[e]
        points.append(a[e] + u[:, None] * (b[e] - a[e]))
        normals.append(surface.face_normals[surface.edges_face[edges][e]])
    points = np.vstack(points)
    edge = np.zeros(len(points), bool)
    edge[len(points) - (int(k.sum()) if len(edges) else 0):] = True
    return points, np.vstack(normals), edge


def _fit_strips(x: np.ndarray, xn: np.ndarray, fine: list[np.ndarray], width: float,
                min_bead: Callable[[np.ndarray], np.ndarray] | None,
                j: np.ndarray, edge: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """:func:`fit_beads` on passes sampled every ``_FIT_STEP`` widths and surface samples ``x``
    (triangle normals ``xn``; ``j`` the nearest pass point of each, :class:`_Owners`; ``edge``
    the samples on the layer's boundary): the shifted passes and their beads."""
    counts = np.array([len(p) for p in fine])
    pts = np.vstack(fine)
    n = len(pts)
    stop = np.cumsum(counts)
    start = stop - counts
    owner = np.repeat(np.arange(len(fine)), counts)
    lo, hi = start[owner], stop[owner]
    i = np.arange(n)
    tan = pts[np.minimum(i + 1, hi - 1)] - pts[np.maximum(i - 1, lo)]
    tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-300)
    first, last = i == lo, i == hi - 1

    normal = np.stack([np.bincount(j, weights=xn[:, c], minlength=n) for c in range(3)], axis=1)
    normal = np.stack([_window(normal[:, c], lo, hi, 2 * _FIT_HALF, "mean") for c in range(3)], axis=1)
    side = np.cross(normal, tan)
    norm = np.linalg.norm(side, axis=1, keepdims=True)
    side = np.where(norm > 1e-9, side / np.maximum(norm, 1e-300), 0.0)

    off = x - pts[j]
    along = np.einsum("ij,ij->i", off, tan[j])
    # distance off the pass in 3D (the chord across a curved strip, as the bead must reach),
    # on the side the layer's tangent plane puts it
    left = np.einsum("ij,ij->i", off, side[j]) >= 0
    lateral = np.linalg.norm(off - along[:, None] * tan[j], axis=1) * np.where(left, 1.0, -1.0)
    extent = np.stack([_group_max(j[left], lateral[left], n), _group_max(j[~left], -lateral[~left], n)])
    owned = np.stack([np.bincount(j[left], minlength=n), np.bincount(j[~left], minlength=n)]).astype(np.float64)
    reach = _group_max(j, np.where(last[j], along, np.where(first[j], -along, 0.0)), n)  # ahead of an end
    # the farthest of k samples spread evenly over [0, e] lies at e·k/(k+1) on average
    # closing (running max, then min): fills the dips where no sample happened to lie near the
    # strip's edge without spreading a wide stretch into a narrow one; the farthest of k samples
    # spread evenly over [0, e] lies at e·k/(k+1); a running mean smooths the bead
    closed = [_window(_window(e, lo, hi, _FIT_HALF, "max"), lo, hi, _FIT_HALF, "min") for e in extent]
    ends = first | last  # a pass end keeps the extent of all it owns (its cap, not to be eroded)
    extent = np.stack([np.where(ends, np.maximum(m, e), m) for m, e in zip(
        [_window(e * (1 + 1 / np.maximum(_window(c, lo, hi, _FIT_HALF, "sum"), 1)), lo, hi, _FIT_HALF, "mean")
         for e, c in zip(closed, owned)], extent)]) + _FIT_MARGIN * width
    floor = np.full(n, _BEAD_RANGE[0] * width)
    if min_bead is not None:
        floor = np.clip(min_bead(pts), floor, _BEAD_RANGE[1] * width)
    bead = np.clip(extent.sum(axis=0), floor, _BEAD_RANGE[1] * width)
    # a bead wider than its strip (the floor) spills over the layer's edge where it has one
    spill = np.stack([_window(np.bincount(j[s & edge], minlength=n).astype(np.float64), lo, hi, _FIT_HALF, "max") > 0
                      for s in (left, ~left)])
    excess = np.maximum(bead - extent.sum(axis=0), 0.0)
    shift = np.clip(0.5 * (extent[0] - extent[1]) + 0.5 * excess * (spill[0].astype(float) - spill[1]), -0.5 * width, 0.5 * width)
    pts = pts + shift[:, None] * side
    grow = np.maximum(reach - 0.5 * bead, 0.0)
    pts[first] -= grow[first, None] * tan[first]
    pts[last] += grow[last, None] * tan[last]
    return np.split(pts, stop[:-1]), np.split(bead, stop[:-1])


def _order_pieces(pieces: list[np.ndarray], widths: list[np.ndarray],
                  start: np.ndarray | None) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Greedy nearest-end ordering (pieces may be reversed, with their vertex widths) to shorten
    travels (§3.3.2 item 2)."""
    left = list(zip(pieces, widths))
    cursor = np.asarray(start, float) if start is not None else (left[0][0][0] if left else None)
    ordered, ordered_w = [], []
    while left:
        d0 = [np.linalg.norm(p[0] - cursor) for p, _ in left]
        d1 = [np.linalg.norm(p[-1] - cursor) for p, _ in left]
        i = int(np.argmin(np.minimum(d0, d1)))
        p, wv = left.pop(i)
        if d0[i] > d1[i]:
            p, wv = p[::-1], wv[::-1]
        ordered.append(p)
        ordered_w.append(wv)
        cursor = p[-1]
    return ordered, ordered_w


def resample(polyline: np.ndarray, step: float, value_weight: float = 0.0, turn_weight: float = 0.0) -> np.ndarray:
    """Uniform re-sampling at spacing ≤ ``step`` (thesis §3.5.2: 1 mm) keeping sharp corners.

    Columns after the first three (x, y, z) are per-vertex values interpolated along the way.
    With ``value_weight`` > 0 the spacing is uniform in ``√(ds² + (value_weight·dv)²)`` instead of
    the arclength ``ds``, so where a value (a bead width) changes, samples come closer and its
    profile survives the linear interpolation between them. ``turn_weight`` adds that much length
    per radian the path turns (below the kept corners), so bends keep their samples."""
    p = np.asarray(polyline, np.float64)
    seg = np.linalg.norm(np.diff(p[:, :3], axis=0), axis=1)
    p = p[np.r_[True, seg > 1e-9]]
    if len(p) < 2:
        return p[:1].copy()
    d = np.diff(p[:, :3], axis=0)
    u = d / np.linalg.norm(d, axis=1, keepdims=True)
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", u[:-1], u[1:]), -1, 1))
    keep = np.r_[0, np.nonzero(turn > _CORNER)[0] + 1, len(p) - 1]
    bend = np.r_[0.0, np.where(turn > _CORNER, 0.0, turn), 0.0]
    cum = np.r_[0.0, np.cumsum(np.linalg.norm(np.c_[d, value_weight * np.diff(p[:, 3:], axis=0)], axis=1)
                               + turn_weight * 0.5 * (bend[:-1] + bend[1:]))]
    # every run between kept corners in n equal steps (the corners themselves are knots of cum)
    start, span = cum[keep[:-1]], cum[keep[1:]] - cum[keep[:-1]]
    n = np.maximum(np.ceil(span / step - 1e-9), 1).astype(np.int64)
    run = np.repeat(np.arange(len(n)), n)
    s = np.r_[start[run] + span[run] * (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / n[run], cum[-1]]
    return np.column_stack([np.interp(s, cum, p[:, i]) for i in range(p.shape[1])])


def extrusion_amounts(positions: np.ndarray, path_id: np.ndarray, thickness: np.ndarray, width,
                      filament_diameter: float) -> np.ndarray:
    """Filament length per segment (0 at each piece's first sample), thickness and bead width
    (a number or one per sample) averaged on it; a bead is never narrower than it is high."""
    pos = np.asarray(positions, np.float64)
    seg = np.r_[0.0, np.linalg.norm(np.diff(pos, axis=0), axis=1)]
    h = np.r_[thickness[0], 0.5 * (thickness[1:] + thickness[:-1])]
    b = np.broadcast_to(np.asarray(width, np.float64), h.shape)
    b = np.r_[b[0], 0.5 * (b[1:] + b[:-1])]
    e = filament_length(seg, np.maximum(b, h), h, filament_diameter)
    first = np.r_[True, path_id[1:] != path_id[:-1]]
    e[first] = 0.0
    return e


# ----------------------------------------------------------------------------- all layers


@dataclass(frozen=True)
class ToolpathSettings:
    """Parameters of the tool-path stage (mm, mm/min, radians)."""

    path_width: float = 1.0  #: iso-contour spacing; default: the nozzle diameter
    step: float = 1.0  #: re-sampling distance (thesis §3.5.2: 1 mm)
    filament_diameter: float = 1.75
    feed: float = 600.0  #: nozzle speed along the path, mm/min
    max_angle: float = float(np.radians(10.0))  #: low-pass / slerp threshold (§3.5.2)
    #: largest angle between orientation and layer normal: the shipped nozzle cone has a 40° half-angle,
    #: so past ~50° it would cut the layer; 40° let every kitten waypoint reach a collision-free pose
    max_tilt: float = float(np.radians(40.0))
    window: int = 8  #: earlier layers searched for the closest point (Eq. 3.3)
    fill_gaps: bool = True  #: extra passes through strips the spirals leave open (more jumps)

    def __post_init__(self) -> None:
        for name in ("path_width", "step", "filament_diameter", "feed", "max_angle", "max_tilt"):
            if not getattr(self, name) > 0:
                raise CurvsliceError(f"tool-path setting {name} must be positive (got {getattr(self, name)})")
        if not self.max_tilt < np.pi / 2:
            raise CurvsliceError("the largest tilt from the layer normal must be below 90° (else the nozzle could point into printed material)")
        if not 0 < self.min_thickness <= self.max_thickness <= 1.0:
            raise CurvsliceError("layer thickness clamps need 0 < min_thickness <= max_thickness <= 1 (shares of the path width)")
    min_thickness: float = 0.1  #: local layer thickness clamp, as a share of the path width
    max_thickness: float = 1.0


@dataclass
class Toolpaths:
    """Samples of all layers in print order (the ``toolpaths.npz`` contract) and per-layer figures."""

    positions: np.ndarray
    normals: np.ndarray
    layer: np.ndarray
    path: np.ndarray
    extrusion: np.ndarray
    thickness: np.ndarray
    feed: np.ndarray
    bead: np.ndarray  #: bead width per sample (mm), encoded in ``extrusion``
    layers: list[dict[str, float]]
    seconds: dict[str, float]


def _thickness(points: np.ndarray, earlier: list[tuple[np.ndarray, cKDTree, float]],
               candidates: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Closest point under each point on the platform top ``z = 0`` or the ``earlier`` layers'
    triangles (Eq. 3.3; ``candidates`` nearest triangle centroids tried on each; each layer comes
    with its centroid tree and largest centroid-to-corner reach) and the distance
    to it: the local layer thickness (unclamped). Layers are searched newest first, and a layer
    only for the points it may bring closer: no triangle is nearer than its nearest centroid
    less the layer's largest centroid-to-corner reach."""
    q = np.asarray(points, np.float64).reshape(-1, 3)
    closest = np.column_stack([q[:, 0], q[:, 1], np.zeros(len(q))])
    dist = np.abs(q[:, 2])
    for tri_k, tree_k, reach in reversed(earlier):
        bound = tree_k.query(q, workers=-1)[0] - reach
        todo = np.nonzero(bound < dist)[0]
        if len(todo) == 0:
            continue
        c_k, d_k, _ = ori.closest_points(q[todo], tri_k, tree_k, candidates)
        better = d_k < dist[todo]
        closest[todo[better]], dist[todo[better]] = c_k[better], d_k[better]
    return closest, dist


def plan_toolpaths(surfaces: list[trimesh.Trimesh], settings: ToolpathSettings = ToolpathSettings(),
                   progress=None) -> Toolpaths:
    """Tool-paths, orientations and extrusion for working surfaces in print order (§3.5.1-3.5.2).

    Layer 1 stands on the platform top ``z = 0``; every later layer also on the ``window``
    layers before it (Eq. 3.3). ``progress`` is an optional tqdm-like object updated per layer.
    """
    w = settings.path_width
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("positions", "normals", "layer", "path", "thickness", "bead")}
    earlier: list[tuple[np.ndarray, cKDTree, float]] = []
    per_layer: list[dict[str, float]] = []
    seconds = {"spirals": 0.0, "orientation": 0.0}
    next_path, cursor = 0, None
    for index, mesh in enumerate(surfaces, start=1):
        t0 = perf_counter()
        surface = clean_surface(mesh)
        tri = surface.triangles
        own_tree = cKDTree(tri.mean(axis=1)) if len(tri) else None
        # (a floor: fewer candidate triangles than for the samples' own thickness below)
        vertex_thickness = np.clip(_thickness(surface.vertices, earlier[-settings.window:], 3)[1],
                                   settings.min_thickness * w, settings.max_thickness * w)
        vertex_tree = cKDTree(surface.vertices) if len(surface.vertices) else None

        def min_bead(points: np.ndarray) -> np.ndarray:  # a bead is never narrower than it is high
            return vertex_thickness[vertex_tree.query(points)[1]]

        paths = layer_paths(surface, w, start=cursor, fill_gaps=settings.fill_gaps, min_bead=min_bead)
        samples = [resample(np.c_[p, b], settings.step, _WIDTH_WEIGHT, _TURN_WEIGHT * w) for p, b in zip(paths.pieces, paths.widths)]
        samples = [s for s in samples if len(s) >= 2]
        t1 = perf_counter()
        row = {"layer": index, "pieces": len(samples), "jumps": max(len(samples) - 1, 0),
               "travel_mm": round(paths.travel, 3), "rings": paths.rings, "regions": paths.regions,
               "splices": paths.splices, "failed_splices": paths.failed_splices,
               "closed_components": paths.closed_components, "gap_passes": paths.gap_passes,
               "bridged_holes": paths.bridged_holes, "thin_passes": paths.thin_passes, "max_distance_mm": round(paths.max_distance, 3),
               "samples": 0, "length_mm": 0.0}
        if samples:
            q = np.vstack(samples)
            q, bead = q[:, :3], q[:, 3]
            pid = np.repeat(np.arange(next_path, next_path + len(samples)), [len(s) for s in samples])
            next_path += len(samples)
            cursor = q[-1]
            q, _, own_face = ori.closest_points(q, tri, own_tree)  # chords (links) back onto the layer
            surface_normal = ori.surface_normals(surface, q, own_face)
            closest, dist = _thickness(q, earlier[-settings.window:])
            t = ori.accumulation_directions(q, closest, surface_normal)
            t = ori.limit_tilt(t, surface_normal, settings.max_tilt)
            t = ori.low_pass(t, pid, settings.max_angle)
            pos, nrm, parent, frac = ori.slerp_subdivide(q, t, pid, settings.max_angle)
            pos, _, pos_face = ori.closest_points(pos, tri, own_tree)  # crest subdivisions onto the layer
            # the low-pass may have tilted a sample past the limit: never into the printed side
            nrm = ori.limit_tilt(nrm, ori.surface_normals(surface, pos, pos_face), _HARD_TILT)
            nxt = np.minimum(parent + 1, len(q) - 1)
            thick = np.clip(dist, settings.min_thickness * w, settings.max_thickness * w)
            row["thickness_clamped"] = int(np.sum((dist < settings.min_thickness * w) | (dist > settings.max_thickness * w)))
            out["positions"].append(pos)
            out["normals"].append(nrm)
            out["layer"].append(np.full(len(pos), index, np.int32))
            out["path"].append(pid[parent].astype(np.int32))
            out["thickness"].append(thick[parent] + frac * (thick[nxt] - thick[parent]))
            out["bead"].append(bead[parent] + frac * (bead[nxt] - bead[parent]))
            row["samples"] = len(pos)
            row["subdivided"] = int(len(pos) - len(q))
            row["length_mm"] = round(float(sum(np.linalg.norm(np.diff(s[:, :3], axis=0), axis=1).sum() for s in samples)), 3)
        if len(tri):
            # the reach bounds every later search of this layer (_thickness): computed once
            earlier.append((tri, own_tree, float(np.linalg.norm(tri - tri.mean(axis=1, keepdims=True), axis=2).max())))
        t2 = perf_counter()
        seconds["spirals"] += t1 - t0
        seconds["orientation"] += t2 - t1
        row["seconds"] = round(t2 - t0, 3)
        per_layer.append(row)
        if progress is not None:
            progress.update(1)
    cat = {k: (np.concatenate(v) if v else np.zeros((0, 3) if k in ("positions", "normals") else 0)) for k, v in out.items()}
    path = cat["path"].astype(np.int32)
    bead = np.maximum(cat["bead"], cat["thickness"]) if len(path) else np.zeros(0)
    extrusion = extrusion_amounts(cat["positions"], path, cat["thickness"], bead, settings.filament_diameter) if len(path) else np.zeros(0)
    return Toolpaths(cat["positions"], cat["normals"], cat["layer"].astype(np.int32), path, extrusion,
                     cat["thickness"], np.full(len(path), settings.feed), bead, per_layer, seconds)


def save_toolpaths(outdir: Path, tp: Toolpaths, settings: ToolpathSettings) -> None:
    """Write ``toolpaths.npz`` (the stage contract) and the extended ``toolpaths.gcode``."""
    outdir = Path(outdir)
    np.savez_compressed(outdir / "toolpaths.npz", positions=tp.positions, normals=tp.normals, layer=tp.layer,
                        path=tp.path, extrusion=tp.extrusion, thickness=tp.thickness, feed=tp.feed)
    header = {k: (round(float(np.degrees(v)), 6) if k in ("max_angle", "max_tilt") else v)
              for k, v in asdict(settings).items()}
    header = {("max_angle_deg" if k == "max_angle" else "max_tilt_deg" if k == "max_tilt" else k): v
              for k, v in header.items()}
    header.update(layers=len(tp.layers), samples=len(tp.positions), pieces=int(len(np.unique(tp.path))))
    write_gcode6(outdir / "toolpaths.gcode", tp.positions, tp.normals, tp.extrusion, tp.feed, tp.path, tp.layer, header)
