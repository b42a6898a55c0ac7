"""Pose-continuous motion of a print (§3.5.3, §4.3.1, Fig. 3.11b): per layer, the shortest path
through the ladder graph (:mod:`curvslice.ladder`), unwinding of the circular joints, timestamps,
and the joint trajectory of the whole print with its report figures.

Where no node of a rung is reachable the motion splits there and a new one starts (Fig. 3.11b);
when a layer needs splits, p is doubled and the search repeated while that removes splits (§4.3.1).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from curvslice.kinematics import Robot
from curvslice.ladder import (TWO_PI, LadderPath, RungMemo, blocked_rungs, circular_joints, deviate_axes, held_frames,
                              hopeless_rungs, joint_steps, ladder, ladder_at, shortest_path)
from curvslice.orientation import angles_between, smooth_along_paths
from curvslice.workcell import Workcell, rotation_samples


@dataclass
class Motion:
    """Joint trajectory of one sequence of waypoints (one layer)."""

    q: np.ndarray  # (m, 6) rad, unwound joint values; NaN rows for skipped waypoints
    t: np.ndarray  # (m,) s from the first waypoint; NaN for skipped waypoints
    segment: np.ndarray  # (m,) int, a new value starts a new smooth motion; -1 if skipped
    rotations: int  # p finally used
    solutions: np.ndarray  # (m,) int, IK solutions per waypoint within the joint limits (-1: not laddered)
    splits: list[int]  # waypoint indices where the graph disconnects (new motion, Fig. 3.11b)
    winding_splits: list[int]  # waypoint indices where a joint would leave its range by winding
    cost: float  # Eq. 3.4 (or 4.6) summed over the segments
    collision_checks: int


def step_times(
    positions: np.ndarray,
    speed: np.ndarray | float,
    min_step: float,
    normals: np.ndarray | None = None,
    turn_speed: float = 0.0,
) -> np.ndarray:
    """Δt_j = ‖c_{j+1} − c_j‖ / v̄_j (§3.5.3), at least ∠(t_j, t_{j+1}) / ω̄ when a tool turn speed
    ω̄ > 0 and the orientations are given, and at least ``min_step`` seconds; (m-1,)."""
    dist = np.linalg.norm(np.diff(np.asarray(positions, float), axis=0), axis=1)
    dt = dist / np.broadcast_to(np.asarray(speed, float), dist.shape)
    if normals is not None and turn_speed > 0:
        n = np.asarray(normals, float)
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        turn = np.arccos(np.clip(np.einsum("ij,ij->i", n[1:], n[:-1]), -1.0, 1.0))
        dt = np.maximum(dt, turn / turn_speed)
    return np.maximum(dt, min_step)


def unwind(q: np.ndarray, segment: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """Actual joint values along a path: circular joints follow their shortest turns and are shifted
    by whole revolutions to stay inside their limits; where a segment would wind beyond a joint's
    range it is split. Returns the unwound q (NaN where segment < 0) and the added split indices."""
    out = np.full_like(q, np.nan)
    circ = circular_joints(lower, upper)
    splits: list[int] = []
    rows = np.flatnonzero(segment >= 0)
    if len(rows) == 0:
        return out, splits
    bounds = np.flatnonzero(np.r_[True, segment[rows][1:] != segment[rows][:-1]])
    pieces = [rows[b:e] for b, e in zip(bounds, np.r_[bounds[1:], len(rows)])]
    centre = (lower + upper) / 2
    while pieces:
        idx = pieces.pop(0)
        step = np.diff(q[idx], axis=0)
        step[:, circ] = (step[:, circ] + np.pi) % TWO_PI - np.pi
        path = q[idx[0]] + np.vstack([np.zeros(6), np.cumsum(step, axis=0)])
        # whole turns k that keep every prefix of the piece inside the limits; none left: split
        lo_k = np.ceil((lower - np.minimum.accumulate(path, axis=0)) / TWO_PI)
        hi_k = np.floor((upper - np.maximum.accumulate(path, axis=0)) / TWO_PI)
        over = ((lo_k > hi_k) & circ).any(axis=1)
        if over.any():
            cut = int(np.argmax(over))
            splits.append(int(idx[cut]))
            pieces.insert(0, idx[cut:])
            idx, path, lo_k, hi_k = idx[:cut], path[:cut], lo_k[:cut], hi_k[:cut]
        want = np.round((centre - path.mean(axis=0)) / TWO_PI)
        k = np.where(circ, np.clip(want, lo_k[-1], hi_k[-1]), 0.0)
        out[idx] = path + TWO_PI * k
    return out, sorted(splits)


#: rungs before a split whose rotation sampling is refined with it (§4.3.1)
REFINE_WINDOW = 8
#: the smallest p a ladder starts from before halving stops (Eq. 4.3)
MIN_START_ROTATIONS = 8


def start_rotations(rotations: int) -> int:
    """p a ladder starts from: ``rotations`` halved while it stays even and ≥ MIN_START_ROTATIONS, so
    that doubling it per rung reaches ``rotations`` again (30 -> 15)."""
    p = int(rotations)
    while p % 2 == 0 and p // 2 >= MIN_START_ROTATIONS:
        p //= 2
    return p


def finest_rotations(cell: Workcell, max_rotations: int | None = None) -> int:
    """The largest p the doubling of :func:`_search` reaches: :func:`start_rotations` of
    ``cell.rotations`` doubled while within ``max_rotations`` (default 4 × ``cell.rotations``)."""
    limit = max_rotations or 4 * cell.rotations
    p = start_rotations(cell.rotations)
    while p * 2 <= limit:
        p *= 2
    return p


@dataclass
class _Found:
    """One ladder search (:func:`_search`): per rung the chosen node (-1: none), its motion id, its
    joints (NaN: none), rotation θ and IK branch; p used, IK solutions per rung, nodes checked."""

    node: np.ndarray
    segment: np.ndarray
    q: np.ndarray
    theta: np.ndarray
    branch: np.ndarray
    rotations: int
    solutions: np.ndarray
    checks: int


def _search(
    robot: Robot,
    cell: Workcell,
    positions: np.ndarray,
    normals: np.ndarray,
    dt: np.ndarray,
    collides: Callable[[np.ndarray], np.ndarray] | None,
    cost: str,
    weights: np.ndarray | None,
    max_rotations: int | None,
    dense: np.ndarray | None,
    ends: tuple[np.ndarray | None, np.ndarray | None] = (None, None),
    memo: RungMemo | None = None,
) -> _Found:
    """The ladder search of :func:`plan_motion` on every rung (p doubling on the breaks' rungs,
    lazy collision checks). ``ends``: joints the first / last rung is pinned to (a single node,
    known collision-free), e.g. where a stretch meets an already planned path; with both pinned the
    ladder starts at twice the usual p, and the nodes outside :func:`reach_cone` are left out first
    (the whole ladder only where that breaks). ``memo``: IK nodes of rungs asked before
    (:class:`curvslice.ladder.RungMemo`)."""
    rungs = ladder if memo is None else (lambda *a: memo.ladder(*a))
    m = len(positions)
    lo, hi = cell.limits(robot)
    circ = circular_joints(lo, hi)
    limit = max_rotations or 4 * cell.rotations
    pinned = m > 1 and ends[0] is not None and ends[1] is not None
    p = start_rotations(cell.rotations)
    if pinned and 2 * p <= limit:
        p *= 2  # between two pinned nodes (a stretch the coarse path's θ interpolation failed on) p rarely connects
    finest = finest_rotations(cell, max_rotations)
    level = np.full(m, p)  # p of each rung
    q, solved = rungs(robot, cell, positions, normals, p)
    solved_at = np.full(m, p)  # p of the IK solutions held for each rung
    known = np.zeros((m, 8 * p), np.int8)  # collision answers: 0 unknown, 1 free, -1 colliding
    fixed = np.zeros(m, bool)
    dead = blocked_rungs(collides, positions, normals)  # no θ at any p: never refined, not a break
    solved[dead] = False
    for row, pin in zip((0, m - 1), ends):
        if pin is not None:  # node 0 (θ sample 0, branch 0) stays node 0 when p doubles
            fixed[row], dead[row] = True, False
            q[row] = np.nan
            q[row, 0] = pin
            solved[row] = False
            solved[row, 0] = True
            known[row, 0] = 1
    asked_total = 0
    best, whole = None, False
    # rung i -> its edges to rung i+1 over every IK node of the ladder, whatever is known of collisions
    # (every lazy pass and p shares them), and the same over the nodes inside reach_cone
    edges: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    cone_edges: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    while True:
        redo = np.flatnonzero((solved_at < level) & ~fixed & ~dead)  # refined rungs: IK at the finer θ samples
        if len(redo):
            q[redo], solved[redo] = rungs(robot, cell, positions[redo], normals[redo], p)
            solved_at[redo] = p
        theta = np.arange(8 * p) // 8
        valid = solved & (theta[None, :] % (p // level)[:, None] == 0)

        def node_ok(r: np.ndarray, k: np.ndarray) -> np.ndarray:
            nonlocal asked_total
            ans = known[r, k]
            todo = np.flatnonzero(ans == 0)
            # on rungs with a colliding node already, first one test per nozzle frame (rung, θ): where
            # a static body meets the platform or part there, all 8 IK branches at that θ collide
            useful = getattr(collides, "held_useful", None)
            held = todo[(known[r[todo]] < 0).any(axis=1) & ~fixed[r[todo]]] \
                if len(todo) and useful is not None and useful() else todo[:0]
            if len(held):
                pairs, back = np.unique(r[held] * p + k[held] // 8, return_inverse=True)
                hit = held_frames(collides, positions[pairs // p], normals[pairs // p], rotation_samples(p)[pairs % p])
                for rung, s in zip(pairs[hit] // p, pairs[hit] % p):
                    known[rung, 8 * s:8 * s + 8] = -1
                ans[held[hit[back.ravel()]]] = -1
                todo = np.flatnonzero(ans == 0)
            if len(todo):
                ans[todo] = np.where(collides(q[r[todo], k[todo]]), -1, 1)
                known[r[todo], k[todo]] = ans[todo]
                asked_total += len(todo)
            return ans > 0

        branch = np.arange(8 * p) % 8  # IK branch of each node: collisions mostly follow the branch

        def run(nodes: np.ndarray, cache: dict) -> LadderPath:
            return shortest_path(q, nodes & (known >= 0), dt, cell.max_joint_speed, circ, cost, weights,
                                 None if collides is None else node_ok, branch, cache,
                                 None if memo is None else memo.edges, nodes)[0]

        path = None
        if pinned:  # first the nodes a motion from one pinned end to the other can pass (exact if it exists)
            path = run(valid & reach_cone(q, ends, dt, cell.max_joint_speed, circ), cone_edges)
            if (path.node < 0).any() or path.segment[-1] != 0:
                path = None
        if path is None:
            path = run(valid, edges)
        # breaks in the motion: disconnections between realized waypoints, and skipped waypoints
        # (a dead rung's skip and the split after it are no break a finer ladder could mend)
        rows = np.flatnonzero(path.node >= 0)
        cut = np.flatnonzero(np.diff(path.segment[rows]) != 0)
        passed = np.cumsum(dead)
        split_rows = rows[cut + 1][passed[rows[cut + 1]] == passed[rows[cut]]]
        skipped = (path.node < 0) & ~dead
        if skipped.any():  # skipped because every θ up to the finest p collides: dead too (no p can help)
            hopeless = np.flatnonzero(skipped)
            hopeless = hopeless[hopeless_rungs(collides, positions[hopeless], normals[hopeless], finest)]
            dead[hopeless], skipped[hopeless] = True, False
            passed = np.cumsum(dead)
            split_rows = rows[cut + 1][passed[rows[cut + 1]] == passed[rows[cut]]]
        breaks = len(split_rows) + int(skipped.sum())
        if best is None or breaks < best[0]:
            best = (breaks, int(level.max()), q.copy(), valid, path)
        elif not whole and (level < p).any():
            whole = True  # refining the breaks' rungs alone did not help: refine every rung at this p
            level[:] = p
            edges, cone_edges = {}, {}
            continue
        else:
            break  # a denser ladder did not help: the breaks come from the path itself (§4.3.1)
        if breaks == 0 or p * 2 > limit:
            break
        refine = skipped if dense is None else skipped | dense
        for r in split_rows:
            refine[max(r - REFINE_WINDOW, 0) : r + 1] = True
        # θ samples nest: the nodes of p are the even ones of 2p (same IK branch order)
        finer = np.full((m, 2 * p, 8, 6), np.nan)
        finer[:, ::2] = q.reshape(m, p, 8, 6)
        finer_ok = np.zeros((m, 2 * p, 8), bool)
        finer_ok[:, ::2] = solved.reshape(m, p, 8)
        finer_known = np.zeros((m, 2 * p, 8), np.int8)
        finer_known[:, ::2] = known.reshape(m, p, 8)
        p *= 2
        q, solved, known = finer.reshape(m, 8 * p, 6), finer_ok.reshape(m, 8 * p), finer_known.reshape(m, 8 * p)
        level[refine], whole = p, False
        # edges between two rungs that keep their nodes carry over, renumbered (node s·8+b -> 2s·8+b)
        edges, cone_edges = ({i: (2 * ia - ia % 8, 2 * ib - ib % 8, w) for i, (ia, ib, w) in cache.items()
                              if not (refine[i] or refine[i + 1])} for cache in (edges, cone_edges))
    _, p, q, valid, path = best
    rows = np.flatnonzero(path.node >= 0)
    chosen = np.full((m, 6), np.nan)
    chosen[rows] = q[rows, path.node[rows]]
    theta = -np.pi + TWO_PI * (path.node // 8) / (q.shape[1] // 8)  # rotation_samples of the held p
    return _Found(path.node, path.segment, chosen, theta, path.node % 8, p, valid.sum(axis=1), asked_total)


def reach_cone(q: np.ndarray, ends: tuple[np.ndarray, np.ndarray], dt: np.ndarray, max_speed: float,
               circular: np.ndarray) -> np.ndarray:
    """(m, K) bool: the nodes of a ladder q (m, K, 6) (NaN: absent) that a motion from the pinned
    first node ``ends[0]`` to the pinned last node ``ends[1]`` with every step ‖Δq‖∞ ≤ ξΔt (Eq. 4.4)
    could pass: within ξ·(time since the first rung) of the one and ξ·(time to the last rung) of the
    other (triangle inequality, circular joints the short way round; a hair wider for rounding)."""
    elapsed = np.r_[0.0, np.cumsum(dt)]
    ok = np.ones(q.shape[:2], bool)
    for pin, span in zip(ends, (elapsed, elapsed[-1] - elapsed)):
        d = np.abs(q - pin)
        d[..., circular] = np.minimum(d[..., circular], TWO_PI - d[..., circular])
        ok &= d.max(axis=-1) <= max_speed * span[:, None] * (1 + 1e-9) + 1e-9
    return ok


#: waypoints per coarse rung inside a tool-path in the coarse-to-fine search (:func:`plan_motion`)
COARSE_STEP = 8
#: times at most a full-search stretch that splits is searched again with its ends further out (while
#: that removes splits), and by how many kept rungs each time (its pinned nodes may cause the split)
WIDEN, WIDEN_STEP = 3, 2


def coarse_rungs(path_id: np.ndarray, step: int = COARSE_STEP) -> np.ndarray:
    """(m,) bool: the rungs of the coarse ladder: the first and last waypoint of every tool-path
    (jumps between paths stay single graph edges) and every ``step``-th waypoint inside a path."""
    path_id = np.asarray(path_id)
    m = len(path_id)
    first = np.r_[True, path_id[1:] != path_id[:-1]] if m else np.zeros(0, bool)
    last = np.r_[first[1:], True] if m else first
    begin = np.maximum.accumulate(np.where(first, np.arange(m), 0)) if m else np.zeros(0, int)
    return first | last | ((np.arange(m) - begin) % max(int(step), 1) == 0)


def plan_motion(
    robot: Robot,
    cell: Workcell,
    positions: np.ndarray,
    normals: np.ndarray,
    dt: np.ndarray,
    collides: Callable[[np.ndarray], np.ndarray] | None = None,
    cost: str = "l1",
    weights: np.ndarray | None = None,
    max_rotations: int | None = None,
    dense: np.ndarray | None = None,
    keep: np.ndarray | None = None,
    memo: RungMemo | None = None,
) -> Motion:
    """Joint trajectory for one waypoint sequence (a layer's tool-paths, in print order).

    ``dt`` (m-1,) are the step times; ``collides(q) -> bool`` marks poses in collision. Every rung
    starts with p = :func:`start_rotations` of ``cell.rotations``; while the motion has breaks (splits
    or skipped waypoints) p is doubled, up to ``max_rotations`` (default 4 × ``cell.rotations``), on
    the rungs of the breaks only (a skipped rung, and the ``REFINE_WINDOW`` rungs up to a split) and
    the search repeated while that removes breaks (§4.3.1); the ladder with the fewest breaks is kept.
    θ samples nest (those of p are every other one of 2p), so collision answers carry over. Rungs
    marked ``dense`` (m,) bool are refined with every break (e.g. those around a deviated tool axis).

    ``keep`` (m,) bool (e.g. :func:`coarse_rungs`): coarse-to-fine. The ladder search runs on the kept
    rungs (edges Eq. 4.4 over the summed Δt); between two kept rungs of one motion on one IK branch
    the waypoints take that branch at θ interpolated in time (one IK each), checked for ξ (Eq. 4.4)
    and collisions, else the same with a smooth bump of θ (:func:`_fill`), else a small ladder of θ
    about the interpolation (:func:`_band_fill`); a stretch where all that fails (or the coarse path
    breaks) gets the full ladder search between its two kept nodes (from 2p, inside their
    :func:`reach_cone` first). ``None``: the full ladder on every rung. ``memo``
    (:class:`curvslice.ladder.RungMemo`): IK nodes shared by the searches (same nodes, solved once).
    """
    positions = np.asarray(positions, float)
    normals = np.asarray(normals, float)
    search = _searcher(robot, cell, positions, normals, collides, cost, weights, max_rotations, dense, memo)
    chosen, link, solutions, p, checks = _links(robot, cell, positions, normals, np.asarray(dt), keep, collides, search)
    return _motion(robot, cell, chosen, link, solutions, p, checks, np.asarray(dt), cost, weights)


def _searcher(robot: Robot, cell: Workcell, positions: np.ndarray, normals: np.ndarray,
              collides: Callable[[np.ndarray], np.ndarray] | None, cost: str, weights: np.ndarray | None,
              max_rotations: int | None, dense: np.ndarray | None, memo: RungMemo | None) -> Callable[..., _Found]:
    """``search(rows, dt, ends)``: :func:`_search` on the waypoints ``rows`` (a slice or indices)."""

    def search(r: slice | np.ndarray, step: np.ndarray, ends=(None, None)) -> _Found:
        return _search(robot, cell, positions[r], normals[r], step, collides, cost, weights, max_rotations,
                       None if dense is None else dense[r], ends, memo)

    return search


def _links(robot: Robot, cell: Workcell, positions: np.ndarray, normals: np.ndarray, dt: np.ndarray,
           keep: np.ndarray | None, collides: Callable[[np.ndarray], np.ndarray] | None,
           search: Callable[..., _Found]) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """The search of :func:`plan_motion` before unwinding: joints (m, 6) (NaN: skipped), link (m,)
    (row j continues row j-1's motion), IK solutions per laddered rung (-1 elsewhere), p, checks."""
    m = len(positions)
    if keep is None or m < 3 or np.all(keep):
        found = search(slice(None), dt)
        link = np.r_[False, (found.segment[1:] == found.segment[:-1]) & (found.segment[1:] >= 0)]
        return found.q, link, found.solutions, found.rotations, found.checks
    lo, hi = cell.limits(robot)
    return _coarse_to_fine(robot, cell, positions, normals, dt, np.asarray(keep, bool), collides,
                           circular_joints(lo, hi), search)


def _motion(robot: Robot, cell: Workcell, chosen: np.ndarray, link: np.ndarray, solutions: np.ndarray, p: int,
            checks: int, dt: np.ndarray, cost: str, weights: np.ndarray | None) -> Motion:
    """The :class:`Motion` of a searched path (:func:`_links`): segments, unwinding, timestamps, cost."""
    m = len(chosen)
    lo, hi = cell.limits(robot)
    circ = circular_joints(lo, hi)
    present = ~np.isnan(chosen[:, 0])
    link = link & present & np.r_[False, present[:-1]]
    starts = present & ~link
    segment = np.where(present, np.cumsum(starts) - 1, -1)
    rows = np.flatnonzero(present)
    splits = [int(r) for r in rows[1:] if starts[r]]
    qa, winding = unwind(chosen, segment, lo, hi)
    for w in winding:
        segment[w:][segment[w:] >= 0] += 1
    times = _timestamps(qa, segment, dt, cell.max_joint_speed)
    inside = (segment[1:] == segment[:-1]) & (segment[1:] >= 0)  # Eq. 3.4 (4.6) inside the final motions
    total = float(joint_steps(chosen[:-1], chosen[1:], circ, cost, weights)[0][inside].sum()) if m > 1 else 0.0
    return Motion(qa, times, segment, p, solutions, splits, winding, total, checks)


def _coarse_to_fine(
    robot: Robot,
    cell: Workcell,
    positions: np.ndarray,
    normals: np.ndarray,
    dt: np.ndarray,
    keep: np.ndarray,
    collides: Callable[[np.ndarray], np.ndarray] | None,
    circ: np.ndarray,
    search: Callable[..., _Found],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """The coarse-to-fine search of :func:`plan_motion`: joints (m, 6) (NaN: skipped), link (m,)
    (row j continues row j-1's motion), IK solutions per laddered rung (-1 elsewhere), p, checks."""
    m = len(positions)
    keep = keep.copy()
    keep[[0, -1]] = True
    elapsed = np.r_[0.0, np.cumsum(dt)]
    idx = np.flatnonzero(keep)
    coarse = search(idx, np.add.reduceat(dt, idx[:-1]))  # Δt summed between kept rungs (one step: the same Δt)
    chosen = np.full((m, 6), np.nan)
    chosen[idx] = coarse.q
    link = np.zeros(m, bool)
    solutions = np.full(m, -1)
    solutions[idx] = coarse.solutions
    p, checks = coarse.rotations, coarse.checks
    on = np.flatnonzero(coarse.node >= 0)
    stretches: list[tuple[int, int, bool, bool]] = []  # rows a..b for the full search, pinned ends
    if len(on) == 0:
        stretches.append((0, m - 1, False, False))
    else:
        if idx[on[0]] > 0:
            stretches.append((0, int(idx[on[0]]), False, True))
        if idx[on[-1]] < m - 1:
            stretches.append((int(idx[on[-1]]), m - 1, True, False))
        ca, cb = on[:-1], on[1:]
        a, b = idx[ca], idx[cb]
        same = coarse.segment[ca] == coarse.segment[cb]
        adjacent = b == a + 1
        link[b[adjacent]] = same[adjacent]
        fill = np.flatnonzero(same & ~adjacent & (coarse.branch[ca] == coarse.branch[cb]))
        filled, asked = _fill(robot, cell, positions, normals, dt, elapsed, a[fill], b[fill],
                              coarse.theta[ca[fill]], coarse.theta[cb[fill]], coarse.branch[ca[fill]], collides, circ,
                              chosen, link)
        checks += asked
        rest = fill[~filled]
        banded, asked = _band_fill(robot, cell, positions, normals, dt, elapsed, a[rest], b[rest], coarse.theta[ca[rest]],
                                   coarse.theta[cb[rest]], coarse.branch[ca[rest]], collides, circ, chosen, link)
        checks += asked
        done = adjacent.copy()
        done[fill[filled]] = True
        done[rest[banded]] = True
        # gaps still open: the band about the whole turn, between kept rungs WIDEN_STEP further out
        # (the coarse node at a or b may be what blocks the gap)
        wa, wb = _band_windows(ca[rest[~banded]], cb[rest[~banded]], coarse, WIDEN_STEP)
        if len(wa):
            wide, asked = _band_fill(robot, cell, positions, normals, dt, elapsed, idx[wa], idx[wb], coarse.theta[wa],
                                     coarse.theta[wb], coarse.branch[wa], collides, circ, chosen, link, WIDE_BAND)
            checks += asked
            for x, y in zip(wa[wide], wb[wide]):
                done[(ca >= x) & (cb <= y)] = True
        stretches += [(int(x), int(y), True, True) for x, y in zip(a[~done], b[~done])]
    p_more, asked = _stretches(stretches, idx, dt, search, chosen, link, solutions)
    return chosen, link, solutions, max(p, p_more), checks + asked


def _stretches(stretches: list[tuple[int, int, bool, bool]], idx: np.ndarray, dt: np.ndarray,
               search: Callable[..., _Found], chosen: np.ndarray, link: np.ndarray,
               solutions: np.ndarray, widen: int = WIDEN) -> tuple[int, int]:
    """The full ladder search on each stretch (rows a..b, ends pinned to ``chosen`` where asked and
    present), written into ``chosen``, ``link`` and ``solutions``. A stretch that splits is searched
    again with its ends ``WIDEN_STEP`` rows of ``idx`` (sorted, with 0 and m-1) further out, at most
    ``widen`` times while that removes splits. Returns the largest p used and the checks made."""
    m = len(chosen)
    p, checks = 0, 0
    for x, y, pin_a, pin_b in sorted(stretches):
        best = None
        for wider in range(widen + 1):  # a stretch that splits: again with ends WIDEN_STEP kept rungs further out
            if wider:
                i, j = np.searchsorted(idx, x) - WIDEN_STEP, np.searchsorted(idx, y) + WIDEN_STEP
                x, y = int(idx[max(i, 0)]), int(idx[min(j, len(idx) - 1)])
                pin_a, pin_b = pin_a and i > 0, pin_b and j < len(idx) - 1
            ends = tuple(chosen[r] if pin and not np.isnan(chosen[r, 0]) else None for r, pin in ((x, pin_a), (y, pin_b)))
            found = search(slice(x, y + 1), dt[x:y], ends)
            checks += found.checks
            seg = found.segment
            splits = int(((seg[1:] != seg[:-1]) & (seg[1:] >= 0) & (seg[:-1] >= 0)).sum())
            if best is not None and splits >= best[0]:
                break  # wider did not help: the split is the ladder's own
            best = (splits, x, y, ends, found)
            if splits == 0 or (seg < 0).any() or (x == 0 and y == m - 1):
                break  # (skipped rungs: the axis deviation's part, not the pins')
        _, x, y, ends, found = best
        a0, b0 = int(ends[0] is not None), int(ends[1] is not None)
        link[x] &= bool(a0)  # a free end starts a motion of its own
        link[min(y + 1, m - 1)] &= bool(b0) or y == m - 1
        inner = slice(x + a0, y + 1 - b0)
        chosen[inner] = found.q[a0:len(found.q) - b0]
        solutions[inner] = found.solutions[a0:len(found.q) - b0]
        seg = found.segment
        link[x + 1:y + 1] = (seg[1:] == seg[:-1]) & (seg[1:] >= 0)
        p = max(p, found.rotations)
    return p, checks


#: bump heights (rad) tried, smallest first, on a gap whose θ interpolated in time fails (:func:`_fill`)
BUMPS = np.radians([15.0, 30.0, 45.0])


def _fill(
    robot: Robot,
    cell: Workcell,
    positions: np.ndarray,
    normals: np.ndarray,
    dt: np.ndarray,
    elapsed: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    theta_a: np.ndarray,
    theta_b: np.ndarray,
    branch: np.ndarray,
    collides: Callable[[np.ndarray], np.ndarray] | None,
    circ: np.ndarray,
    chosen: np.ndarray,
    link: np.ndarray,
) -> tuple[np.ndarray, int]:
    """The waypoints strictly between kept rows a[g] and b[g] (one motion, one IK branch) on that
    branch at θ interpolated in time along the short arc: a gap is filled (``chosen``, ``link``
    written) when every one of its nodes exists inside the limits, every step of a..b keeps
    ‖Δq‖∞ ≤ ξΔt (Eq. 4.4) and no node collides (one batched check). A gap that fails is tried
    again with a smooth bump δ·sin²(πu) added to θ (u: time fraction of the gap; the ends and their
    slopes stay), δ = ±:data:`BUMPS` smallest first, of the two signs the feasible one of lower
    Eq. 3.4 cost: the rotation about the nozzle axis is the redundancy (§4.3.1), and a gap fails
    mostly where the interpolated θ swings the forearm into the platform by a few degrees (bunny
    1.0 layers 66/70/100: 118 of 129 failed gaps filled at 15-30°, ~1 ms each against ~14 ms for
    the pinned ladder search of the stretch). Returns filled (G,), checks."""
    good = np.zeros(len(a), bool)
    asked = 0
    for bump in np.r_[0.0, BUMPS]:
        todo = np.flatnonzero(~good)
        if not len(todo):
            break
        tries = [_fill_try(robot, cell, positions, normals, dt, elapsed, a[todo], b[todo], theta_a[todo],
                           theta_b[todo], branch[todo], collides, circ, chosen, sign * bump)
                 for sign in ((1.0,) if bump == 0 else (1.0, -1.0))]
        asked += sum(t.asked for t in tries)
        cost = np.array([np.where(t.fits, t.cost, np.inf) for t in tries])  # (signs, G)
        pick = np.argmin(cost, axis=0)
        for s, t in enumerate(tries):
            mine = t.fits & (pick == s)
            take = mine[t.gap]
            chosen[t.rows[take]] = t.q[take]
            link[t.rows[take]] = True
            link[b[todo[mine]]] = True
            good[todo[mine]] = True
    return good, asked


#: θ offsets (rad) about the rotation interpolated in time that :func:`_band_fill` gives each waypoint
BAND = np.radians(np.arange(-90.0, 90.1, 7.5))


def _band_fill(robot: Robot, cell: Workcell, positions: np.ndarray, normals: np.ndarray, dt: np.ndarray,
               elapsed: np.ndarray, a: np.ndarray, b: np.ndarray, theta_a: np.ndarray, theta_b: np.ndarray,
               branch: np.ndarray, collides: Callable[[np.ndarray], np.ndarray] | None, circ: np.ndarray,
               chosen: np.ndarray, link: np.ndarray, band: np.ndarray = BAND) -> tuple[np.ndarray, int]:
    """Gaps :func:`_fill` could not fill (rows a[g]..b[g], one motion, one IK branch), each searched as
    a small ladder of its own (§4.3.1): its ends pinned to their kept nodes, each inner waypoint with
    the nodes of its branch at θ :data:`BAND` about θ interpolated in time, the shortest path (Eq. 3.4,
    ξ of Eq. 4.4, lazy collision checks) through all gaps at once (one ladder, no edge between
    gaps). A gap whose path reaches its end in one motion is filled (``chosen``, ``link`` written): the
    smooth bumps' search widened to any θ path near the interpolation, at a band's nodes per waypoint
    where the full ladder of the stretch has 8·2p. Returns filled (G,), checks."""
    G = len(a)
    if not G:
        return np.zeros(0, bool), 0
    inner = b - a - 1
    gap, rows, u, turn = _gap_rows(a, b, elapsed, theta_a, theta_b)
    K = len(band)
    qi, ok = ladder_at(robot, cell, np.repeat(positions[rows], K, axis=0), np.repeat(normals[rows], K, axis=0),
                       ((theta_a[gap] + u * turn[gap])[:, None] + band[None]).ravel(), np.repeat(branch[gap], K))
    # one ladder: per gap its kept rung a (one node), its inner rungs, its kept rung b (one node)
    size = inner + 2
    first = np.cumsum(size) - size
    at = first[gap] + rows - a[gap]  # the inner rows' rungs
    q = np.full((size.sum(), K, 6), np.nan)
    q[first, 0], q[first + size - 1, 0] = chosen[a], chosen[b]
    q[at] = np.where(ok.reshape(-1, K)[..., None], qi.reshape(-1, K, 6), np.nan)
    row_of = np.empty(len(q), np.int64)
    row_of[first], row_of[first + size - 1], row_of[at] = a, b, rows
    owner = np.repeat(np.arange(G), size)
    # between gaps 0 s: no edge (but from one gap's end to the next one's start where that is the same kept node)
    step = np.where(owner[1:] == owner[:-1], dt[np.minimum(row_of[:-1], len(dt) - 1)], 0.0)
    node_ok = None if collides is None else (lambda r, k: ~collides(q[r, k]))
    path, _, asked = shortest_path(q, ~np.isnan(q[..., 0]), step, cell.max_joint_speed, circ, node_ok=node_ok)
    node, seg = path.node, path.segment
    whole = (np.bincount(owner, node < 0, G) == 0) & (seg[first] == seg[first + size - 1])
    take = whole[gap]
    chosen[rows[take]] = q[at[take], node[at[take]]]
    link[rows[take]] = True
    link[b[whole]] = True
    return whole, asked


#: every θ (7.5° apart) about the interpolated one: :func:`_band_fill` between wider ends
WIDE_BAND = np.radians(np.arange(-180.0, 180.0, 7.5))


def _band_windows(ca: np.ndarray, cb: np.ndarray, coarse: _Found, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Coarse rungs (x, y) around the open gaps ca[g]..cb[g] (indices into the coarse path): ``step``
    kept rungs further out each side, merged where they overlap, kept where both ends are on one
    motion and IK branch of the coarse path (the wider band's pinned ends)."""
    last = len(coarse.node) - 1
    x, y = np.clip(ca - step, 0, last), np.clip(cb + step, 0, last)
    out: list[list[int]] = []
    for i, j in sorted(zip(x.tolist(), y.tolist())):
        if out and i <= out[-1][1]:
            out[-1][1] = max(out[-1][1], j)
        else:
            out.append([i, j])
    w = np.array(out, np.int64).reshape(-1, 2)
    a, b = w[:, 0], w[:, 1]
    ok = (coarse.node[a] >= 0) & (coarse.node[b] >= 0) & (coarse.segment[a] == coarse.segment[b]) \
        & (coarse.branch[a] == coarse.branch[b])
    return a[ok], b[ok]


def _gap_rows(a: np.ndarray, b: np.ndarray, elapsed: np.ndarray, theta_a: np.ndarray,
              theta_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The rows strictly inside gaps a[g]..b[g]: the gap of each, the rows, their time fraction u of
    their gap, and per gap the short-arc turn from θ_a to θ_b."""
    inner = b - a - 1
    gap = np.repeat(np.arange(len(a)), inner)
    rows = a[gap] + 1 + np.arange(len(gap)) - np.repeat(np.cumsum(inner) - inner, inner)
    u = (elapsed[rows] - elapsed[a[gap]]) / np.maximum(elapsed[b[gap]] - elapsed[a[gap]], 1e-300)
    return gap, rows, u, (theta_b - theta_a + np.pi) % TWO_PI - np.pi


class _FillTry(NamedTuple):
    """One try of :func:`_fill` over G gaps: whether each fits and its Eq. 3.4 cost (G,), the gaps'
    inner rows with the gap of each and their joints, and the collision checks made."""

    fits: np.ndarray
    cost: np.ndarray
    rows: np.ndarray
    gap: np.ndarray
    q: np.ndarray
    asked: int


def _fill_try(robot: Robot, cell: Workcell, positions: np.ndarray, normals: np.ndarray, dt: np.ndarray,
              elapsed: np.ndarray, a: np.ndarray, b: np.ndarray, theta_a: np.ndarray, theta_b: np.ndarray,
              branch: np.ndarray, collides: Callable[[np.ndarray], np.ndarray] | None, circ: np.ndarray,
              chosen: np.ndarray, bump: float) -> _FillTry:
    """One try of :func:`_fill` with bump height ``bump``."""
    gap, rows, u, turn = _gap_rows(a, b, elapsed, theta_a, theta_b)
    q, ok = ladder_at(robot, cell, positions[rows], normals[rows], theta_a[gap] + u * turn[gap]
                      + bump * np.sin(np.pi * u) ** 2, branch[gap])
    good = np.bincount(gap, ~ok, len(a)) == 0
    # every step of each gap: into its inner rows, and from its last inner row into b
    cand = chosen.copy()
    cand[rows] = q
    into = np.r_[rows, b]
    step, largest = joint_steps(cand[into - 1], cand[into], circ)
    fast = ~(largest <= cell.max_joint_speed * dt[into - 1])
    owner = np.r_[gap, np.arange(len(a))]
    good &= np.bincount(owner, fast, len(a)) == 0
    cost = np.bincount(owner, np.where(np.isfinite(step), step, 0.0), len(a))
    asked = 0
    if collides is not None:
        test = good[gap]
        hit = np.zeros(len(rows), bool)
        hit[test] = collides(q[test])
        asked = int(test.sum())
        good &= np.bincount(gap, hit, len(a)) == 0
    return _FillTry(good, cost, rows, gap, q, asked)


#: neighbouring steps of one tool-path differ in duration by at most this ratio (:func:`ramp_steps`)
FEED_RAMP = 1.3


def ramp_steps(dt: np.ndarray, path_id: np.ndarray, ratio: float = FEED_RAMP) -> np.ndarray:
    """Step times (m-1,) lengthened so that neighbouring steps of one path (``path_id`` (m,) per
    waypoint) differ by at most ``ratio``: the arm slows down over a few steps before a step that
    must be slow (the tool turning at ω̄, :func:`step_times`) and speeds up after it, as a
    controller's look-ahead does, instead of changing its feed several-fold from one step to the
    next, which the jerk stage could only answer by time-scaling (on bunny 1.0 layers 9-24 and
    60-67 with the axis smoothing, 59 % of the steps are turn-limited and the time-scaling added
    7.1 %). The smallest such times: log Δt'_i = max_j (log Δt_j − |i − j| log ratio) over j on
    i's path."""
    dt = np.asarray(dt, float)
    if len(dt) < 2 or ratio <= 1:
        return dt
    pid = np.asarray(path_id)
    inside = pid[1:] == pid[:-1]  # a step on one path; a jump between paths is a run of its own
    run = np.cumsum(np.r_[True, ~inside[1:] | ~inside[:-1]])  # runs of steps on one path
    c = np.log(ratio)
    i = np.arange(len(dt), dtype=float)
    u = np.log(np.maximum(dt, 1e-300))
    big = (u.max() - u.min() + c * len(dt) + 1.0) * run  # keeps the running maxima inside their run
    fwd = np.maximum.accumulate(u + c * i + big) - big - c * i
    bwd = (np.maximum.accumulate((u - c * i - big)[::-1]) + big[::-1])[::-1] + c * i
    return np.exp(np.maximum(fwd, bwd))


def _timestamps(q: np.ndarray, segment: np.ndarray, dt: np.ndarray, max_speed: float) -> np.ndarray:
    """Seconds from the first waypoint: Δt inside a segment; a joint move at ξ between segments."""
    t = np.full(len(q), np.nan)
    clock, last = 0.0, -1
    elapsed = np.r_[0.0, np.cumsum(dt)]
    for i in np.flatnonzero(segment >= 0):
        if last < 0:
            clock = 0.0
        elif segment[i] == segment[last]:
            clock += elapsed[i] - elapsed[last]
        else:
            clock += max(float(np.abs(q[i] - q[last]).max()) / max_speed, elapsed[i] - elapsed[last])
        t[i] = clock
        last = i
    return t


@dataclass
class PrintMotion:
    """The joint trajectory of a whole print: one row per realized waypoint, in print order."""

    index: np.ndarray  # (R,) row of the waypoint in the tool-path arrays
    t: np.ndarray  # (R,) s, strictly increasing
    q: np.ndarray  # (R, 6) rad
    segment: np.ndarray  # (R,) global motion id; a new id is reached by a joint move
    extruding: np.ndarray  # (R,) bool, extruder on while moving to the row
    normals: np.ndarray  # (R, 3) realized tool axis (the planned one unless deviated)
    deviation: np.ndarray  # (R,) rad between the realized and the planned tool axis
    layers: list[dict]  # per layer: waypoints, rotations, splits, skipped, checks, seconds


def segment_speeds(path_id: np.ndarray, feed: np.ndarray, cell: Workcell) -> np.ndarray:
    """Speed (mm/s) of each step j -> j+1: the G-code feed inside a path (v̄ where it is 0), the
    workcell's travel speed for a jump to a new path."""
    same = path_id[1:] == path_id[:-1]
    feed_s = np.asarray(feed[1:], float) / 60.0
    return np.where(same, np.where(feed_s > 0, feed_s, cell.linear_speed), cell.travel_speed)


class Remembered:
    """A collision predicate that answers a configuration it was asked before from memory (bitwise
    equal joints: the same IK node met again, e.g. when a layer is planned again after an axis
    deviation or a stretch is searched again); ``asked`` counts the configurations really checked."""

    def __init__(self, collides: Callable[[np.ndarray], np.ndarray]):
        self.collides, self.known, self.asked = collides, {}, 0
        self.dead: dict[bytes, bool] = {}
        self.held: dict[bytes, bool] = {}
        if hasattr(collides, "blocked"):
            self.blocked = lambda frames: self._frames(frames, self.collides.blocked, self.dead)
        if hasattr(collides, "held_blocked"):
            self.held_blocked = self._held_blocked
        self.held_asked = self.held_hits = 0

    def _held_blocked(self, frames: np.ndarray) -> np.ndarray:
        out = self._frames(frames, self.collides.held_blocked, self.held)
        self.held_asked += len(out)
        self.held_hits += int(out.sum())
        return out

    def held_useful(self) -> bool:
        """Whether the per-frame test (``held_blocked``) still pays before node-by-node checks: it
        found contacts in at least a quarter of the frames asked so far (near the platform, where
        whole θ collide), or fewer than 64 were asked."""
        return self.held_asked < 64 or 4 * self.held_hits >= self.held_asked

    @staticmethod
    def _frames(frames: np.ndarray, test: Callable[[np.ndarray], np.ndarray], known: dict[bytes, bool]) -> np.ndarray:
        """The predicate's per-frame test (``collides.blocked`` for whole rungs, ``held_blocked`` for
        one θ), remembered per frame in ``known``."""
        frames = np.ascontiguousarray(frames, float)
        keys = [f.tobytes() for f in frames]
        new = [i for i, k in enumerate(keys) if k not in known]
        if new:
            known.update(zip((keys[i] for i in new), np.asarray(test(frames[new]), bool).tolist()))
        return np.array([known[k] for k in keys], bool).reshape(len(frames))

    def __call__(self, q: np.ndarray) -> np.ndarray:
        q = np.ascontiguousarray(q, float)
        keys = [row.tobytes() for row in q]
        out = np.array([self.known.get(k, 2) for k in keys], np.int8).reshape(len(q))
        new = np.flatnonzero(out == 2)
        if len(new):
            first = {keys[i]: i for i in new[::-1]}  # repeats inside one call: check once
            todo = np.array(sorted(first.values()))
            hit = self.collides(q[todo])
            self.known.update(zip((keys[i] for i in todo), hit.tolist()))
            self.asked += len(todo)
            out[new] = [self.known[keys[i]] for i in new]
        return out.astype(bool)


#: rows either side of a deviated waypoint searched again with its new axis (:func:`plan_layer`)
DEVIATION_MARGIN = 2 * COARSE_STEP


def deviation_windows(changed: np.ndarray, margin: int) -> list[tuple[int, int, bool, bool]]:
    """Stretches (a, b, pin a, pin b) of rows to search again around the ``changed`` (m,) rows: each
    run of them widened by ``margin`` rows either side (clipped to the layer, windows that meet
    merged), both ends pinned (to the path already found there; an end without one stays free)."""
    m = len(changed)
    rows = np.flatnonzero(changed)
    if not len(rows):
        return []
    new = np.r_[True, np.diff(rows) > 2 * margin + 1]
    first, last = rows[new], rows[np.r_[new[1:], True]]
    return [(max(int(a) - margin, 0), min(int(b) + margin, m - 1), True, True) for a, b in zip(first, last)]


def _around(rows: np.ndarray) -> np.ndarray:
    """(m,) bool: the ``rows`` (m,) bool and the ``REFINE_WINDOW`` rows either side of each: the rungs
    around a deviated tool axis, refined with every break of the search (:func:`plan_motion`'s ``dense``)."""
    m = len(rows)
    return np.convolve(rows, np.ones(2 * REFINE_WINDOW + 1))[REFINE_WINDOW:REFINE_WINDOW + m] > 0


def plan_layer(
    robot: Robot,
    cell: Workcell,
    toolpaths: dict[str, np.ndarray],
    rows: np.ndarray,
    collides: Callable[[np.ndarray], np.ndarray] | None = None,
    cost: str = "l1",
    max_rotations: int | None = None,
    coarse_step: int = COARSE_STEP,
) -> PrintMotion:
    """One layer's motion: ``rows`` of ``toolpaths`` (keys of ``toolpaths.npz``, one layer, in print
    order) as a ladder graph of its own (multi-source, like the thesis's per-tool-path graphs, §4.3.1).

    ``collides(q)`` is the collision predicate valid while printing that layer (the part then is the
    union of the earlier layers): the layer depends on no other layer's motion, so layers are
    independent tasks. Waypoints that no rotation θ can serve with their planned axis
    (:func:`blocked_rungs`, :func:`hopeless_rungs`) get a deviated axis (:func:`deviate_axes`) before
    the search; those the search leaves without a usable pose get one after it, and only the stretch
    around them is searched again (:func:`deviation_windows`, its ends pinned to the path found where
    it has one). Times start at 0 and segments at 0;
    :func:`join_motions` places the layers one after the other. ``coarse_step`` > 1: the
    coarse-to-fine search of :func:`plan_motion` on :func:`coarse_rungs`; 1: the full ladder."""
    start = time.perf_counter()
    rows = np.asarray(rows)
    positions = np.asarray(toolpaths["positions"], float)[rows]
    planned = np.asarray(toolpaths["normals"], float)[rows]
    path_id = np.asarray(toolpaths["path"])[rows]
    speed = segment_speeds(path_id, np.asarray(toolpaths["feed"], float)[rows], cell)
    m = len(rows)
    keep = coarse_rungs(path_id, coarse_step) if coarse_step > 1 else None
    # the axis the arm follows: the tool-path's, low-passed along each path within half the bounded
    # deviation (workcell.py, "Axis smoothing"); a row tilted for a collision is tilted from its own
    axes, _ = smooth_along_paths(positions, planned, path_id, cell.axis_smoothing, cell.max_axis_deviation / 2)
    deviation, tried = np.zeros(m), np.zeros(m, bool)
    collides = None if collides is None else Remembered(collides)
    memo = RungMemo()  # the windows ask mostly the rungs the first search asked
    if cell.max_axis_deviation > 0 and collides is not None and m:
        # rows no θ can serve with their planned axis, known before any search: the extruder's core
        # meets the platform or part (blocked), or at every θ of the finest p a static body does
        # (hopeless). Their axes are tilted first and the layer searched once (bunny 1.0 layers 9-25:
        # 231 of 256 stuck rows were known so; searching, tilting and searching the windows around
        # them again cost the near-platform layers ~40 % of their graph time)
        tried = blocked_rungs(collides, positions, axes)
        rest = np.flatnonzero(~tried)
        tried[rest] = hopeless_rungs(collides, positions[rest], axes[rest], finest_rotations(cell, max_rotations))
        if tried.any():
            axes, deviation = deviate_axes(robot, cell, positions, np.where(tried[:, None], planned, axes), tried,
                                           collides, start_rotations(cell.rotations))
    dt = ramp_steps(step_times(positions, speed, cell.min_step_time, axes, cell.tool_turn_speed), path_id) if m > 1 \
        else np.zeros(0)
    search = _searcher(robot, cell, positions, axes, collides, cost, None, max_rotations,
                       _around(deviation > 0) if (deviation > 0).any() else None, memo)
    chosen, link, solutions, p, checks = _links(robot, cell, positions, axes, dt, keep, collides, search)
    while cell.max_axis_deviation > 0:
        stuck = np.isnan(chosen[:, 0]) & ~tried
        if not stuck.any():
            break
        axes, more = deviate_axes(robot, cell, positions, np.where(stuck[:, None], planned, axes), stuck, collides,
                                  start_rotations(cell.rotations))
        tried |= stuck
        if not (more > 0).any():
            break
        deviation = deviation + more
        dt = ramp_steps(step_times(positions, speed, cell.min_step_time, axes, cell.tool_turn_speed), path_id)
        search = _searcher(robot, cell, positions, axes, collides, cost, None, max_rotations, _around(deviation > 0), memo)
        # (not widened: near a deviated axis the splits are the ladder's own, wider ends never mended one)
        p_more, asked = _stretches(deviation_windows(more > 0, DEVIATION_MARGIN), np.arange(m), dt, search, chosen,
                                   link, solutions, widen=0)
        p, checks = max(p, p_more), checks + asked
    motion = _motion(robot, cell, chosen, link, solutions, p, checks, dt, cost, None)
    axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    realized = angles_between(axes, planned)
    done = motion.segment >= 0
    seg = motion.segment[done]
    local = np.cumsum(np.r_[True, seg[1:] != seg[:-1]]) - 1 if len(seg) else seg
    starts = np.r_[True, local[1:] != local[:-1]] if len(seg) else np.zeros(0, bool)
    t = motion.t[done]
    laddered = motion.solutions[motion.solutions >= 0]
    stats = {
        "layer": int(np.asarray(toolpaths["layer"])[rows[0]]) if len(rows) else 0,
        "waypoints": int(len(rows)),
        "rotations": motion.rotations,
        "ik_solutions_mean": round(float(laddered.mean()), 2) if len(laddered) else 0.0,  # laddered rungs
        "ik_solutions_min": int(laddered.min()) if len(laddered) else 0,
        "splits": [int(rows[s]) for s in motion.splits],
        "winding_splits": [int(rows[s]) for s in motion.winding_splits],
        "skipped": int((~done).sum()),
        "deviated": int((deviation[done] > 0).sum()),  # tilted for a collision (the smoothing aside)
        "max_deviation_deg": round(float(np.degrees(realized[done].max())), 3) if done.any() else 0.0,
        "collision_checks": collides.asked if collides is not None else 0,  # distinct poses, every pass
        "seconds": round(time.perf_counter() - start, 3),
    }
    return PrintMotion(
        index=rows[done].astype(np.int64),
        t=t - t[0] if len(t) else t,
        q=motion.q[done],
        segment=local.astype(np.int64),
        extruding=(np.asarray(toolpaths["extrusion"], float)[rows[done]] > 0) & ~starts,
        normals=axes[done],
        deviation=realized[done],
        layers=[stats],
    )


def join_motions(parts: list[PrintMotion], move_time: Callable[[np.ndarray, np.ndarray], float]) -> PrintMotion:
    """The layers' motions one after the other: each starts ``move_time(q_last, q_first)`` seconds
    after the previous one ends (a joint move, a new segment); segment ids become global."""
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("index", "t", "q", "segment", "extruding", "normals", "deviation")}
    clock, seg0, last_q = 0.0, 0, None
    for part in parts:
        if len(part.q):
            clock += 0.0 if last_q is None else move_time(last_q, part.q[0])
            out["t"].append(part.t - part.t[0] + clock)
            out["segment"].append(part.segment - part.segment[0] + seg0)
            for k in ("index", "q", "extruding", "normals", "deviation"):
                out[k].append(getattr(part, k))
            clock, seg0, last_q = float(out["t"][-1][-1]), int(out["segment"][-1][-1]) + 1, part.q[-1]
    empty = {"index": (0,), "t": (0,), "q": (0, 6), "segment": (0,), "extruding": (0,), "normals": (0, 3),
             "deviation": (0,)}
    arrays = {k: np.concatenate(v) if v else np.zeros(empty[k]) for k, v in out.items()}
    return PrintMotion(
        index=arrays["index"].astype(np.int64), t=arrays["t"], q=arrays["q"],
        segment=arrays["segment"].astype(np.int64), extruding=arrays["extruding"].astype(bool),
        normals=arrays["normals"], deviation=arrays["deviation"],
        layers=[s for part in parts for s in part.layers],
    )


def joint_move_time(cell: Workcell) -> Callable[[np.ndarray, np.ndarray], float]:
    """The graph search's move between layers: every joint at most ξ (Eq. 4.4), at least one step."""
    return lambda qa, qb: max(float(np.abs(qb - qa).max()) / cell.max_joint_speed, cell.min_step_time)


def plan_print(
    robot: Robot,
    cell: Workcell,
    toolpaths: dict[str, np.ndarray],
    collides_for_layer: Callable[[int], Callable[[np.ndarray], np.ndarray] | None] | None = None,
    cost: str = "l1",
    max_rotations: int | None = None,
    progress: Callable[[int], None] | None = None,
) -> PrintMotion:
    """Plan every layer of ``toolpaths`` with :func:`plan_layer` (``collides_for_layer(layer)``: its
    collision predicate) and join them by joint moves at ξ. ``progress(n)`` is told of n waypoints done."""
    layer = np.asarray(toolpaths["layer"])
    parts = []
    for value in np.unique(layer):
        rows = np.flatnonzero(layer == value)
        collides = collides_for_layer(int(value)) if collides_for_layer else None
        parts.append(plan_layer(robot, cell, toolpaths, rows, collides, cost, max_rotations))
        if progress:
            progress(len(rows))
    return join_motions(parts, joint_move_time(cell))


def motion_summary(motion: PrintMotion, waypoints: int) -> dict[str, object]:
    """Figures of a planned print for ``report.json``: rows, IK solutions per waypoint, splits
    (graph disconnections, Fig. 3.11b), winding splits, skipped waypoints, waypoints printed with a
    deviated tool axis and the largest deviation, max joint step, p used."""
    inside = motion.segment[1:] == motion.segment[:-1]
    step = np.abs(np.diff(motion.q, axis=0)).max(axis=1) if len(motion.q) > 1 else np.zeros(0)
    layers = motion.layers
    return {
        "waypoints": waypoints,
        "rows": int(len(motion.q)),
        "skipped": int(sum(s["skipped"] for s in layers)),
        "deviated": int(sum(s["deviated"] for s in layers)),
        "max_deviation_deg": round(float(np.degrees(motion.deviation.max())), 3) if len(motion.deviation) else 0.0,
        "segments": int(motion.segment.max() + 1) if len(motion.segment) else 0,
        "splits": int(sum(len(s["splits"]) for s in layers)),
        "winding_splits": int(sum(len(s["winding_splits"]) for s in layers)),
        "ik_solutions_per_waypoint_mean": round(float(np.average([s["ik_solutions_mean"] for s in layers],
                                                                 weights=[s["waypoints"] for s in layers])), 2) if layers else 0.0,
        "ik_solutions_per_waypoint_min": int(min(s["ik_solutions_min"] for s in layers)) if layers else 0,
        "max_joint_step_rad": round(float(step[inside].max()), 6) if inside.any() else 0.0,
        "print_time_s": round(float(motion.t[-1] - motion.t[0]), 3) if len(motion.t) else 0.0,
        "rotations_used": sorted({int(s["rotations"]) for s in layers}),
        "collision_checks": int(sum(s["collision_checks"] for s in layers)),
        "layers": layers,
    }
