"""Pose-continuous motion: ladder graph and multi-source shortest path (§3.5.3, §4.3.1, Fig. 4.2).

Each waypoint (c_j, t_j) gives a rung of nodes: every analytic IK solution of p rotations about the
nozzle axis (Eq. 4.3), inside the joint limits and free of collision. An edge joins consecutive
rungs when ‖Δq‖∞/Δt ≤ ξ (Eq. 4.4, Δt = ‖c_{j+1} − c_j‖/v̄) with weight ‖Δq‖₁ (Eq. 3.4) or the
weighted quadratic Δqᵀ W Δq (Eq. 4.5); distances are circular on joints that can turn a full
revolution ("winding effect", §4.3.1). The graph is a DAG, so the multi-source Dijkstra of the
thesis (all first-rung nodes as sources) is computed rung by rung, vectorized over node pairs.
Where no node of a rung is reachable the motion splits there and a new one starts (Fig. 3.11b);
when a layer needs splits, p is doubled and the search repeated while that removes splits (§4.3.1).
Collisions are checked lazily: only nodes on the current best path are tested; where one collides,
the other nodes of its IK branch in that rung are tested too and the search resumes from the
earliest such rung. The result equals checking every node first (tested against that).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from curvslice.kinematics import Robot, ik
from curvslice.workcell import Workcell, flange_poses

TWO_PI = 2 * np.pi


@dataclass
class LadderPath:
    """A shortest path through a ladder: node index per rung (-1 on empty rungs), segment id per
    rung (-1 on empty rungs; a new id after each disconnection), and the total edge cost."""

    node: np.ndarray
    segment: np.ndarray
    cost: float


@dataclass
class Motion:
    """Joint trajectory of one sequence of waypoints (one layer)."""

    q: np.ndarray  # (m, 6) rad, unwound joint values; NaN rows for skipped waypoints
    t: np.ndarray  # (m,) s from the first waypoint; NaN for skipped waypoints
    segment: np.ndarray  # (m,) int, a new value starts a new smooth motion; -1 if skipped
    rotations: int  # p finally used
    solutions: np.ndarray  # (m,) int, IK solutions per waypoint within the joint limits
    splits: list[int]  # waypoint indices where the graph disconnects (new motion, Fig. 3.11b)
    winding_splits: list[int]  # waypoint indices where a joint would leave its range by winding
    cost: float  # Eq. 3.4 (or 4.6) summed over the segments
    collision_checks: int


def circular_joints(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Joints whose range exceeds one revolution: their distances are measured on the circle."""
    return (np.asarray(upper) - np.asarray(lower)) > TWO_PI + 1e-9


def edge_weights(
    qa: np.ndarray,
    qb: np.ndarray,
    dt: float,
    max_speed: float,
    circular: np.ndarray,
    cost: str = "l1",
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """(Ka, Kb) edge weights between two rungs; ``inf`` where ‖Δq‖∞/Δt > ξ (Eq. 4.4) or a node is
    absent (NaN). ``cost`` = "l1" (Eq. 3.4, weighted by ``weights``) or "quadratic" (Eq. 4.5)."""
    total, largest = _joint_costs(lambda j: qb[None, :, j] - qa[:, None, j], circular, cost, weights)
    total[~(largest <= max_speed * dt)] = np.inf  # NaN nodes compare False -> excluded
    return total


def _joint_costs(
    diff: Callable[[int], np.ndarray], circular: np.ndarray, cost: str, weights: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Edge cost (Eq. 3.4 or 4.5) and ‖Δq‖∞ from per-joint differences ``diff(j)``, one joint at
    a time (keeps the work in cache); circular joints take the short way round."""
    total = largest = None
    for j in range(len(circular)):
        d = np.abs(diff(j))
        if circular[j]:
            np.minimum(d, TWO_PI - d, out=d)
        largest = d.copy() if largest is None else np.maximum(largest, d, out=largest)
        if cost != "l1":
            d *= d
        d *= 1.0 if weights is None else float(weights[j])
        total = d if total is None else np.add(total, d, out=total)
    return total, largest


def sparse_edges(
    qa: np.ndarray,
    qb: np.ndarray,
    dt: float,
    max_speed: float,
    circular: np.ndarray,
    cost: str = "l1",
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The finite entries of :func:`edge_weights` as (ia, ib, w), found without the dense matrix:
    candidates are the pairs whose most discriminating joint differs by at most ξΔt (a sorted-window
    search), then every joint is tested exactly as in :func:`edge_weights` (same arithmetic, same result)."""
    limit = max_speed * dt
    ka = np.flatnonzero(~np.isnan(qa[:, 0]))
    kb = np.flatnonzero(~np.isnan(qb[:, 0]))
    if len(ka) == 0 or len(kb) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    if limit >= 1.0:  # wide windows: the dense matrix is as cheap
        w = edge_weights(qa, qb, dt, max_speed, circular, cost, weights)
        ia, ib = np.nonzero(np.isfinite(w))
        return ia, ib, w[ia, ib]
    # window on the joint with the fewest target nodes within ξΔt of each other (joint 1 is
    # useless when every rotation θ leaves the wrist in place)
    v = np.sort(qb[kb], axis=0)
    crowd = [(np.searchsorted(v[:, j], v[:, j] + limit, "right") - np.searchsorted(v[:, j], v[:, j] - limit, "left")).sum()
             for j in range(v.shape[1])]
    j0 = int(np.argmin(crowd))
    b0 = qb[kb, j0]
    copies = (b0, b0 + TWO_PI, b0 - TWO_PI) if circular[j0] else (b0,)
    values = np.concatenate(copies)
    owner = np.tile(np.arange(len(kb)), len(copies))
    order = np.argsort(values, kind="stable")
    sorted_values = values[order]
    a0 = qa[ka, j0]
    lo = np.searchsorted(sorted_values, a0 - limit, "left")
    hi = np.searchsorted(sorted_values, a0 + limit, "right")
    counts = hi - lo
    ia = np.repeat(np.arange(len(ka)), counts)
    pos = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts) + np.repeat(lo, counts)
    ib = owner[order[pos]]
    ia, ib = ka[ia], kb[ib]
    total, largest = _joint_costs(lambda j: qb[ib, j] - qa[ia, j], circular, cost, weights)
    keep = largest <= limit
    return ia[keep], ib[keep], total[keep]


def _relax(
    valid: np.ndarray,
    best: np.ndarray,
    pred: np.ndarray,
    start: int,
    edges: Callable[[int], tuple[np.ndarray, np.ndarray, np.ndarray]],
) -> None:
    """Fill ``best``/``pred`` for rungs ``start..m-1`` (rung start-1 already final)."""
    m = len(valid)
    for i in range(max(start, 0), m):
        best[i] = np.inf
        pred[i] = -1
        if i > 0 and np.isfinite(best[i - 1]).any():
            ia, ib, w = edges(i - 1)
            total = best[i - 1][ia] + w
            ok = np.isfinite(total) & valid[i][ib]
            ia, ib, total = ia[ok], ib[ok], total[ok]
            if len(ib):
                order = np.lexsort((ia, total, ib))  # per target: least cost, then first source
                first = order[np.r_[True, ib[order][1:] != ib[order][:-1]]]
                best[i][ib[first]] = total[first]
                pred[i][ib[first]] = ia[first]
                continue
        best[i] = np.where(valid[i], 0.0, np.inf)  # sources: a new motion starts here


def _backtrack(best: np.ndarray, pred: np.ndarray) -> LadderPath:
    m = len(best)
    node = np.full(m, -1)
    i = m - 1
    cost = 0.0
    while i >= 0:
        if not np.isfinite(best[i]).any():
            i -= 1
            continue
        k = int(np.argmin(best[i]))
        cost += float(best[i][k])
        while True:
            node[i] = k
            if pred[i][k] < 0:
                break
            k = int(pred[i][k])
            i -= 1
        i -= 1
    starts = (node >= 0) & np.r_[True, pred[np.arange(1, m), np.maximum(node[1:], 0)] < 0]
    segment = np.where(node >= 0, np.cumsum(starts) - 1, -1)
    return LadderPath(node, segment, cost)


def shortest_path(
    q: np.ndarray,
    valid: np.ndarray,
    dt: np.ndarray,
    max_speed: float,
    circular: np.ndarray,
    cost: str = "l1",
    weights: np.ndarray | None = None,
    node_ok: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    group: np.ndarray | None = None,
) -> tuple[LadderPath, np.ndarray, int]:
    """Multi-source shortest path through a ladder (m rungs, K nodes, 6 joints), rung by rung.

    ``q`` (m, K, 6), ``valid`` (m, K), ``dt`` (m-1,) seconds. ``node_ok(rungs, nodes)`` (optional)
    returns which of the given nodes are usable (e.g. collision-free); it is called lazily on path
    nodes; where one is rejected, the other nodes of its ``group`` (labels (K,), e.g. the IK branch;
    default: the whole rung) in that rung are asked too. Returns the path, the final validity mask, and how many nodes
    ``node_ok`` was asked about.
    """
    q = np.where(valid[..., None], q, np.nan)
    valid = valid.copy()
    m, K = valid.shape
    best = np.full((m, K), np.inf)
    pred = np.full((m, K), -1)
    cache: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def edges(i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # edges only lose endpoints between passes (_relax masks invalid ones), so keep them
        if i not in cache:
            ia, ib, w = sparse_edges(q[i], q[i + 1], dt[i], max_speed, circular, cost, weights)
            cache[i] = (ia.astype(np.int32), ib.astype(np.int32), w)
        return cache[i]

    _relax(valid, best, pred, 0, edges)
    checked = np.zeros((m, K), bool)
    asked = 0
    while True:
        path = _backtrack(best, pred)
        if node_ok is None:
            return path, valid, asked
        rungs = np.flatnonzero(path.node >= 0)
        rungs = rungs[~checked[rungs, path.node[rungs]]]
        if len(rungs) == 0:
            return path, valid, asked
        ok = node_ok(rungs, path.node[rungs])
        asked += len(rungs)
        checked[rungs, path.node[rungs]] = True
        bad = rungs[~ok]
        if len(bad) == 0:
            continue
        same = np.ones((len(bad), K), bool) if group is None else group[None, :] == group[path.node[bad]][:, None]
        rr, kk = np.nonzero(valid[bad] & ~checked[bad] & same)
        rr = bad[rr]
        if len(rr):
            ok = node_ok(rr, kk)
            asked += len(rr)
            checked[rr, kk] = True
            valid[rr[~ok], kk[~ok]] = False
        valid[bad, path.node[bad]] = False
        q[~valid] = np.nan
        _relax(valid, best, pred, int(bad.min()), edges)


def reference_shortest_path(
    q: np.ndarray,
    valid: np.ndarray,
    dt: np.ndarray,
    max_speed: float,
    circular: np.ndarray,
    cost: str = "l1",
    weights: np.ndarray | None = None,
) -> LadderPath:
    """The same problem solved by scipy.sparse.csgraph.dijkstra on the explicit graph (tests only):
    multi-source from the first reachable rung, a new search after every disconnection."""
    q = np.where(valid[..., None], q, np.nan)
    m, K = valid.shape
    rows, cols, vals = [], [], []
    for i in range(m - 1):
        w = edge_weights(q[i], q[i + 1], dt[i], max_speed, circular, cost, weights)
        a, b = np.nonzero(np.isfinite(w))
        rows.append(i * K + a)
        cols.append((i + 1) * K + b)
        vals.append(w[a, b] + 1e-300)  # keep zero-weight edges as edges
    graph = csr_matrix(
        (np.concatenate(vals) if vals else [], (np.concatenate(rows) if rows else [], np.concatenate(cols) if cols else [])),
        shape=(m * K, m * K),
    )
    node = np.full(m, -1)
    segment = np.full(m, -1)
    total = 0.0
    seg = 0
    i = 0
    while i < m:
        if not valid[i].any():
            i += 1
            continue
        sources = i * K + np.flatnonzero(valid[i])
        dist, predecessors, _ = dijkstra(graph, directed=True, indices=sources, min_only=True, return_predecessors=True)
        dist = dist.reshape(m, K)
        reach = np.isfinite(dist).any(axis=1)
        end = i
        while end + 1 < m and reach[end + 1]:
            end += 1
        k = int(np.argmin(dist[end]))
        total += float(dist[end, k])
        v = end * K + k
        while v >= 0:
            node[v // K] = v % K
            segment[v // K] = seg
            v = int(predecessors[v]) if v // K > i else -1
        seg += 1
        i = end + 1
    return LadderPath(node, segment, total)


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


def ladder(robot: Robot, cell: Workcell, positions: np.ndarray, normals: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """Rungs of IK nodes: q (m, 8p, 6) and valid (m, 8p) (solution exists and is inside the limits).

    Joints with more than one revolution of range keep angles in [-π, π); the others take the
    representative inside their limits (none: the node is dropped).
    """
    m = len(positions)
    T = flange_poses(cell, positions, normals, p).reshape(-1, 4, 4)
    q, ok = ik(robot, T)
    lo, hi = cell.limits(robot)
    circ = circular_joints(lo, hi)
    rep = lo + (q - lo) % TWO_PI
    q = np.where(circ, q, rep)
    ok &= ((q >= lo - 1e-12) & (q <= hi + 1e-12)).all(axis=-1)
    return q.reshape(m, 8 * p, 6), ok.reshape(m, 8 * p)


def tilted_axes(axis: np.ndarray, angle: float, azimuths: int = 8) -> np.ndarray:
    """Unit axes at ``angle`` (rad) from the unit ``axis``, ``azimuths`` of them around it, ordered
    from the one tilted towards the vertical +Z (first) to the one tilted away from it (last)."""
    a = np.asarray(axis, float)
    up = np.array([0.0, 0.0, 1.0]) - a[2] * a  # +Z without its component along the axis
    if np.linalg.norm(up) < 1e-9:
        up = np.array([1.0, 0.0, 0.0]) - a[0] * a
    u = up / np.linalg.norm(up)
    v = np.cross(a, u)
    phi = 2 * np.pi * np.arange(azimuths) / azimuths
    phi = phi[np.argsort(np.minimum(phi, 2 * np.pi - phi), kind="stable")]  # 0, +45°, -45°, ...
    d = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    return np.cos(angle) * a + np.sin(angle) * d


def deviate_axes(
    robot: Robot,
    cell: Workcell,
    positions: np.ndarray,
    normals: np.ndarray,
    stuck: np.ndarray,
    collides: Callable[[np.ndarray], np.ndarray] | None,
    p: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Tool axes for waypoints with no usable pose (``stuck``): keep the contact point c_j and tilt
    t_j in rings of ``cell.axis_deviation_step`` up to ``cell.max_axis_deviation`` (towards the
    vertical first) until some rotation θ and IK branch is inside the limits and collision-free.

    A bounded deviation of an orientation the thesis itself low-passes (§3.5.2). Returns the axes
    (m, 3) (unchanged where not stuck or where no tilt within the bound helps) and the deviation
    (m,) rad (0 where unchanged)."""
    axes = np.asarray(normals, float) / np.linalg.norm(normals, axis=1, keepdims=True)
    deviation = np.zeros(len(axes))
    angles = np.arange(1, int(np.floor(cell.max_axis_deviation / cell.axis_deviation_step + 1e-9)) + 1) \
        * cell.axis_deviation_step
    for j in np.flatnonzero(stuck):
        for angle in angles:
            found = None
            for cand in tilted_axes(axes[j], angle):
                if cand[2] <= -1 + 1e-9:
                    continue
                q, ok = ladder(robot, cell, positions[j][None], cand[None], p)
                nodes = q[0, ok[0]]
                if len(nodes) and (collides is None or not collides(nodes).all()):
                    found = cand
                    break
            if found is not None:
                axes[j], deviation[j] = found / np.linalg.norm(found), angle
                break
    return axes, deviation


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
) -> Motion:
    """Joint trajectory for one waypoint sequence (a layer's tool-paths, in print order).

    ``dt`` (m-1,) are the step times; ``collides(q) -> bool`` marks poses in collision. p starts at
    ``cell.rotations`` and doubles while the motion needs splits and doubling reduces them, up to
    ``max_rotations`` (default 4 p); the ladder with the fewest breaks is kept.
    """
    positions = np.asarray(positions, float)
    normals = np.asarray(normals, float)
    lo, hi = cell.limits(robot)
    circ = circular_joints(lo, hi)
    p = cell.rotations
    limit = max_rotations or 4 * cell.rotations
    asked_total = 0
    best = None
    while True:
        q, valid = ladder(robot, cell, positions, normals, p)
        node_ok = None if collides is None else (lambda r, k: ~collides(q[r, k]))  # noqa: E731
        branch = np.arange(8 * p) % 8  # IK branch of each node: collisions mostly follow the branch
        path, _, asked = shortest_path(q, valid, dt, cell.max_joint_speed, circ, cost, weights, node_ok, branch)
        asked_total += asked
        # breaks in the motion: disconnections between realized waypoints, and skipped waypoints
        breaks = int((np.diff(path.segment[path.segment >= 0]) != 0).sum() + (path.node < 0).sum())
        if best is None or breaks < best[0]:
            best = (breaks, p, q, valid, path)
        else:
            break  # a denser ladder did not help: the breaks come from the path itself (§4.3.1)
        if breaks == 0 or p * 2 > limit:
            break
        p *= 2
    _, p, q, valid, path = best
    solutions = valid.sum(axis=1)
    starts = np.flatnonzero(np.r_[False, np.diff(path.segment[path.segment >= 0]) != 0])
    rows = np.flatnonzero(path.node >= 0)
    chosen = np.full((len(positions), 6), np.nan)
    chosen[rows] = q[rows, path.node[rows]]
    qa, winding = unwind(chosen, path.segment, lo, hi)
    splits = [int(rows[s]) for s in starts]
    segment = path.segment.copy()
    for w in winding:
        segment[w:][segment[w:] >= 0] += 1
    times = _timestamps(qa, segment, dt, cell.max_joint_speed)
    return Motion(qa, times, segment, p, solutions, splits, winding, path.cost, asked_total)


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


def plan_print(
    robot: Robot,
    cell: Workcell,
    toolpaths: dict[str, np.ndarray],
    collides_for_layer: Callable[[int], Callable[[np.ndarray], np.ndarray] | None] | None = None,
    cost: str = "l1",
    max_rotations: int | None = None,
    progress: Callable[[int], None] | None = None,
) -> PrintMotion:
    """Plan every layer of ``toolpaths`` (keys of ``toolpaths.npz``) as its own ladder graph
    (multi-source, like the thesis's per-tool-path graphs); layers are joined by joint moves.

    ``collides_for_layer(layer)`` returns the collision predicate valid while printing that layer
    (the part then is the union of the earlier layers). Waypoints left without a usable pose get a
    deviated axis (:func:`deviate_axes`) and the layer is planned again with it. ``progress(n)`` is
    told of n waypoints done.
    """
    positions = np.asarray(toolpaths["positions"], float)
    normals = np.asarray(toolpaths["normals"], float)
    layer = np.asarray(toolpaths["layer"])
    path_id = np.asarray(toolpaths["path"])
    feed = np.asarray(toolpaths["feed"], float)
    extrusion = np.asarray(toolpaths["extrusion"], float)
    out_idx, out_t, out_q, out_seg, out_ext, out_axis, out_dev, stats = [], [], [], [], [], [], [], []
    clock, seg0, last_q = 0.0, 0, None
    for value in np.unique(layer):
        start = time.perf_counter()
        rows = np.flatnonzero(layer == value)
        speed = segment_speeds(path_id[rows], feed[rows], cell)
        collides = collides_for_layer(int(value)) if collides_for_layer else None
        axes, deviation, tried = normals[rows], np.zeros(len(rows)), np.zeros(len(rows), bool)
        checks = 0
        while True:
            dt = step_times(positions[rows], speed, cell.min_step_time, axes, cell.tool_turn_speed) \
                if len(rows) > 1 else np.zeros(0)
            motion = plan_motion(robot, cell, positions[rows], axes, dt, collides, cost, None, max_rotations)
            checks += motion.collision_checks
            stuck = (motion.segment < 0) & ~tried
            if not stuck.any() or cell.max_axis_deviation <= 0:
                break
            axes, more = deviate_axes(robot, cell, positions[rows], axes, stuck, collides, motion.rotations)
            tried |= stuck
            if not (more > 0).any():
                break
            deviation = deviation + more
        done = motion.segment >= 0
        if done.any():
            first = motion.q[done][0]
            move = 0.0 if last_q is None else max(float(np.abs(first - last_q).max()) / cell.max_joint_speed, cell.min_step_time)
            base = clock + move - float(motion.t[done][0])
            seg = motion.segment[done]
            seg_global = seg0 + np.cumsum(np.r_[True, seg[1:] != seg[:-1]]) - 1
            starts = np.r_[True, seg_global[1:] != seg_global[:-1]]
            out_idx.append(rows[done])
            out_t.append(motion.t[done] + base)
            out_q.append(motion.q[done])
            out_seg.append(seg_global)
            out_ext.append((extrusion[rows[done]] > 0) & ~starts)
            out_axis.append(axes[done] / np.linalg.norm(axes[done], axis=1, keepdims=True))
            out_dev.append(deviation[done])
            clock = float(out_t[-1][-1])
            seg0 = int(seg_global[-1]) + 1
            last_q = motion.q[done][-1]
        stats.append({
            "layer": int(value),
            "waypoints": int(len(rows)),
            "rotations": motion.rotations,
            "ik_solutions_mean": round(float(motion.solutions.mean()), 2),
            "ik_solutions_min": int(motion.solutions.min()),
            "splits": [int(rows[s]) for s in motion.splits],
            "winding_splits": [int(rows[s]) for s in motion.winding_splits],
            "skipped": int((~done).sum()),
            "deviated": int((deviation[done] > 0).sum()),
            "max_deviation_deg": round(float(np.degrees(deviation[done].max())), 3) if done.any() else 0.0,
            "collision_checks": checks,  # over every planning pass of the layer
            "seconds": round(time.perf_counter() - start, 3),
        })
        if progress:
            progress(len(rows))
    cat = lambda parts, shape: np.concatenate(parts) if parts else np.zeros(shape)  # noqa: E731
    return PrintMotion(
        index=cat(out_idx, (0,)).astype(np.int64),
        t=cat(out_t, (0,)),
        q=cat(out_q, (0, 6)),
        segment=cat(out_seg, (0,)).astype(np.int64),
        extruding=cat(out_ext, (0,)).astype(bool),
        normals=cat(out_axis, (0, 3)),
        deviation=cat(out_dev, (0,)),
        layers=stats,
    )


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
        "deviated": int((motion.deviation > 0).sum()),
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
