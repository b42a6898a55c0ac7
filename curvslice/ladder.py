"""Ladder graph of IK nodes and its rung-by-rung multi-source shortest path (§3.5.3, §4.3.1, Fig. 4.2).

Each waypoint (c_j, t_j) gives a rung of nodes: every analytic IK solution of p rotations about the
nozzle axis (Eq. 4.3), inside the joint limits and free of collision. An edge joins consecutive
rungs when ‖Δq‖∞/Δt ≤ ξ (Eq. 4.4, Δt = ‖c_{j+1} − c_j‖/v̄) with weight ‖Δq‖₁ (Eq. 3.4) or the
weighted quadratic Δqᵀ W Δq (Eq. 4.5); distances are circular on joints that can turn a full
revolution ("winding effect", §4.3.1). The graph is a DAG, so the multi-source Dijkstra of the
thesis (all first-rung nodes as sources) is computed rung by rung, vectorized over node pairs;
:func:`reference_shortest_path` solves the same problem with scipy's Dijkstra (the tests' oracle).
Collisions are checked lazily: only nodes on the current best path are tested; where one collides,
the other nodes of its IK branch in that rung are tested too and the search resumes from the
earliest such rung. The result equals checking every node first (tested against that).
Waypoints whose rung has no usable node get a bounded tilt of the tool axis (:func:`deviate_axes`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from curvslice.kinematics import Robot, ik, rigid_inverse
from curvslice.workcell import Workcell, deposition_frames, flange_poses, rotation_samples

TWO_PI = 2 * np.pi


@dataclass
class LadderPath:
    """A shortest path through a ladder: node index per rung (-1 on empty rungs), segment id per
    rung (-1 on empty rungs; a new id after each disconnection), and the total edge cost."""

    node: np.ndarray
    segment: np.ndarray
    cost: float


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


def joint_steps(
    qa: np.ndarray, qb: np.ndarray, circular: np.ndarray, cost: str = "l1", weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Row by row from ``qa`` (n, 6) to ``qb`` (n, 6): the edge cost (Eq. 3.4 or 4.5, as
    :func:`edge_weights`) and ‖Δq‖∞, circular joints the short way round."""
    return _joint_costs(lambda j: qb[:, j] - qa[:, j], circular, cost, weights)


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


#: ξΔt (rad, < π: a window then never holds a node twice) from which :func:`sparse_edges` takes the
#: dense matrix, and node pairs up to which it takes it already from 1 rad (bunny layer 15 rungs,
#: ξΔt 1-1.5 rad: 960 x 960 nodes dense 25-27 ms, windowed 8-12 ms; 240 x 240 0.9-1.2 / 0.6-0.9 ms;
#: 120 x 120 0.21 / 0.24 ms; at 2.5 rad dense is faster at every size)
DENSE_WINDOW, DENSE_PAIRS = 2.0, 20000
#: every how many target nodes :func:`sparse_edges` counts the crowd of each joint on
CROWD_STEP = 4
#: rad between the joints' values in :func:`sparse_edges`' one sorted array (more than a joint's range plus 2ξΔt)
CROWD_SHIFT = 16.0


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
    if limit >= DENSE_WINDOW or (limit >= 1.0 and len(ka) * len(kb) <= DENSE_PAIRS):  # the dense matrix is as cheap
        w = edge_weights(qa, qb, dt, max_speed, circular, cost, weights)
        ia, ib = np.nonzero(np.isfinite(w))
        return ia, ib, w[ia, ib]
    # window on the joint with the fewest target nodes within ξΔt of each other (joint 1 is
    # useless when every rotation θ leaves the wrist in place), counted on every CROWD_STEP-th
    # node, all joints in one sorted array (each joint's values shifted apart by CROWD_SHIFT)
    v = np.sort(qb[kb[::CROWD_STEP]], axis=0) + CROWD_SHIFT * np.arange(qb.shape[1])
    flat = v.T.ravel()
    crowd = (np.searchsorted(flat, flat + limit, "right") - np.searchsorted(flat, flat - limit, "left")) \
        .reshape(qb.shape[1], -1).sum(axis=1)
    j0, j1 = (int(j) for j in np.argsort(crowd, kind="stable")[:2])
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
    # the next most discriminating joint drops most candidates before every joint is tested (its
    # difference is computed as in _joint_costs: a pair kept there passes this test too)
    d = np.abs(qb[ib, j1] - qa[ia, j1])
    if circular[j1]:
        np.minimum(d, TWO_PI - d, out=d)
    near = d <= limit
    ia, ib = ia[near], ib[near]
    total, largest = _joint_costs(lambda j: qb[ib, j] - qa[ia, j], circular, cost, weights)
    keep = largest <= limit
    return ia[keep], ib[keep], total[keep]


def _relax(
    valid: np.ndarray,
    best: np.ndarray,
    pred: np.ndarray,
    start: int,
    edges: Callable[[int], tuple[np.ndarray, np.ndarray, np.ndarray]],
    changed: int | None = None,
) -> None:
    """Fill ``best``/``pred`` for rungs ``start..m-1`` (rung start-1 already final). ``changed``: the
    last rung whose ``valid`` changed since ``best``/``pred`` were filled: a later rung that comes out
    bit-identical (e.g. a new motion's sources after a disconnection) leaves every rung after it as it
    was, so the relaxation stops there."""
    m, K = valid.shape
    reached = np.isfinite(best[max(start, 1) - 1]).any() if start > 0 else False
    for i in range(max(start, 0), m):
        row, back = best[i], pred[i]
        was = (row.copy(), back.copy()) if changed is not None and i > changed else None
        row.fill(np.inf)
        back.fill(-1)
        linked = False
        if i > 0 and reached:
            ia, ib, w = edges(i - 1)
            total = best[i - 1][ia] + w
            ok = valid[i][ib] & (total < np.inf)
            ia, ib, total = ia[ok], ib[ok], total[ok]
            if len(ib):
                np.minimum.at(row, ib, total)  # per target: least cost ...
                tie = total == row[ib]
                first = np.full(K, K)
                np.minimum.at(first, ib[tie], ia[tie])  # ... then first source
                hit = first < K
                back[hit] = first[hit]
                linked = True
        if not linked:
            row[valid[i]] = 0.0  # sources: a new motion starts here
            reached = bool(valid[i].any())
        if was is not None and np.array_equal(row, was[0]) and np.array_equal(back, was[1]):
            return  # rung i as before (same kind: linked or sources) and no change after it


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
    edge_cache: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
    edge_memo: EdgeMemo | None = None,
    nodes: np.ndarray | None = None,
) -> tuple[LadderPath, np.ndarray, int]:
    """Multi-source shortest path through a ladder (m rungs, K nodes, 6 joints), rung by rung.

    ``q`` (m, K, 6), ``valid`` (m, K), ``dt`` (m-1,) seconds. ``node_ok(rungs, nodes)`` (optional)
    returns which of the given nodes are usable (e.g. collision-free); it is called lazily on path
    nodes; where one is rejected, the other nodes of its ``group`` (labels (K,), e.g. the IK branch;
    default: the whole rung) in that rung are asked too. ``edge_cache`` (rung i -> edges i to i+1) may
    carry edges over from an earlier call on the same nodes (edges to nodes invalid now are ignored);
    ``edge_memo`` (:class:`EdgeMemo`) keeps the edges between two rungs by their content (nodes and
    Δt: the same edges whatever call asks, e.g. :class:`RungMemo`'s ``edges``). ``nodes`` (m, K)
    (default ``valid``): the nodes the edges are computed over, a superset of ``valid`` (e.g. every IK
    node, whatever is known of collisions; ``nodes | valid`` is used): edges touching a node not valid are never relaxed, so the
    path is the same, and the edges depend on ``q`` and ``nodes`` only (shared by calls that differ in
    ``valid``, through ``edge_cache`` or ``edge_memo``).
    Returns the path, the final validity mask, and how many nodes ``node_ok`` was asked about.
    """
    q = np.where((valid if nodes is None else nodes | valid)[..., None], q, np.nan)
    valid = valid.copy()
    m, K = valid.shape
    best = np.full((m, K), np.inf)
    pred = np.full((m, K), -1)
    cache = {} if edge_cache is None else edge_cache

    def edges(i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # edges only lose endpoints between passes (_relax masks invalid ones), so keep them
        if i not in cache:
            key = None
            if edge_memo is not None:
                key = hashlib.blake2b(q[i].tobytes() + q[i + 1].tobytes() + np.float64(dt[i]).tobytes(),
                                      digest_size=16).digest()
                found = edge_memo.get(key)
                if found is not None:
                    cache[i] = found
                    return cache[i]
            ia, ib, w = sparse_edges(q[i], q[i + 1], dt[i], max_speed, circular, cost, weights)
            cache[i] = (ia.astype(np.int32), ib.astype(np.int32), w)
            if key is not None:
                edge_memo.put(key, cache[i])
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
        if nodes is None:
            q[~valid] = np.nan
        _relax(valid, best, pred, int(bad.min()), edges, int(max(bad.max(), rr.max(initial=-1))))


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


def ladder(robot: Robot, cell: Workcell, positions: np.ndarray, normals: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """Rungs of IK nodes: q (m, 8p, 6) and valid (m, 8p) (solution exists and is inside the limits).

    Joints with more than one revolution of range keep angles in [-π, π); the others take the
    representative inside their limits (none: the node is dropped).
    """
    m = len(positions)
    q, ok = _limited_ik(robot, cell, flange_poses(cell, positions, normals, p).reshape(-1, 4, 4))
    return q.reshape(m, 8 * p, 6), ok.reshape(m, 8 * p)


#: bytes of edges an :class:`EdgeMemo` holds at most (the oldest are dropped first)
EDGE_MEMO_BYTES = 128 * 2**20


class EdgeMemo:
    """Edges between two rungs (ia, ib, w) by a digest of their content, for :func:`shortest_path`:
    at most ``budget`` bytes, the oldest dropped first (a dropped entry is computed again)."""

    def __init__(self, budget: int = EDGE_MEMO_BYTES) -> None:
        self.budget, self.size = budget, 0
        self.held: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def get(self, key: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        return self.held.get(key)

    def put(self, key: bytes, edges: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        if key in self.held:
            return
        self.held[key] = edges
        self.size += sum(a.nbytes for a in edges)
        while self.size > self.budget and self.held:
            self.size -= sum(a.nbytes for a in self.held.pop(next(iter(self.held))))


class RungMemo:
    """IK nodes of the rungs :func:`ladder` was asked for before, per waypoint and tool axis, at the
    finest p asked (the θ samples of p are every (p'/p)-th of p' ≥ p when p divides p', Eq. 4.3), and
    the edges between rungs (``edges``, for :func:`shortest_path`'s ``edge_memo``): a layer's
    searches ask the same rungs again (the finer ladder of a break, a stretch searched again with
    wider ends, the layer planned again after an axis deviation) and get the same nodes and edges
    without solving IK or testing node pairs again; only the θ samples not held yet are solved.
    One memo serves one workcell, robot, cost and step-time rule (a layer's plan)."""

    def __init__(self) -> None:
        self.held: dict[bytes, tuple[int, np.ndarray, np.ndarray]] = {}  # key -> p, q (p, 8, 6), ok (p, 8)
        self.edges = EdgeMemo()

    def ladder(self, robot: Robot, cell: Workcell, positions: np.ndarray, normals: np.ndarray,
               p: int) -> tuple[np.ndarray, np.ndarray]:
        """:func:`ladder`, remembered."""
        positions, normals = np.asarray(positions, float), np.asarray(normals, float)
        m = len(positions)
        q = np.full((m, p, 8, 6), np.nan)
        ok = np.zeros((m, p, 8), bool)
        need = np.ones((m, p), bool)
        keys = [a.tobytes() + b.tobytes() for a, b in zip(positions, normals)]
        for i, key in enumerate(keys):
            have = self.held.get(key)
            if have is None:
                continue
            ph, qh, okh = have
            if ph % p == 0:
                q[i], ok[i], need[i] = qh[:: ph // p], okh[:: ph // p], False
            elif p % ph == 0:
                q[i, :: p // ph], ok[i, :: p // ph], need[i, :: p // ph] = qh, okh, False
        rows = np.flatnonzero(need.any(axis=1))
        if len(rows):
            T = flange_poses(cell, positions[rows], normals[rows], p)  # (r, p, 4, 4)
            r, t = np.nonzero(need[rows])
            qn, okn = _limited_ik(robot, cell, T[r, t])
            q[rows[r], t], ok[rows[r], t] = qn, okn
            for i in rows:
                if self.held.get(keys[i], (0,))[0] < p:
                    self.held[keys[i]] = (p, q[i].copy(), ok[i].copy())
        return q.reshape(m, 8 * p, 6), ok.reshape(m, 8 * p)


def turned_frames(positions: np.ndarray, normals: np.ndarray, thetas: np.ndarray) -> np.ndarray:
    """Deposition frames (n, 4, 4) of waypoints each at its own rotation ``thetas`` (n,) rad about
    the nozzle axis (the θ convention of :func:`curvslice.workcell.deposition_frames`)."""
    T = deposition_frames(positions, normals, np.zeros(1))[:, 0]
    c, s = np.cos(thetas), np.sin(thetas)
    Rz = np.zeros((len(T), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    T[:, :3, :3] = T[:, :3, :3] @ Rz
    return T


def ladder_at(robot: Robot, cell: Workcell, positions: np.ndarray, normals: np.ndarray, thetas: np.ndarray,
              branch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One node per waypoint: IK branch ``branch`` (n,) at its own rotation ``thetas`` (n,) rad about
    the nozzle axis (Eq. 4.3, the θ convention of :func:`ladder`); q (n, 6) and whether it exists
    inside the limits (n,), represented as in :func:`ladder`."""
    T = turned_frames(positions, normals, thetas)
    return _limited_ik(robot, cell, cell.nozzle @ rigid_inverse(T) @ rigid_inverse(cell.platform_mount), branch)


def _limited_ik(robot: Robot, cell: Workcell, T: np.ndarray,
                branch: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """IK of flange poses (n, 4, 4): (n, 8, 6) and (n, 8) valid inside the joint limits (with
    ``branch`` (n,): that solution only, (n, 6) and (n,)); joints with more than one revolution of
    range keep angles in [-π, π), the others take the representative inside their limits (none:
    invalid)."""
    q, ok = ik(robot, T, branch=branch)
    lo, hi = cell.limits(robot)
    q = np.where(circular_joints(lo, hi), q, lo + (q - lo) % TWO_PI)
    ok &= ((q >= lo - 1e-12) & (q <= hi + 1e-12)).all(axis=-1)
    return q, ok


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
    left = np.flatnonzero(stuck)  # every stuck waypoint takes the first tilt that helps it, in the order
    for angle in angles:          # above; all of them are tried at once per tilt
        cands = np.stack([tilted_axes(axes[j], angle) for j in left], axis=1) if len(left) else []
        done = np.zeros(len(left), bool)
        for cand in cands:  # (n, 3) per azimuth
            rows = np.flatnonzero(~done & (cand[:, 2] > -1 + 1e-9))
            rows = rows[~blocked_rungs(collides, positions[left[rows]], cand[rows])]
            rows = rows[~hopeless_rungs(collides, positions[left[rows]], cand[rows], p)]
            if len(rows) == 0:
                continue
            q, ok = ladder(robot, cell, positions[left[rows]], cand[rows], p)
            rows = rows[ok.any(axis=1) if collides is None else _any_free(q, ok, collides)]
            axes[left[rows]] = cand[rows] / np.linalg.norm(cand[rows], axis=1, keepdims=True)
            deviation[left[rows]] = angle
            done[rows] = True
        left = left[~done]
    return axes, deviation


def blocked_rungs(collides: Callable[[np.ndarray], np.ndarray] | None, positions: np.ndarray,
                  normals: np.ndarray) -> np.ndarray:
    """(m,) bool: waypoints where every rotation θ of the nozzle collides whatever the arm does, by
    the predicate's own whole-rung test ``collides.blocked(nozzle frames)`` when it has one
    (:meth:`curvslice.collision.CollisionScene.blocked`); all False otherwise."""
    test = getattr(collides, "blocked", None)
    if test is None or not len(positions):
        return np.zeros(len(positions), bool)
    return np.asarray(test(deposition_frames(positions, normals, np.zeros(1))[:, 0]), bool)


def held_frames(collides: Callable[[np.ndarray], np.ndarray] | None, positions: np.ndarray, normals: np.ndarray,
                thetas: np.ndarray) -> np.ndarray:
    """(n,) bool: waypoints (positions, axes (n, 3)) at their own rotation ``thetas`` (n,) about the
    nozzle axis (Eq. 4.3) whose nozzle frame alone puts a static body in contact with the carried
    platform or part (``collides.held_blocked``): every IK branch there collides. All False without
    that test."""
    test = getattr(collides, "held_blocked", None)
    if test is None or not len(positions):
        return np.zeros(len(positions), bool)
    return np.asarray(test(turned_frames(positions, normals, thetas)), bool)


def hopeless_rungs(collides: Callable[[np.ndarray], np.ndarray] | None, positions: np.ndarray,
                   normals: np.ndarray, p: int) -> np.ndarray:
    """(m,) bool: waypoints where at each of the p rotations θ (Eq. 4.3) the nozzle frame alone
    puts a static body in contact with the carried platform or part (the predicate's per-frame test
    ``collides.held_blocked(frames)``, :meth:`curvslice.collision.CollisionScene.held_blocked`): then
    every node of the rung collides, at p and at every p whose θ samples nest in it; all False
    without that test. θ samples are tried one at a time over the rungs still blocked."""
    out = np.zeros(len(positions), bool)
    if getattr(collides, "held_blocked", None) is None or not len(positions):
        return out
    left = np.arange(len(positions))
    for theta in rotation_samples(p):
        left = left[held_frames(collides, positions[left], normals[left], np.full(len(left), theta))]
        if not len(left):
            return out
    out[left] = True
    return out


def _any_free(q: np.ndarray, ok: np.ndarray, collides: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """(n,) whether some node of each rung (q (n, K, 6), ok (n, K)) is collision-free: nodes asked
    in batches over all rungs that doubling in size, a rung leaving once a free node is found."""
    n = len(q)
    free = np.zeros(n, bool)
    order = [np.flatnonzero(row) for row in ok]
    start, size = 0, 8
    while True:
        rr = [(r, order[r][start:start + size]) for r in range(n) if not free[r] and start < len(order[r])]
        if not rr:
            return free
        rungs = np.concatenate([np.full(len(k), r) for r, k in rr])
        nodes = np.concatenate([k for _, k in rr])
        clear = ~collides(q[rungs, nodes])
        free[rungs[clear]] = True
        start, size = start + size, 2 * size
