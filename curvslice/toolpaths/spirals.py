"""Connected Fermat spirals (thesis §3.5.1; Zhao et al., SIGGRAPH 2016, the thesis's ref. [2]).

A chain of nested rings is cut (``CUT_RANGE`` widths) near a common cut line and rerouted into
one in-and-out spiral (inwards on rings 0, 2, 4, ..., outwards on 1, 3, 5, ..., both ends next to
each other on the outer ring); where the contour tree branches, each child spiral is spliced into
the ring that hosts it through a gap, so a connected region is one continuous piece unless a
splice has no room (then the child becomes its own piece, counted as a jump).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import shapely
from scipy.spatial import ConvexHull, cKDTree

from curvslice.toolpaths.constants import (BEAD_RANGE, CORNER_ANGLE, CUT_RANGE, CUT_SHARE, CUT_STEP, DENSE_STEP, DOT_RING, FIRST_LEVEL,
                                           FIT_STEP, OPEN_GAP, SPLICE_REACH, SPLICE_SHIFT, SPLICE_SHIFTS, THIN_LOOP)
from curvslice.toolpaths.resampling import resample
from curvslice.toolpaths.rings import Ring, fitting_centre_line, lone_thin_loop, thin_rise
from curvslice.vectors import row_norms


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
    s, closest = _closest_points(ring, ring.cumlen, point[None])
    return float(s[0]), float(np.linalg.norm(closest[0] - point))


def _tangent(ring: Ring, s: float, span: float) -> np.ndarray:
    cum = ring.cumlen
    pts = np.vstack([ring.points, ring.points[:1]])
    total = cum[-1]
    return _point_at(pts, cum, (s + span) % total) - _point_at(pts, cum, (s - span) % total)


def _seam(ring: Ring, s: float, width: float, edge: Callable[[], cKDTree | None] | None = None) -> float:
    """Arclength of a lone ring's seam: the point nearest (along the ring) to ``s`` where the ring
    turns less than ``CORNER_ANGLE`` over a width either side, so the ends of the walk meet along a
    straight stretch and their round caps touch; at a sharp tip they would be lengthened past
    each other (:func:`~curvslice.toolpaths.beads.fit_beads`). Where no stretch is that straight (a
    ring a few widths long), its straightest point where the strip between it and the layer's ``edge``
    (a tree of points along it, asked for only here) is narrowest, within the edge's sampling step (``FIT_STEP`` widths): at
    the tip of an elongated ring the caps were widened over each other (fertility 0.8 layer 150: 15.5 %
    overlap); at a corner of the layer the seam's caps, as wide as the walk's ends, leave the corner
    open that the widened beads around the ring reach everywhere else (a rounded square 2.5 w across at
    0.8 mm, the sharp tips' top: 94.3 % coverage)."""
    cum, total = ring.cumlen, ring.length
    if total <= 4.0 * width:
        return s
    at = cum[:-1]
    cos = _turn_cos(ring, cum, at, width)
    straight = np.nonzero(cos > np.cos(CORNER_ANGLE))[0]
    if len(straight) == 0:  # a small ring: its straightest point, of those where its strip is narrowest
        tree = edge() if edge is not None else None
        if tree is not None and tree.n:
            strip = tree.query(ring.points)[0]  # (at: the points' arclengths)
            narrow = np.flatnonzero(strip <= strip.min() + FIT_STEP * width)
            return float(at[narrow[np.argmax(cos[narrow])]])
        return float(at[np.argmax(cos)])
    off = np.abs((at[straight] - s + 0.5 * total) % total - 0.5 * total)
    return float(at[straight[np.argmin(off)]])


def _closest_points(ring: Ring, cum: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_closest_s` of many ``points`` at once (``cum``: the ring's ``cumlen``): the arclengths on
    ``ring`` and the closest points."""
    a = ring.points
    ab = np.roll(a, -1, axis=0) - a
    t = np.clip(np.einsum("cij,ij->ci", points[:, None] - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0, 1)
    dist = row_norms(a + t[..., None] * ab - points[:, None])
    i = np.argmin(dist, axis=1)
    ti = t[np.arange(len(points)), i]
    return cum[i] + ti * (cum[i + 1] - cum[i]), a[i] + ti[:, None] * ab[i]


def _turn_cos(ring: Ring, cum: np.ndarray, s: np.ndarray, width: float) -> np.ndarray:
    """Cosine of the turn of ``ring`` at arclengths ``s`` over a width either side (:func:`_seam`'s measure;
    ``cum``: the ring's ``cumlen``)."""
    closed = np.vstack([ring.points, ring.points[:1]])
    at, ahead, behind = (np.column_stack([np.interp((s + d) % cum[-1], cum, closed[:, i]) for i in range(3)])
                         for d in (0.0, width, -width))
    u, v = at - behind, ahead - at
    return np.einsum("ij,ij->i", u, v) / np.maximum(row_norms(u) * row_norms(v), 1e-300)


def _dot_centre(ring: Ring) -> np.ndarray:
    """A dot's centre, where the links of a spiral reach it: its point nearest to its mean."""
    return ring.points[np.argmin(row_norms(ring.points - ring.points.mean(axis=0)))]


def _dot_chord(ring: Ring, width: float, anchor: np.ndarray, border: np.ndarray | None = None,
               chords: int | None = None) -> np.ndarray:
    """A lone dot's pass: chords across its blob in the plane of its ring, walked to and fro from the end
    nearest to ``anchor`` (where the previous piece ended). The blob is the ring's convex hull grown by
    the reach of its beads outwards: to the layer's edge (an outermost ring, ``FIRST_LEVEL`` widths) or to
    the bead of the ring outside it (a dot nested in a spiral, ½ width). Its least breadth (rotating
    calipers) is twice the reach of its beads across: from the ring up to the top of the distance inside
    it (``Ring.top − level``) plus that outward reach; one chord of the widest bead (``BEAD_RANGE``)
    covers it while that breadth leaves at most one hairline (``OPEN_GAP − ½`` widths, never open) beyond
    the bead, else ``⌈(2·reach − hairline) / widest⌉`` chords evenly spaced across the ring parallel to its
    narrowest edge, each spanning its share of the hull (counting the whole top of a nested dot laid 3
    chords over a blob one bead fills, cheburashka 2.5 mm layer 2: 14.1 % overlap). A chord from one
    point of the ring to the farthest one ran diagonally across an elongated blob and left both ends to
    gap passes (cow 0.8 layer 14: 10.1 % overlap; the corpus' arch layer 10 flipped between 4.1 and
    5.8 % as its vertices moved by 4e-16 mm).

    One chord is the centre line of the hull's cross-sections (:func:`_centre_line`), bending where the
    blob's sides slant, so its bead spans each cross-section and its round ends reach the corners: of the
    directions of the hull's edges and of its vertices from its centre, the one whose bead (half the
    widest, round ends) covers most of the blob. A straight chord along the narrowest breadth, centred
    in the hull's band, left two corners of a pentagonal blob 2.2 × 1.5 w open (rocker-arm 0.8 layer 98:
    90.3 % coverage), and which way a round blob's slivers fall (along flats or across corners, homer
    0.8 layer 62, an octagon 1.6 w across) is decided by the same area. ``chords``: their number where it
    is known (a lone thin loop: one, whose bead spans the loop by :func:`~curvslice.toolpaths.rings.thin_rise`),
    else from the blob's breadth as above."""
    centre = ring.points.mean(axis=0)
    plane = np.linalg.svd(ring.points - centre, full_matrices=False)[2][:2]
    flat = (ring.points - centre) @ plane.T
    hull = flat[ConvexHull(flat).vertices]
    edge = np.roll(hull, -1, axis=0) - hull
    edge /= np.maximum(row_norms(edge)[..., None], 1e-300)
    normal = np.c_[-edge[:, 1], edge[:, 0]]
    across = hull @ normal.T  # (hull point, direction)
    breadth = np.ptp(across, axis=0)
    k = int(np.argmin(breadth))
    # half the breadth the dot's beads must fill: from its ring inwards to the top, and outwards
    outward = min(ring.level, 0.5 * width)
    rise = ring.top - ring.level if np.isfinite(ring.top) else 0.5 * breadth[k]  # (a spliced ring: its own breadth)
    if chords is None:
        chords = max(int(np.ceil((2.0 * (rise + outward) - (OPEN_GAP - 0.5) * width) / (BEAD_RANGE[1] * width))), 1)
    if chords == 1:
        blob = shapely.Polygon(hull).buffer(outward)
        if border is not None and len(border):  # the layer's edge around the ring: the corners its contour rounds off
            near = border[np.isfinite(cKDTree(ring.points).query(border, distance_upper_bound=outward + 0.5 * BEAD_RANGE[1] * width)[0])]
            if len(near):
                blob = shapely.MultiPoint(np.vstack([np.array(blob.exterior.coords), (near - centre) @ plane.T])).convex_hull
        outline = np.array(blob.exterior.coords)[:-1]
        radial = outline - outline.mean(axis=0)
        sides = np.roll(outline, -1, axis=0) - outline
        ways = np.vstack([sides, radial])
        ways = ways[row_norms(ways) > 1e-9 * width]
        lines = [_centre_line(outline, way / np.linalg.norm(way), width, outward) for way in ways]
        # what the bead across the blob's least breadth (within the widest) reaches, short of the hairline:
        # all directions cover the blob at full reach, the corners the tighter reach leaves tell them apart
        unit = sides / np.maximum(row_norms(sides)[..., None], 1e-300)
        least = np.ptp(outline @ np.c_[-unit[:, 1], unit[:, 0]].T, axis=0).min()
        reach = 0.5 * min(BEAD_RANGE[1] * width, least) - (OPEN_GAP - 0.5) * width
        covered = [blob.intersection(shapely.LineString(line).buffer(reach)).area for line in lines]
        spans = [lines[int(np.argmax(covered))]]
    else:
        lo, hi = across[:, k].min(), across[:, k].max()
        along = hull @ edge[k]
        outline = shapely.Polygon(np.c_[along, across[:, k]])
        share = (hi - lo) / chords
        spans = []
        for c in range(chords):  # each chord spans its share of the hull from end to end
            band = outline.intersection(shapely.box(along.min() - width, lo + c * share,
                                                    along.max() + width, lo + (c + 1) * share))
            span = np.array(band.bounds)[[0, 2]] if not band.is_empty else np.full(2, along.mean())
            mid = lo + (c + 0.5) * share
            spans.append(np.outer(span, edge[k]) + np.outer(np.full(2, mid), normal[k]))
    walks = []
    for legs in (spans, spans[::-1]):  # from either side, either way: the walk that starts nearest the anchor
        for first in (0, 1):
            walk = np.vstack([leg[::-1] if (c + first) % 2 else leg for c, leg in enumerate(legs)])
            walks.append(centre + walk @ plane)
    return min(walks, key=lambda walk: float(np.linalg.norm(walk[0] - anchor)))


def _centre_line(hull: np.ndarray, direction: np.ndarray, width: float, inset: float) -> np.ndarray:
    """Midpoints of the cross-sections of a convex polygon (``hull``, 2D) normal to the unit vector
    ``direction``, every quarter width from ``inset`` inside one end of the polygon to ``inset`` inside
    the other: a bead down it spans each cross-section evenly, bending where the polygon's sides slant."""
    side = np.array([-direction[1], direction[0]])
    t, u = hull @ direction, hull @ side
    inset = min(inset, 0.25 * np.ptp(t))
    at = np.linspace(t.min() + inset, t.max() - inset, max(int(np.ceil(np.ptp(t) / (0.25 * width))), 2) + 1)
    t0, t1, u0, u1 = t, np.roll(t, -1), u, np.roll(u, -1)
    lo_t, hi_t = np.minimum(t0, t1), np.maximum(t0, t1)
    s = np.clip((at[:, None] - t0) / np.where(hi_t > lo_t, t1 - t0, 1.0), 0.0, 1.0)  # (cross-section, edge)
    hit = (at[:, None] >= lo_t - 1e-12) & (at[:, None] <= hi_t + 1e-12) & (hi_t > lo_t)
    cross = u0 + s * (u1 - u0)
    mid = 0.5 * (np.where(hit, cross, np.inf).min(axis=1) + np.where(hit, cross, -np.inf).max(axis=1))
    return np.outer(at, direction) + np.outer(mid, side)


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

    def __init__(self, tree: _Tree, width: float, edge: np.ndarray | None = None):
        self.tree = tree
        self.w = width
        self.gap = CUT_RANGE[0] * width
        self.extra_pieces: list[np.ndarray] = []
        self.splices = 0
        self.failed = 0
        self._ring_points: tuple[_Tree, cKDTree, np.ndarray] | None = None  # every ring's points, for _link_crosses
        self._lines: dict[int, np.ndarray | None] = {}  # ring -> its centre line where it lies inside it (_centre_line)
        self._bands: dict[tuple[int, int], bool] = {}  # rings (a, b) -> whether their band is thin (_thin_band)
        self.edge = edge  #: points of the layer's edge (:func:`_dot_chord`)
        self._edge: cKDTree | None = None  # their tree (:func:`_seam`), once asked

    def _edge_tree(self) -> cKDTree | None:
        """The KD-tree of ``edge`` (built once per layer, when a lone ring's seam first asks; None without edge)."""
        if self._edge is None and self.edge is not None and len(self.edge):
            self._edge = cKDTree(self.edge)
        return self._edge

    def chain_from(self, ring_id: int) -> list[int]:
        """The rings nested from ``ring_id`` inwards while each band holds one ring more. A chain that
        turns back down -- a ring entered from its higher side, the band between it and the ring before
        bounded by both from below -- across a thin band (:meth:`_thin_band`) stops before that ring: the
        band is an annulus whose two sides lie closer than a bead, and the first ring's pass, fitted to the
        strip, prints it all (two passes would lay their beads over each other)."""
        chain = [ring_id]
        while True:
            comp = self.tree.child_comp.get(chain[-1])
            kids = self.tree.child_rings.get(comp, []) if comp is not None else []
            if len(kids) != 1:
                return chain
            if self.tree.rings[kids[0]].above == comp and self._thin_band(chain[-1], kids[0]):
                return chain
            chain.append(kids[0])

    def _past_thin_band(self, ring_id: int) -> list[int]:
        """The rings beyond a thin band that stopped a chain at ``ring_id`` (:meth:`chain_from`): the rings
        nested inside the band's other ring, on its far side. That ring is printed by the chain's last pass,
        the rings past it are not, so the chain's last ring hosts them (a torus at 1.5 mm, layer 4: an
        annulus whose crest is such a band; its inner half, three rings, was left to a gap pass, 80.9 %
        coverage). None where the chain did not stop at a thin band."""
        comp = self.tree.child_comp.get(ring_id)
        kids = self.tree.child_rings.get(comp, []) if comp is not None else []
        if len(kids) != 1 or self.tree.rings[kids[0]].above != comp or not self._thin_band(ring_id, kids[0]):
            return []
        return list(self.tree.child_rings.get(self.tree.child_comp.get(kids[0]), []))

    def _thin_band(self, a: int, b: int) -> bool:
        """Whether rings ``a`` and ``b``, both bounding the band above them from below, hold between them a
        band printed by one pass: it rises less above them than a thin loop (:func:`lone_thin_loop`), by its
        highest point or along most of it -- half the median gap between the two rings, as a thin loop's rise
        is half its breadth (a cup's 1.2 w wall at 1 mm, layer 17: rings 0.3 w apart all round but where the
        handle joins, 2.3 w; walked both sides, 7.9 % overlap). Where the band bulges wider than the one pass's
        bead, the gap passes print the rest."""
        if (a, b) not in self._bands:  # (chain_from asks again for every piece and splice through the band)
            ra, rb = self.tree.rings[a], self.tree.rings[b]
            thin = lone_thin_loop(ra, self.w) and lone_thin_loop(rb, self.w)
            if not thin:
                gap = float(np.median(cKDTree(rb.points).query(ra.points)[0]))
                thin = 0.5 * gap < max(thin_rise(min(ra.floor, rb.floor), self.w), THIN_LOOP * self.w)
            self._bands[(a, b)] = bool(thin)
        return self._bands[(a, b)]

    def _centre_line(self, ring_id: int) -> np.ndarray | None:
        """The centre line of ``ring_id`` where it lies inside the loop
        (:func:`~curvslice.toolpaths.rings.fitting_centre_line`), else ``None``: such a loop is walked round."""
        if ring_id not in self._lines:
            self._lines[ring_id] = fitting_centre_line(self.tree.rings[ring_id])
        return self._lines[ring_id]

    def _encloses(self, ring_id: int) -> bool:
        """Whether ``ring_id`` alone bounds the band above it, the region its own loop encloses: only then
        is that region a strip between the loop's own two sides, whose centre line
        (:func:`~curvslice.toolpaths.rings.loop_centre_line`) pairs them. A ring sharing its band with
        another (an annulus between an outer and an inner ring) encloses the other's hole as well: the
        pairing of its sides ran across that hole (a thin-walled box at 1 mm, layer 5: a bead laid 15 mm
        through the box's inside). And only where that centre line lies inside the loop (:meth:`_centre_line`)."""
        above = self.tree.rings[ring_id].above
        return not any(r.above == above for i, r in enumerate(self.tree.rings) if i != ring_id) and self._centre_line(ring_id) is not None

    def piece(self, ring_id: int, anchor: np.ndarray, host_tangent: np.ndarray | None,
              siblings: list[int] = ()) -> np.ndarray:
        """Fermat spiral of the chain starting at ``ring_id``, cut next to ``anchor``.

        The innermost ring of a chain thinner than :func:`~curvslice.toolpaths.rings.thin_rise`
        (and hosting no branches) is not part of the spiral: its two sides would be laid over each
        other, so it becomes one pass down its middle, a piece of its own."""
        chain = self.chain_from(ring_id)
        beyond = self._past_thin_band(chain[-1])
        inner = self.tree.rings[chain[-1]]
        inner_comp = self.tree.child_comp.get(chain[-1])
        if (len(chain) > 1 and inner.length >= DOT_RING * self.w and inner.rise < thin_rise(inner.floor, self.w)
                and len(self.tree.child_rings.get(inner_comp, [])) <= 1 and self._encloses(chain[-1])):
            self.extra_pieces.append(self._centre_line(chain[-1]))
            chain = chain[:-1]
        rings = [self.tree.rings[i] for i in chain]
        cuts: list[float] = []
        tangent = host_tangent
        for k, (ring, point) in enumerate(zip(rings, self.cut_line(chain, anchor, spliced=host_tangent is not None))):
            s, _ = _closest_s(ring, point)
            if tangent is not None and ring.length > 0 and np.dot(_tangent(ring, s, self.w), tangent) < 0:
                ring = _reversed(ring)
                s = ring.length - s
            rings[k] = ring
            cuts.append(s)
            tangent = _tangent(ring, s, self.w)
        seam = len(rings) == 1 and host_tangent is None  # a lone ring's own seam: no link crosses its cut
        if seam:
            cuts[0] = _seam(rings[0], cuts[0], self.w, self._edge_tree)
        dots = [r.length < DOT_RING * self.w for r in rings]
        # an odd chain turns at its innermost ring, reached by the link in from the end of the inward walk and
        # left by the link out to the start of the outward one, both on the same side of the cut line: a ring
        # parts them by its own walk across, a dot (its centre) does not, and they converged on it in a V whose
        # arms lay within a bead of each other from the dot out to the ring around it (inverted cone at 1.5 mm,
        # layer 8: 7.0 % overlap). Where that ring is the spiral's last walk (a root chain of three; a spliced
        # spiral's ends must meet at its host's gap, and further out the other links cross the cut the same way),
        # it is walked the other way round, from the other side of the cut, so the links reach the dot from either
        # side; the spiral then ends a cut across from its start.
        turn_dot = host_tangent is None and len(rings) == 3 and dots[2] and not dots[1]
        # children hosted by the innermost ring (branches), root siblings by ring 0
        hosted: dict[int, list[int]] = {}
        last_comp = self.tree.child_comp.get(chain[-1])
        if last_comp is not None and len(self.tree.child_rings.get(last_comp, [])) > 1:
            hosted[len(chain) - 1] = list(self.tree.child_rings[last_comp])
        if beyond:
            hosted.setdefault(len(chain) - 1, []).extend(beyond)
        if siblings:
            hosted.setdefault(0, []).extend(siblings)
        if len(rings) == 1 and not hosted and lone_thin_loop(rings[0], self.w) and self._encloses(chain[0]):
            # a loop whose sides lie closer than a bead: one pass down its middle, the bead as wide
            # as the region (fit_beads), instead of two sides printed over each other; a round one is a
            # blob, whose farthest pair of points is any diameter: the centre line of the blob, as a lone
            # dot's one chord, in the direction its bead covers most of it (cheburashka 0.8 layer 69: the
            # diameter across left a wedge of the blob to a gap pass whose bead, as wide as the layer is
            # thick, overlapped the centre line's: 5.9 % overlap; one chord: 0 %, coverage 95.1 %)
            if rings[0].round and rings[0].length >= DOT_RING * self.w:
                return _dot_chord(rings[0], self.w, anchor, self.edge, chords=1)
            return self._centre_line(chain[0])  # (cached: _encloses computed it)
        arcs: list[np.ndarray] = []
        n = len(rings)
        order = list(range(0, n, 2)) + list(range(n - 1 if n % 2 == 0 else n - 2, 0, -2))
        for k in order:
            ring, s = rings[k], cuts[k]
            if dots[k]:  # a bead-sized ring: its centre, reached by the links (alone: its diameter)
                arcs.append(_dot_centre(ring)[None] if n > 1 else _dot_chord(ring, self.w, anchor, self.edge))
                for child in hosted.get(k, []):
                    self._separate(child)
                continue
            if seam or (n == 2 and host_tangent is None):
                # the walk stops a bead short of its start, the round caps touching (a root chain of two rings:
                # one link crosses the cut, in to the inner ring, whose walk stops a bead short of it; a gap as
                # wide as two links need left the strip between them open: the needle's top at 0.8 mm, two
                # rings 8.8 and 4.5 w long, 93.9 % coverage)
                g = self.w
            else:
                g = float(np.clip(ring.length / CUT_SHARE, CUT_RANGE[0] * self.w, CUT_RANGE[1] * self.w)) if n >= 3 else self.gap
            if k % 2 == 0 or turn_dot:
                start, end, direction = s - g / 2, s + g / 2, -1
            else:
                start, end, direction = s + g / 2, s - g / 2, +1
            arcs.append(self._ring_walk(ring, chain[k], start, end, direction, hosted.get(k, []), s))
        return np.vstack(arcs)

    def cut_line(self, chain: list[int], anchor: np.ndarray, spliced: bool = False) -> list[np.ndarray]:
        """Cut point of every ring of ``chain`` (outermost first), lined up on one cut line (Zhao et
        al. 2016). A root chain: the innermost ring's point nearest to ``anchor``, then outwards each
        ring's point nearest to the cut of the ring inside it. A chain ``spliced`` into a host ring:
        the outermost ring's point nearest to ``anchor`` (the splice on the host), then inwards.

        Every point of an inner ring lies about a width from the ring around it (the boundary
        distance grows by one width from one ring to the next, at most one width per width walked),
        but not the converse: an outer ring's point may lie far from a small or off-centre inner
        ring. Propagated outwards, the links of the spiral across the cut line stay about a width
        long wherever the anchor lies (inwards from an anchor beside an off-centre inner ring, a link
        crossed the region: rocker-arm 0.8 layer 125, 36 w). A spliced chain's first link runs from
        the host's gap to its outermost cut, so there the cut line starts at the splice: propagated
        outwards it could end anywhere on the child's outer ring, a splice too far to link (an
        annulus with an off-centre hole: the hole's branch was printed as a separate piece)."""
        order = list(range(len(chain))) if spliced else list(reversed(range(len(chain))))
        points: dict[int, np.ndarray] = {}
        point = anchor if spliced or len(chain) < 2 else self._straight_anchor(chain, anchor)
        for k in order:
            ring = self.tree.rings[chain[k]]
            point = _point_at(np.vstack([ring.points, ring.points[:1]]), ring.cumlen, _closest_s(ring, point)[0])
            points[k] = point
        return [points[k] for k in range(len(chain))]

    def _straight_anchor(self, chain: list[int], anchor: np.ndarray) -> np.ndarray:
        """Where a root chain's cut line starts on its innermost ring: the point nearest to ``anchor``
        whose cut line (propagated outwards, :meth:`cut_line`) meets no ring at a corner -- where it
        turns more than ``CORNER_ANGLE`` over a width either side (:func:`_seam`'s rule for a lone
        ring) and more than along half its length (a ring that turns alike all round, a small circle,
        has no corner). At a corner the links in and out of the spiral turn with the rings and their
        beads overlap each other and the rings' (kitten 1.6 layer 24, cut at a tip of its inner ring:
        5.0 % overlap, 2.8 % a few widths along its flank). Dots (rings shorter than ``DOT_RING``
        widths) do not count; where every cut line meets a corner, the one whose sharpest is least
        sharp. Candidates: the innermost ring's point nearest to ``anchor``, then its
        points every ``CUT_STEP`` widths."""
        inner = self.tree.rings[chain[-1]]
        start = _point_at(np.vstack([inner.points, inner.points[:1]]), inner.cumlen, _closest_s(inner, anchor)[0])
        if self._cut_sharpness(chain, start[None])[0] <= 0:
            return start
        cum = inner.cumlen
        candidates = np.vstack([start, np.column_stack([np.interp(np.arange(0.0, cum[-1], CUT_STEP * self.w), cum,
                                                                  np.r_[inner.points[:, i], inner.points[0, i]])
                                                        for i in range(3)])])
        sharp = self._cut_sharpness(chain, candidates)
        if not np.any(sharp <= 0):
            return candidates[int(np.argmin(sharp))]
        return candidates[int(np.argmin(np.where(sharp <= 0, row_norms(candidates - anchor), np.inf)))]

    def _cut_sharpness(self, chain: list[int], points: np.ndarray) -> np.ndarray:
        """For cut lines starting at ``points`` on the innermost ring of ``chain``: how much sharper
        than a corner (:meth:`_straight_anchor`) their sharpest ring is where they meet it, in the
        cosine of the turn (:func:`_turn_cos`); ``<= 0``: no corner."""
        sharp = np.full(len(points), -np.inf)
        for ring_id in reversed(chain):
            ring = self.tree.rings[ring_id]
            cum = ring.cumlen
            s, points = _closest_points(ring, cum, points)
            if cum[-1] >= DOT_RING * self.w:
                corner = min(np.cos(CORNER_ANGLE), float(np.median(_turn_cos(ring, cum, cum[:-1], self.w))))
                sharp = np.maximum(sharp, corner - _turn_cos(ring, cum, s, self.w))
        return sharp

    def _thin_leaf(self, ring_id: int) -> bool:
        """Whether ``ring_id`` alone makes a thin loop's centre line (:func:`~curvslice.toolpaths.rings.lone_thin_loop`,
        hosting nothing): spliced into a host, the walk would go out along the line and come back beside
        it over its whole length (cow 0.8 layer 110: a strip's line 7 w long), so it is a piece of its own."""
        comp = self.tree.child_comp.get(ring_id)
        ring = self.tree.rings[ring_id]
        return (not self.tree.child_rings.get(comp, []) and ring.length >= DOT_RING * self.w
                and lone_thin_loop(ring, self.w) and self._encloses(ring_id))

    def _separate(self, ring_id: int) -> None:
        self.failed += 1
        first = self.tree.rings[ring_id].points[0]
        self.extra_pieces.append(self.piece(ring_id, first, None))

    def _link_crosses(self, a: np.ndarray, b: np.ndarray, own: tuple[int, int]) -> bool:
        """Whether a splice link from ``a`` (on the host) to ``b`` (the child's cut) runs over another ring
        of the tree than its ``own`` two: its points more than half a width from both ends come within
        half a width of one (inside that ring's bead). Such a link crosses a region printed by other
        passes (cow 0.8 layer 110: two lobes spliced across the strip between them, whose centre pass it
        crossed)."""
        length = float(np.linalg.norm(b - a))
        if length <= self.w:
            return False
        t = np.arange(0.5 * self.w, length - 0.5 * self.w, DENSE_STEP * self.w) / length
        if not len(t):
            return False
        if self._ring_points is None or self._ring_points[0] is not self.tree:
            dense = [resample(np.vstack([r.points, r.points[:1]]), DENSE_STEP * self.w) for r in self.tree.rings]
            owner = np.repeat(np.arange(len(dense)), [len(d) for d in dense])
            self._ring_points = (self.tree, cKDTree(np.vstack(dense)), owner)
        _, tree, owner = self._ring_points
        near = tree.query_ball_point(a + t[:, None] * (b - a), 0.5 * self.w)
        return any(o not in own for o in {int(owner[j]) for hits in near for j in hits})

    def _ring_walk(self, ring: Ring, host: int, start: float, end: float, direction: int,
                   children: list[int], cut: float) -> np.ndarray:
        """Walk ``ring`` (ring ``host`` of the tree, perhaps reversed) from ``start`` to ``end`` splicing in
        the spirals of ``children``."""
        total = ring.length
        span = (end - start) % total if direction > 0 else (start - end) % total
        g = self.gap
        closed = np.vstack([ring.points, ring.points[:1]])
        cum = ring.cumlen
        placed: list[tuple[float, int]] = []  # (offset along the walk, child)
        shifts = np.repeat(np.arange(1, SPLICE_SHIFTS + 1) * SPLICE_SHIFT * self.w, 2) * np.tile([1, -1], SPLICE_SHIFTS)
        for child in children:
            if self._thin_leaf(child):  # its centre line's two ends lie apart: the link back would run along it
                self.extra_pieces.append(self._centre_line(child))
                continue
            # where the child's cut line meets the host (its outermost cut, next to the host)
            cut_point = self.cut_line(self.chain_from(child), self._nearest_point(child, ring), spliced=True)[0]
            s_child, dist = _closest_s(ring, cut_point)
            offset = (s_child - start) % total if direction > 0 else (start - s_child) % total
            taken = [o for o, _ in placed]
            ok_pos = None
            for shift in np.r_[0.0, shifts]:
                o = offset + shift
                if g <= o <= span - g and all(abs(o - t) >= 2 * g for t in taken):
                    ok_pos = o
                    break
            if ok_pos is None or dist > self._reach(ring, child) or self._link_crosses(
                    _point_at(closed, cum, s_child), cut_point, (host, child)):
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

    def _reach(self, host: Ring, child: int) -> float:
        """How far ``child`` may lie from ``host`` to be spliced into it: ``SPLICE_REACH`` widths, but one width
        (the spacing of nested rings) for a sibling -- a ring of the same band component below as the host, a
        lobe of the layer joined to the host's across the band under the first level. That band is narrower than
        ``2·FIRST_LEVEL`` widths, so the splice's links in and out, a cut apart at either end, squeeze into it
        side by side over their whole length and lay two beads along it (fertility 0.8 layer 187: a lobe 2.2 w
        along a neck, 9.5 % overlap); a longer way round, the sibling is a piece of its own."""
        return self.w if self.tree.rings[child].below == host.below else SPLICE_REACH * self.w

    def _nearest_point(self, child: int, host: Ring) -> np.ndarray:
        pts = self.tree.rings[child].points
        a = host.points
        dist, idx = cKDTree(a).query(pts)
        return a[idx[np.argmin(dist)]]




def connected_spirals(rings: list[Ring], width: float, start: np.ndarray | None,
                      edge: np.ndarray | None = None) -> tuple[list[np.ndarray], int, int, int]:
    """One connected-Fermat-spiral piece per connected region of ``rings``, each rooted at the
    outermost ring nearest to where the previous one ended (``start`` for the first), then the
    children that no splice could host. Returns the pieces and the numbers of regions, splices
    and failed splices. A ring's ``floor`` (the narrowest bead along it) decides whether it is a
    thin loop (:func:`~curvslice.toolpaths.rings.thin_rise`). ``edge``: points along the layer's edge,
    which a lone dot's pass reaches (:func:`_dot_chord`)."""
    pieces: list[np.ndarray] = []
    remaining = set(range(len(rings)))
    builder = _Builder(_Tree(rings, {}, {}), width, edge)
    cursor = np.asarray(start, float) if start is not None else (rings[0].points[0] if rings else None)
    while remaining:
        # root: the band-0 component of the outermost ring nearest to the cursor
        outer = [i for i in remaining if rings[i].level == FIRST_LEVEL * width] or list(remaining)
        first = min(outer, key=lambda i: _closest_s(rings[i], cursor)[1])
        root = rings[first].below
        tree, order = _contour_tree(rings, root)
        remaining -= set(order)
        builder.tree = tree
        roots = tree.child_rings.get(root, [])
        # a thin leaf loop is printed down its middle, never walked round as a host of the others (two
        # sides under a bead apart: the cup's thin wall, split by a curved layer into arcs, 11 % overlap)
        hosts = [i for i in roots if not builder._thin_leaf(i)] or roots
        main = max(hosts, key=lambda i: rings[i].length)
        others = [i for i in roots if i != main]
        if builder._thin_leaf(main):  # all thin leaves: each its own centre line
            builder.extra_pieces += [builder.piece(i, cursor, None) for i in others]
            others = []
        piece = builder.piece(main, cursor, None, siblings=others)
        pieces.append(piece)
        cursor = piece[-1]
    return pieces + builder.extra_pieces, len(pieces), builder.splices, builder.failed
