"""The growing field G: convex-front advancing (thesis §3.4.2-3.4.4, Algorithms 1, 3 and 5).

Three methods, selectable by name:

* ``gcfa``        Algorithm 1, greedy convex-front advancing;
* ``sp-gcfa``     Algorithm 1 + shadow prevention by recursive PCA refinement (Algorithm 3);
* ``pg-sp-gcfa``  Algorithm 5, growth governed by the inverse peeling field F̄ with threshold
  steps Δf, plus the shadow prevention of Algorithm 3.

Layer τ = 1 holds the voxels on the platform (row k = 0). A voxel enters layer τ+1 when it is an
AM-stable neighbour (Definition 1, 18-neighbourhood) of a deposited voxel and NOT inside the
current convex front C_τ = C(layers ≤ τ ∪ T) (Definition 3, ε); G = layer index, 0 = missed.

Implementation notes (choices the pseudo-code leaves open, each keeping the constraints):

* Candidates are the unprocessed neighbours of *all* deposited voxels, not only of the last layer
  L_c. This is what Algorithm 5 needs to continue after ``f_τ`` is raised (its L_c is empty
  then), and it lets a voxel that shadow prevention held back be reconsidered for a later layer.
  For ``gcfa`` it gives exactly Algorithm 1's layers (a neighbour of an older layer that was not
  taken was inside a front, and fronts only grow).
* Refinement (Algorithm 3) adds a subset to L̃ only when it is shadow-free and drops a single
  voxel that still creates shadows (the printed pseudo-code's last line is meant as the
  'else' branch). Tests are against C(C_c ∪ T ∪ L̃ ∪ L_sub) with L̃ growing as subsets are accepted.
  A failing subset is first split into the voxels that can cause its shadows and the rest
  (provably shadow-free, see :func:`_split`), then by PCA halves.
* Shadow tests look only where the front can grow (``convex_front.newly_inside``): a voxel not
  inside C can only enter C' = C(C ∪ S) beyond a facet of C that S removes.
* "Unprocessed" voxels counted as shadowed include the rest of L_next, so a voxel held back is
  still reachable later.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from curvslice.convex_front import GROW_EPS, Hull, grow, hull_of, inside, newly_inside
from curvslice.errors import CurvsliceError
from curvslice.voxelize import VoxelGrid

METHODS = ("gcfa", "sp-gcfa", "pg-sp-gcfa")

#: Index offsets of the 18 AM-stable neighbours (Definition 1: L1 distance 1 or 2, no corners).
ASN_OFFSETS = np.array(
    [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if 1 <= abs(i) + abs(j) + abs(k) <= 2]
)


@dataclass
class GrowthStats:
    """Counters of one growth run, reported in ``report.json``."""

    layers: int = 0
    missed: int = 0
    shadow_tests: int = 0
    shadow_fallbacks: int = 0
    held_back: int = 0
    threshold_steps: int = 0
    layer_sizes: list[int] = field(default_factory=list)


def asn_table(occupied: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Occupied voxel indices (n,3) and their AM-stable neighbours (n,18) as voxel numbers, -1 = none."""
    ijk = np.argwhere(occupied)
    lut = np.full(np.array(occupied.shape) + 2, -1, dtype=np.int64)
    lut[ijk[:, 0] + 1, ijk[:, 1] + 1, ijk[:, 2] + 1] = np.arange(len(ijk))
    nb = ijk[:, None, :] + 1 + ASN_OFFSETS[None, :, :]
    return ijk, lut[nb[..., 0], nb[..., 1], nb[..., 2]]


class _Front:
    """Mutable state of one growth run: the front, the deposited/alive sets and the frontier."""

    def __init__(self, grid: VoxelGrid, platform_vertices: np.ndarray, eps: float):
        self.ijk, self.nbr = asn_table(grid.occupied)
        self.pts = grid.centres(self.ijk)
        self.eps = eps * grid.voxel_size
        n = len(self.ijk)
        self.layer = np.zeros(n, dtype=np.int32)
        self.frontier = np.zeros(n, bool)
        self.hull: Hull | None = None
        self.platform = np.asarray(platform_vertices, float)
        # alive = unprocessed and not inside the current front
        self.alive = np.ones(n, bool)
        self.stats = GrowthStats()

    def deposit(self, ids: np.ndarray, hull: Hull | None = None) -> None:
        """Add ``ids`` as the next layer and advance the front; a ``hull`` given is the front
        already checked shadow-free, otherwise the voxels the new front swallows are retired."""
        tau = self.stats.layers + 1
        self.layer[ids] = tau
        self.alive[ids] = False
        self.frontier[ids] = False
        nb = self.nbr[ids].ravel()
        nb = nb[nb >= 0]
        self.frontier[nb[self.layer[nb] == 0]] = True
        new_pts = self.pts[ids]
        old = self.hull
        if hull is not None:
            self.hull = hull
        else:
            self.hull = grow(old if old is not None else hull_of(self.platform), new_pts)
            alive = np.flatnonzero(self.alive)
            if old is None:
                swallowed = alive[inside(self.hull, self.pts[alive], self.eps)]
            else:
                swallowed = alive[newly_inside(old, self.hull, new_pts, self.pts[alive], self.eps)]
            self.alive[swallowed] = False
        self.stats.layers = tau
        self.stats.layer_sizes.append(int(len(ids)))

    def candidates(self) -> np.ndarray:
        """Unprocessed AM-stable neighbours of deposited voxels that are not inside the front."""
        return np.flatnonzero(self.frontier & self.alive)

    def shadow_free_subset(self, next_ids: np.ndarray) -> tuple[np.ndarray, Hull | None]:
        """Algorithm 3: L_next itself if it creates no shadow, else the union L̃ of shadow-free
        subsets found by recursive PCA splitting (empty if none).

        Only voxels shadowed by the whole of L_next (S_p) need re-testing for a subset, since
        C_t = C(C_c ∪ T ∪ L̃ ∪ L_sub) ⊂ C_p (§3.4.3)."""
        assert self.hull is not None
        self.stats.shadow_tests += 1
        new_pts = self.pts[next_ids]
        full = grow(self.hull, new_pts)
        alive = np.flatnonzero(self.alive)
        s_p = alive[newly_inside(self.hull, full, new_pts, self.pts[alive], self.eps)]
        if len(np.setdiff1d(s_p, next_ids, assume_unique=True)) == 0:
            return next_ids, full
        accepted: list[np.ndarray] = []
        acc_hull = self.hull
        pending = np.ones(len(s_p), bool)  # S_p voxels not yet part of L̃
        stack = [next_ids]
        while stack:
            sub = stack.pop()
            self.stats.shadow_tests += 1
            test = grow(acc_hull, self.pts[sub])
            in_sub = np.isin(s_p, sub)
            watch = s_p[pending & ~in_sub]
            hit = inside(test, self.pts[watch], self.eps)
            if not hit.any():
                accepted.append(sub)
                acc_hull = test
                pending &= ~in_sub
            elif len(sub) > 1:
                stack.extend(_split(self.pts, sub, self.pts[watch[hit]], acc_hull, self.eps)[::-1])
        if not accepted:
            return np.zeros(0, dtype=np.int64), None
        chosen = np.concatenate(accepted)
        self.stats.held_back += len(next_ids) - len(chosen)
        return chosen, acc_hull


def _split(pts: np.ndarray, ids: np.ndarray, shadowed: np.ndarray, front: Hull, eps: float) -> list[np.ndarray]:
    """Split a subset that creates shadows into parts tested in order (Algorithm 3, line 6).

    A shadowed voxel s can only enter C(front ∪ S) if some voxel of S lies above a plane of the
    front that s is beyond (or within ε of); the voxels above none of those planes ("rest") are
    therefore shadow-free and go first, the others ("culprits") are split further. When that
    separates nothing, split in halves along the longest principal axis (PCA) as in §3.4.3.
    """
    beyond = (shadowed @ front.normals.T + front.offsets > -eps).any(axis=0)
    culprit = (pts[ids] @ front.normals[beyond].T + front.offsets[beyond] > 0).any(axis=1)
    if culprit.any() and not culprit.all():
        return [ids[~culprit], ids[culprit]]
    x = pts[ids] - pts[ids].mean(axis=0)
    _, vecs = np.linalg.eigh(x.T @ x)
    order = np.argsort(x @ vecs[:, -1], kind="stable")
    half = len(ids) // 2
    return [ids[order[:half]], ids[order[half:]]]


def growing_field(grid: VoxelGrid, platform_vertices: np.ndarray, method: str = "pg-sp-gcfa",
                  peeling: np.ndarray | None = None, delta_f: int = 1, eps: float = GROW_EPS,
                  progress=None) -> tuple[np.ndarray, GrowthStats]:
    """Compute the growing field G (int32 grid, layer index from 1, 0 = empty or missed).

    ``method`` is one of :data:`METHODS`; ``pg-sp-gcfa`` needs the inverse peeling field
    ``peeling`` (F̄, from :func:`curvslice.peeling_field.peeling_field`) and ``delta_f`` (Δf ≥ 1).
    ``eps`` is ε in voxel widths. ``progress`` is an optional tqdm-like object updated with the
    number of voxels deposited.
    """
    if method not in METHODS:
        raise CurvsliceError(f"unknown growing method {method!r}; choose one of {', '.join(METHODS)}")
    governed = method == "pg-sp-gcfa"
    prevent = method != "gcfa"
    if governed:
        if peeling is None:
            raise CurvsliceError("pg-sp-gcfa needs the peeling field")
        if delta_f < 1:
            raise CurvsliceError(f"--delta-f must be a positive integer, got {delta_f}")
    front = _Front(grid, platform_vertices, eps)
    fbar = peeling[tuple(front.ijk.T)] if governed else None
    f_max = int(fbar.max()) if governed else 0
    f_tau = delta_f

    base = np.flatnonzero(front.ijk[:, 2] == 0)  # voxels on the platform top (Algorithm 1 line 1)
    if len(base) == 0:
        raise CurvsliceError("no voxel touches the platform; is the model placed on z = 0?")
    front.deposit(base)
    if progress is not None:
        progress.update(len(base))
    while True:
        cand = front.candidates()
        if governed:
            cand = cand[fbar[cand] <= f_tau]
            if len(cand) == 0:
                if f_tau > f_max or not front.candidates().size:
                    break
                f_tau += delta_f
                front.stats.threshold_steps += 1
                continue
        elif len(cand) == 0:
            break
        hull = None
        if prevent:
            chosen, hull = front.shadow_free_subset(cand)
            if len(chosen) == 0:  # Algorithm 3 line 11: accept the shadows, keep advancing
                front.stats.shadow_fallbacks += 1
                chosen, hull = cand, None
            cand = chosen
        front.deposit(cand, hull)
        if progress is not None:
            progress.update(len(cand))
    out = np.zeros(grid.shape, dtype=np.int32)
    out[tuple(front.ijk.T)] = front.layer
    front.stats.missed = int((front.layer == 0).sum())
    return out, front.stats
