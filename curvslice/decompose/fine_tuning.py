"""Phase III of the RoboFDM decomposition: constrained fine tuning (thesis §2.4.3).

Works on the solids of the analysis mesh and records every cut (:class:`Cut`) so the same
decomposition can be replayed exactly on the full-resolution model (:func:`replay`).

- Plane perturbation: each coarse separating plane is replaced by the best of a few random
  perturbations (offset ≤ 2.5 % of the bounding-box diagonal, tilt ≤ 5°) that does not grow the
  cross-section by more than 20 %, scored by R(M_i) + R(M_j).
- Region merging: a child is merged into its parent when the merged part, printed from the
  parent's base plane, is no riskier than the two apart.
- Fine decomposition (Eq. 2.2): the riskiest part is clipped by the plane out of 100 normals on
  its upper hemisphere × offsets every 5 mm that removes most risky area and keeps Constraints I
  and II (the first ``valid_candidates`` valid planes of the ranking are compared by their exact
  gain); when it has no such plane the next of the ``top_k`` riskiest is tried. Repeated until
  every part's risky area is within tolerance (or ``max_parts``). Candidate
  planes are ranked on area-weighted surface samples (all offsets of a normal at once by
  cumulative sums); the best few are then cut exactly and checked.

Every cut, coarse or fine, must also leave a new part the extruder can print (not in the thesis,
§2.6 limitation 5): one no thinner than ``min_part_layers`` layers along its direction (a sliver
gets no layer of its own), clear of the platform at its tilt, and *accessible*: at each sampled
nozzle position on it some turn of the extruder holds none of the material of the parts that may
be printed before it -- every part but its own descendants (:func:`turn_hits`). As each new
part is checked against all the material that is not its descendant, and a later cut or merge only
splits or joins that material, every part of the result is accessible in any order that prints
parents first; the cut replacing a blocked one is searched further along the part (higher offsets
of the Eq. 2.2 ranking, or the next perturbed plane).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import manifold3d
import numpy as np
import shapely
import trimesh
from scipy.spatial import cKDTree

from curvslice.decompose.constraints import (clearance_table, clears_platform, faces_up,
                                              material_points, nozzle_positions, sections_intersect, turn_hits)
from curvslice.decompose.parts import Plane, centroid, cross_section, plane_frame, split, to_trimesh, union
from curvslice.decompose.risky import PLATFORM_CONTACT_MM, base_face_mask, lowest_plane, risky_area, risky_faces
from curvslice.decompose.sequence import Sequence, fibonacci_sphere
from curvslice.decompose.shape_analysis import CoarseDecomposition


@dataclass
class Piece:
    """A part during the decomposition: its solid, base plane (build direction = its normal), parent."""

    solid: manifold3d.Manifold
    base: Plane
    parent: int | None
    section: shapely.MultiPolygon = field(default_factory=shapely.MultiPolygon)


@dataclass(frozen=True)
class Cut:
    """Split ``holder`` by ``plane``; the pieces above it whose centres are nearest to a ``keep``
    centre become part ``new``, the others stay with the holder (centres of the analysis pieces)."""

    holder: int
    new: int
    plane: Plane
    keep: np.ndarray
    rest: np.ndarray


@dataclass
class Settings:
    """Phase III parameters; the defaults are the thesis's (§2.4.3) unless marked."""

    alpha_max: float = np.radians(45.0)
    perturbations: int = 16  # random perturbed planes per separating plane (count not stated)
    max_offset_fraction: float = 0.025
    max_tilt: float = np.radians(5.0)
    max_section_growth: float = 0.2
    normals: int = 100
    offset_step: float = 5.0  # mm
    top_k: int = 6
    risky_tolerance: float = 1.0  # mm²: a part is safe below this (not stated in the thesis)
    min_part_volume_fraction: float = 0.005  # no sliver parts (not stated)
    samples: int = 6000  # surface samples ranking the Eq. 2.2 candidates
    exact_candidates: int = 64  # best-ranked planes cut exactly per part
    offsets_per_normal: int = 3  # of the ranked candidates
    valid_candidates: int = 4  # valid planes compared by their exact gain
    max_parts: int = 16
    seed: int = 0
    #: workcell whose extruder each part must clear the platform and the parts printed before it
    #: with (None: Constraints I and II alone)
    workcell: str | None = "ur3"
    #: layer height the parts will be printed at (mm; the default voxel of ``curvslice decompose
    #: --print``), and the fewest layers a part may have along its direction (not stated)
    layer_height: float = 1.0
    min_part_layers: int = 2
    access_samples: int = 100  # nozzle positions sampled per new part (accessibility)
    access_spacing: float = 2.5  # mm between the obstacle points standing for the other parts' material

    def clearance(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The platform-clearance table of :attr:`workcell` (:func:`clearance_table`)."""
        from curvslice.workcell import load_workcell

        return None if self.workcell is None else clearance_table(load_workcell(self.workcell))


@dataclass
class Access:
    """Accessibility of new parts for the extruder of ``settings.workcell`` (:func:`turn_hits`),
    each solid's mesh and obstacle points made once."""

    settings: Settings
    _cache: dict[int, tuple[manifold3d.Manifold, trimesh.Trimesh, np.ndarray]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        from curvslice.workcell import load_workcell

        self.cell = None if self.settings.workcell is None else load_workcell(self.settings.workcell)

    def _of(self, solid: manifold3d.Manifold) -> tuple[manifold3d.Manifold, trimesh.Trimesh, np.ndarray]:
        key = id(solid)
        if key not in self._cache or self._cache[key][0] is not solid:
            mesh = to_trimesh(solid)
            self._cache[key] = (solid, mesh, material_points(mesh, self.settings.access_spacing, self.settings.seed))
        return self._cache[key]

    def points(self, solids: list[manifold3d.Manifold]) -> np.ndarray:
        return np.vstack([self._of(q)[2] for q in solids]) if solids else np.zeros((0, 3))

    def _positions(self, mesh: trimesh.Trimesh) -> np.ndarray:
        return nozzle_positions(mesh, self.settings.access_samples, self.settings.seed)

    def printable(self, mesh: trimesh.Trimesh, plane: Plane, ancestors: list[manifold3d.Manifold],
                  others: dict[int, Piece]) -> bool:
        """A new part (``mesh`` printed from ``plane``) is clear of its ``ancestors`` (printed before it in
        any order) and can take a place among the unrelated ``others``: each of them that blocks it
        (with the ancestors) must be printable after it, with the parts standing on it, clear of the
        new part, and the rest must leave it clear."""
        if self.cell is None:
            return True
        at = self._positions(mesh)
        first = turn_hits(self.cell, at, plane.normal, plane.offset, self.points(ancestors))
        if first.all(axis=1).any():
            return False
        if not others or not (first | turn_hits(self.cell, at, plane.normal, plane.offset,
                                                self.points([q.solid for q in others.values()]))).all(axis=1).any():
            return True
        per = {i: turn_hits(self.cell, at, plane.normal, plane.offset, self.points([q.solid])) for i, q in others.items()}
        blockers = [i for i, h in per.items() if (first | h).all(axis=1).any()]
        rest = np.logical_or.reduce([first, *(h for i, h in per.items() if i not in blockers)])
        if rest.all(axis=1).any():
            return False  # unrelated parts that block it only together: not resolved by an order
        if blockers:
            mine = material_points(mesh, self.settings.access_spacing, self.settings.seed)
            for r in (others[k] for k in _descendants(others, blockers)):
                if turn_hits(self.cell, self._positions(self._of(r.solid)[1]), r.base.normal, r.base.offset,
                             mine).all(axis=1).any():
                    return False
        return True


def thick_enough(vertices: np.ndarray, plane: Plane, s: Settings) -> bool:
    """The part (its ``vertices``) rises ``min_part_layers`` layers over its base ``plane``."""
    return float((np.asarray(vertices) @ plane.normal).max()) - plane.offset >= s.min_part_layers * s.layer_height


def _vertices(solid: manifold3d.Manifold) -> np.ndarray:
    return np.asarray(solid.to_mesh().vert_properties)[:, :3]


def part_risk(piece: Piece, alpha_max: float) -> float:
    return risky_area(to_trimesh(piece.solid), piece.base, alpha_max)


def _subtree(seq: Sequence, j: int) -> set[int]:
    out, stack = set(), [j]
    while stack:
        i = stack.pop()
        out.add(i)
        stack.extend(c for c, p in seq.parent.items() if p == i)
    return out


def _perturbed(plane: Plane, centre: np.ndarray, diag: float, s: Settings, rng: np.random.Generator) -> list[Plane]:
    out = [plane]
    R = plane_frame(plane.normal, centre)[:3, :3]
    for _ in range(s.perturbations):
        tilt, turn = s.max_tilt * np.sqrt(rng.random()), 2 * np.pi * rng.random()
        n = R @ np.array([np.sin(tilt) * np.cos(turn), np.sin(tilt) * np.sin(turn), np.cos(tilt)])
        shift = (2 * rng.random() - 1) * s.max_offset_fraction * diag
        out.append(Plane(n, float(n @ centre + shift)))
    return out


def coarse_parts(solid: manifold3d.Manifold, coarse: CoarseDecomposition, seq: Sequence, s: Settings
                 ) -> tuple[dict[int, Piece], list[Cut]]:
    """Cut the coarse parts in sequence order, each separating plane perturbed (§2.4.3)."""
    mesh, labels = coarse.mesh, coarse.labels
    rng = np.random.default_rng(s.seed)
    diag = float(np.linalg.norm(mesh.extents))
    tol = 2.0 * float(mesh.edges_unique_length.mean())
    centres = mesh.triangles_center
    root_base = lowest_plane(mesh.vertices, seq.root_direction)
    pieces = {seq.root: Piece(solid, root_base, None, cross_section(solid, root_base, PLATFORM_CONTACT_MM))}
    table = s.clearance()
    access = Access(s)
    owner = {p: seq.root for p in range(len(coarse.areas))}
    cuts: list[Cut] = []
    for j in seq.order[1:]:
        if j not in seq.planes:
            continue  # its separating plane faces down (Constraint II): not cut
        holder = owner[j]
        sub = _subtree(seq, j)
        inside = np.isin(labels, list(sub))
        mine, others = cKDTree(centres[inside]), cKDTree(centres[~inside])
        boundary = mesh.vertices[np.unique(mesh.face_adjacency_edges[
            (labels[mesh.face_adjacency[:, 0]] == j) ^ (labels[mesh.face_adjacency[:, 1]] == j)])]
        options = []
        ref_area = None
        for plane in _perturbed(seq.planes[j], boundary.mean(axis=0), diag, s, rng):
            if not faces_up(plane.normal, seq.root_direction):
                continue
            below, above = split(pieces[holder].solid, plane)
            keep, rest = [], []
            for comp in above:
                v = np.asarray(comp.to_mesh().vert_properties)[:, :3]
                hits = len(mine.query_ball_point(v, tol, return_length=True).nonzero()[0])
                miss = len(others.query_ball_point(v, tol, return_length=True).nonzero()[0])
                (keep if hits > miss else rest).append(comp)
            if not keep:
                continue
            kept = union(keep)
            km = to_trimesh(kept)
            if not clears_platform(km.vertices, plane.normal, seq.root_direction, root_base.offset, table):
                continue
            cap = float(km.area_faces[base_face_mask(km, plane)].sum())
            ref_area = cap if ref_area is None else ref_area
            if cap > (1 + s.max_section_growth) * ref_area or not thick_enough(km.vertices, plane, s):
                continue
            left = union([below, *rest])
            score = part_risk(Piece(left, pieces[holder].base, pieces[holder].parent), s.alpha_max) \
                + risky_area(km, plane, s.alpha_max)
            options.append((score, len(options), plane, kept, km, left, keep, rest))
        # the least risky plane whose part the extruder can print: the holder's rest and its
        # ancestors are printed before it, the other parts cut so far are unrelated
        anc = _ancestors(pieces, holder)
        others = {i: q for i, q in pieces.items() if i != holder and i not in anc}
        best = next((o for o in sorted(options, key=lambda o: o[:2])  # the holder's rest: below the plane but `rest`
                     if access.printable(o[4], o[2], [*o[7], *(pieces[i].solid for i in anc)], others)), None)
        if best is None:
            continue  # the plane does not separate this patch: it stays in its holder
        _, _, plane, kept, _, left, keep, rest = best
        pieces[holder].solid = left
        pieces[j] = Piece(kept, plane, holder, cross_section(kept, plane))
        for p in sub:
            owner[p] = j
        cuts.append(Cut(holder, j, plane, np.array([centroid(c) for c in keep]),
                        np.array([centroid(c) for c in rest]).reshape(-1, 3)))
    return pieces, cuts


def _base_area(solid: manifold3d.Manifold, base: Plane, platform: bool) -> float:
    mesh = to_trimesh(solid)
    return float(mesh.area_faces[base_face_mask(mesh, base, platform)].sum())


def merge_regions(pieces: dict[int, Piece], cuts: list[Cut], order: list[int], s: Settings) -> list[Cut]:
    """Region merging (§2.4.3): fold a child into its parent when that is no riskier."""
    table = s.clearance()
    root = next(q for q in pieces.values() if q.parent is None)
    for j in reversed(order):
        if j not in pieces or pieces[j].parent is None:
            continue
        p = pieces[j].parent
        merged = union([pieces[p].solid, pieces[j].solid])
        if len(merged.decompose()) != 1 or not clears_platform(_vertices(merged), pieces[p].base.normal,
                                                                root.base.normal, root.base.offset, table):
            continue
        cand = Piece(merged, pieces[p].base, pieces[p].parent, pieces[p].section)
        if part_risk(cand, s.alpha_max) <= part_risk(pieces[p], s.alpha_max) + part_risk(pieces[j], s.alpha_max) + 1e-6:
            pieces[p] = cand
            del pieces[j]
            for q in pieces.values():
                if q.parent == j:
                    q.parent = p
            cuts = [c if c.holder != j else Cut(p, c.new, c.plane, c.keep, c.rest) for c in cuts if c.new != j]
    return cuts


def rank_cuts(piece: Piece, root_direction: np.ndarray, s: Settings) -> list[tuple[float, Plane]]:
    """Eq. 2.2 on surface samples: (estimated risky area removed, plane), best first."""
    mesh = to_trimesh(piece.solid)
    pts, face = trimesh.sample.sample_surface(mesh, s.samples, seed=s.seed)
    n = mesh.face_normals[face]
    w = mesh.area / s.samples
    d = piece.base.normal
    lower_risk = w * risky_faces(mesh, piece.base, s.alpha_max)[face]
    K = fibonacci_sphere(s.normals, hemisphere=True) @ plane_frame(d, np.zeros(3))[:3, :3].T
    K = K[[faces_up(k, root_direction) for k in K]]
    if len(K) == 0:
        return []
    H = pts @ K.T  # (N, K)
    lo = H.min(axis=0)
    bins = np.floor((H - lo) / s.offset_step).astype(np.int64)
    nb = int(bins.max()) + 1
    flat = bins + nb * np.arange(len(K))
    upper_risk = w * (n @ K.T + np.sin(s.alpha_max) < 0)  # (N, K): risky if printed along K
    low = np.bincount(flat.ravel(), weights=np.repeat(lower_risk[:, None], len(K), 1).ravel(),
                      minlength=nb * len(K)).reshape(len(K), nb)
    up = np.bincount(flat.ravel(), weights=upper_risk.ravel(), minlength=nb * len(K)).reshape(len(K), nb)
    r_s = np.cumsum(low, axis=1)[:, :-1]  # offsets lo + step·(l + 1), l < nb - 1
    r_t = (up.sum(axis=1, keepdims=True) - np.cumsum(up, axis=1))[:, :-1]
    gain = lower_risk.sum() - (r_s + r_t)
    if gain.shape[1] == 0:
        return []
    # planes cutting through the base face would leave part of the base above them
    base_v = mesh.vertices[mesh.faces[base_face_mask(mesh, piece.base, piece.parent is None)].ravel()]
    if len(base_v):
        top_base = (base_v @ K.T).max(axis=0)
        offsets = lo[:, None] + s.offset_step * (np.arange(nb - 1) + 1)[None, :]
        gain = np.where(offsets > top_base[:, None], gain, -np.inf)
    # a few offsets per normal keep the candidates diverse (neighbouring planes fail together)
    top_l = np.argsort(-gain, axis=1)[:, :s.offsets_per_normal]
    top = np.take_along_axis(gain, top_l, axis=1)
    out = [(float(top[k, m]), Plane(K[k], float(lo[k] + s.offset_step * (top_l[k, m] + 1))))
           for k in range(len(K)) for m in range(top_l.shape[1]) if top[k, m] > 0]
    return sorted(out, key=lambda c: -c[0])


def fine_decomposition(pieces: dict[int, Piece], cuts: list[Cut], root_direction: np.ndarray, total_volume: float,
                       s: Settings) -> list[Cut]:
    """Greedy refinement by optimal cutting planes (Eq. 2.2) under Constraints I and II, the platform
    clearance, the least part thickness and accessibility (module docstring)."""
    known: dict[int, tuple[manifold3d.Manifold, float]] = {}
    # parts with no valid plane stay so while their solid is unchanged: a new part only adds a base
    # section for Constraint I to keep apart from (the bunny's root, unimprovable, was re-searched every round)
    stuck: dict[int, manifold3d.Manifold] = {}
    table = s.clearance()
    access = Access(s)
    platform = next(q for q in pieces.values() if q.parent is None).base.offset
    while len(pieces) < s.max_parts:
        for i, p in pieces.items():
            if i not in known or known[i][0] is not p.solid:
                known[i] = (p.solid, part_risk(p, s.alpha_max))
        risk = {i: known[i][1] for i in pieces}
        queue = sorted((i for i in risk if risk[i] > s.risky_tolerance), key=lambda i: -risk[i])[: s.top_k]
        best = None
        for g in queue:
            if stuck.get(g) is pieces[g].solid:
                continue
            piece = pieces[g]
            base_area = 0.99 * _base_area(piece.solid, piece.base, piece.parent is None)
            valid = []  # the extruder test, the costliest, only on the best of each batch of valid planes
            for _, plane in rank_cuts(piece, root_direction, s)[: s.exact_candidates]:
                below, above = split(piece.solid, plane)
                if len(below.decompose()) != 1 or not above:
                    continue
                top = union(above)
                if top.volume() < s.min_part_volume_fraction * total_volume or _base_area(below, piece.base, piece.parent is None) < base_area:
                    continue
                top_v = _vertices(top)
                if not (clears_platform(top_v, plane.normal, root_direction, platform, table)
                        and thick_enough(top_v, plane, s) and thick_enough(_vertices(below), piece.base, s)):
                    continue
                top_mesh = to_trimesh(top)
                gain = risk[g] - part_risk(Piece(below, piece.base, piece.parent), s.alpha_max) \
                    - risky_area(top_mesh, plane, s.alpha_max)
                if gain <= 1e-6:
                    continue
                section = cross_section(top, plane)
                if any(sections_intersect(plane, section, q.base, q.section) for i, q in pieces.items() if i != g) \
                        or sections_intersect(plane, section, piece.base, piece.section):
                    continue
                valid.append((gain, g, plane, below, top, above, section, top_mesh))
                if len(valid) == s.valid_candidates:
                    best = _best_printable(valid, pieces, access)
                    if best is not None:
                        break
                    valid = []
            if best is None and valid:
                best = _best_printable(valid, pieces, access)
            if best is not None:
                break  # the riskiest part that can be improved is refined first
            stuck[g] = piece.solid
        if best is None:
            break
        _, g, plane, below, top, above, section, _ = best
        new = max(pieces) + 1
        for i in _moved_children(pieces, g, plane):  # children standing on the cut-off top now stand on the new part
            pieces[i].parent = new
        pieces[g].solid = below
        pieces[new] = Piece(top, plane, g, section)
        cuts.append(Cut(g, new, plane, np.array([centroid(c) for c in above]), np.zeros((0, 3))))
    return cuts


def _best_printable(valid: list[tuple], pieces: dict[int, Piece], access: Access) -> tuple | None:
    """The valid cut of largest gain whose new part the extruder can print: the holder's ancestors are
    printed before it (the holder's rest lies under the plane), the parts standing on it after it,
    the others in an order the extruder allows (:meth:`Access.printable`)."""
    for c in sorted(valid, key=lambda c: -c[0]):
        _, g, plane, *_, top_mesh = c
        anc = _ancestors(pieces, g)
        after = _descendants(pieces, _moved_children(pieces, g, plane))
        if access.printable(top_mesh, plane, [pieces[i].solid for i in anc],
                            {i: q for i, q in pieces.items() if i != g and i not in anc | after}):
            return c
    return None


def _moved_children(pieces: dict[int, Piece], g: int, plane: Plane) -> list[int]:
    """The children of ``g`` standing on the part its cut by ``plane`` takes off (their section above it)."""
    out = []
    for i, q in pieces.items():
        if q.parent == g and q.section.area > 0:
            c = q.base.frame() @ np.r_[np.asarray(q.section.representative_point().coords[0]), 0.0, 1.0]
            if plane.normal @ c[:3] > plane.offset:
                out.append(i)
    return out


def _ancestors(pieces: dict[int, Piece], i: int) -> set[int]:
    out = set()
    while pieces[i].parent is not None:
        i = pieces[i].parent
        out.add(i)
    return out


def _descendants(pieces: dict[int, Piece], roots: list[int]) -> set[int]:
    out, stack = set(), list(roots)
    while stack:
        i = stack.pop()
        out.add(i)
        stack.extend(k for k, q in pieces.items() if q.parent == i)
    return out


def replay(solid: manifold3d.Manifold, root: int, cuts: list[Cut]) -> dict[int, manifold3d.Manifold]:
    """Apply the recorded cuts to another (full-resolution) solid of the same model."""
    out = {root: solid}
    for c in cuts:
        below, above = split(out[c.holder], c.plane)
        refs = np.vstack([c.keep, c.rest])
        keep, rest = [], [below]
        for comp in above:
            nearest = int(np.argmin(np.linalg.norm(refs - centroid(comp), axis=1)))
            (keep if nearest < len(c.keep) else rest).append(comp)
        if not keep:
            raise ValueError(f"replaying cut {c.holder}->{c.new}: no piece above the plane matches the analysis")
        out[c.new] = union(keep)
        out[c.holder] = union(rest)
    return out
