"""Joint derivatives at waypoints on real, non-uniform times (thesis §4.3.2, Eq. 4.7-4.11) and the
evidence of Eq. 4.2 on a trajectory.

At every row, the degree-4 polynomial through the five nearest rows of its motion segment (centred where
the segment allows, Eq. 4.7); its derivatives at t_i are fixed linear combinations of the five joint values
(the inverse Vandermonde matrix of Eq. 4.9), assembled into sparse operators D1, D2, D3 (Eq. 4.10). With a
constant step h, D3 is Eq. 4.11. Used by the jerk filter (:mod:`curvslice.jerk`) and its time-scaling;
the verifier re-derives the same figures with its own solve.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def segment_bounds(segment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last row (inclusive) of the segment of every row; rows are grouped by equal
    consecutive ``segment`` values."""
    n = len(segment)
    start = np.r_[True, segment[1:] != segment[:-1]] if n else np.zeros(0, bool)
    first = np.maximum.accumulate(np.where(start, np.arange(n), 0))
    end = np.r_[segment[1:] != segment[:-1], True] if n else np.zeros(0, bool)
    last = np.minimum.accumulate(np.where(end, np.arange(n), n)[::-1])[::-1]
    return first, last


def stencils(t: np.ndarray, segment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4.7-4.9 at every row: the first row of its 5-row window (n,) and the weights (n, 3, 5) of
    q̇, q̈, q⃛ at t_i on the window's rows (:func:`_fornberg`). The window is centred (i-2..i+2) where the segment allows,
    else the 5 nearest rows of the segment; a segment of L < 5 rows uses its L rows (degree L-1)."""
    t = np.asarray(t, float)
    n = len(t)
    first, last = segment_bounds(np.asarray(segment))
    length = last - first + 1
    start = np.clip(np.arange(n) - 2, first, np.maximum(last - 4, first))
    weights = np.zeros((n, 3, 5))
    for L in np.unique(length):
        rows = np.flatnonzero(length == L)
        k = int(min(L, 5))
        if k < 2:
            continue
        idx = start[rows, None] + np.arange(k)
        h = (t[idx[:, -1]] - t[idx[:, 0]]) / (k - 1)  # scale: conditioning (times in units of h)
        c = _fornberg((t[idx] - t[rows, None]) / h[:, None], min(k - 1, 3))
        for r in range(1, min(k, 4)):
            weights[rows, r - 1, :k] = c[:, :, r] / h[:, None] ** r
    return start, weights


def _fornberg(x: np.ndarray, m: int) -> np.ndarray:
    """Weights (n, k, m+1) of the derivatives 0..m at τ = 0 of the polynomial through the k nodes x
    (n, k) of each row: r! × the inverse Vandermonde matrix's row r of Eq. 4.9 (B_j^(r)(0), Eq. 4.8),
    by Fornberg's recurrence (1988) on all rows at once instead of n inversions."""
    n, k = x.shape
    C = np.zeros((n, k, m + 1))
    C[:, 0, 0] = 1.0
    c1, c4 = np.ones(n), x[:, 0].copy()
    for i in range(1, k):
        top = min(i, m)
        c2, c5, c4 = np.ones(n), c4, x[:, i].copy()
        for j in range(i):
            c3 = x[:, i] - x[:, j]
            c2 = c2 * c3
            if j == i - 1:
                for d in range(top, 0, -1):
                    C[:, i, d] = c1 * (d * C[:, i - 1, d - 1] - c5 * C[:, i - 1, d]) / c2
                C[:, i, 0] = -c1 * c5 * C[:, i - 1, 0] / c2
            for d in range(top, 0, -1):
                C[:, j, d] = (c4 * C[:, j, d] - d * C[:, j, d - 1]) / c3
            C[:, j, 0] = c4 * C[:, j, 0] / c3
        c1 = c2
    return C


def derivative_operators(t: np.ndarray, segment: np.ndarray) -> tuple[sp.csr_matrix, sp.csr_matrix, sp.csr_matrix]:
    """Sparse D1, D2, D3 (n × n) with q̇ = D1 q, q̈ = D2 q, q⃛ = D3 q at every row (Eq. 4.10)."""
    n = len(t)
    start, w = stencils(t, segment)
    cols = np.minimum(start[:, None] + np.arange(5), max(n - 1, 0))
    rows = np.repeat(np.arange(n), 5)
    return tuple(sp.csr_matrix((w[:, r].ravel(), (rows, cols.ravel())), shape=(n, n)) for r in range(3))


def derivatives(q: np.ndarray, t: np.ndarray, segment: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint velocity, acceleration and jerk (n, 6) at every row by Eq. 4.7-4.10, per segment."""
    D1, D2, D3 = derivative_operators(t, segment)
    return D1 @ q, D2 @ q, D3 @ q


def uniform_jerk(q: np.ndarray, h: float) -> np.ndarray:
    """Eq. 4.11: q⃛ at the interior rows 2..n-3 of a path sampled every h seconds."""
    return (q[4:] - 2 * q[3:-1] + 2 * q[1:-3] - q[:-4]) / (2 * h**3)


def total_squared_jerk(jerk: np.ndarray, weights: np.ndarray | None = None) -> float:
    """J of Eq. 4.2: Σ_i q⃛_iᵀ W q⃛_i."""
    w = np.ones(jerk.shape[1]) if weights is None else np.asarray(weights, float)
    return float((jerk**2 @ w).sum())


def motion_stats(q: np.ndarray, t: np.ndarray, segment: np.ndarray, weights: np.ndarray | None = None) -> dict:
    """Evidence of Eq. 4.2 on a trajectory: max |q̈| and |q⃛| per joint, J, print time."""
    return group_stats(q, t, segment, np.zeros(len(q), int), weights).get(0, _stats(np.zeros((0, 6)), np.zeros((0, 6)), np.zeros(0), None))


def group_stats(q: np.ndarray, t: np.ndarray, segment: np.ndarray, group: np.ndarray,
                weights: np.ndarray | None = None) -> dict[int, dict]:
    """:func:`motion_stats` of the rows of each value of ``group`` (n,) (e.g. the layers), from one
    derivative pass: no segment may span two groups (the stencils then stay inside a group)."""
    if len(q) == 0:
        return {}
    _, acc, jerk = derivatives(q, t, segment)
    values, inv = np.unique(group, return_inverse=True)
    return {int(v): _stats(acc[inv == i], jerk[inv == i], t[inv == i], weights) for i, v in enumerate(values)}


def combined_stats(parts, t: np.ndarray) -> dict:
    """:func:`motion_stats` of a whole trajectory (times ``t``) from those of its groups (:func:`group_stats`)."""
    parts = list(parts)
    if not parts or len(t) == 0:
        return _stats(np.zeros((0, 6)), np.zeros((0, 6)), np.zeros(0), None)
    return {
        "max_acceleration": [max(p["max_acceleration"][j] for p in parts) for j in range(6)],
        "max_jerk": [max(p["max_jerk"][j] for p in parts) for j in range(6)],
        "total_squared_jerk": float(f"{sum(p['total_squared_jerk'] for p in parts):.6g}"),
        "time_s": round(float(t[-1] - t[0]), 3),
    }


def _stats(acc: np.ndarray, jerk: np.ndarray, t: np.ndarray, weights: np.ndarray | None) -> dict:
    if len(t) == 0:
        return {"max_acceleration": [0.0] * 6, "max_jerk": [0.0] * 6, "total_squared_jerk": 0.0, "time_s": 0.0}
    return {
        "max_acceleration": [round(float(v), 4) for v in np.abs(acc).max(axis=0)],
        "max_jerk": [round(float(v), 4) for v in np.abs(jerk).max(axis=0)],
        "total_squared_jerk": float(f"{total_squared_jerk(jerk, weights):.6g}"),
        "time_s": round(float(t[-1] - t[0]), 3),
    }
