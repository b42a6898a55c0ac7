"""Limits a real controller has (thesis §4.3.2, Eq. 4.2's last line): time-scaling of a trajectory until
every row meets a_max, j_max and ξ, and time-optimal jerk-limited rest-to-rest moves between motion
segments (Ruckig, the standard online trajectory generator).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from curvslice.derivatives import derivatives, stencils
from curvslice.kinematics import Robot
from curvslice.workcell import Workcell

if TYPE_CHECKING:
    from curvslice.jerk import JerkSettings


@dataclass
class Limits:
    """Per-joint limits of Eq. 4.2 (rad, rad/s, rad/s², rad/s³)."""

    lower: np.ndarray
    upper: np.ndarray
    speed: float  # ξ (Eq. 4.4), on ‖Δq‖∞/Δt as the graph search and the verifier use it
    acceleration: np.ndarray
    jerk: np.ndarray

    def beyond(self, q: np.ndarray) -> np.ndarray:
        """Rows of ``q`` (n, 6) outside the joint limits."""
        return ((q < self.lower - 1e-9) | (q > self.upper + 1e-9)).any(axis=1)

    @classmethod
    def of(cls, robot: Robot, cell: Workcell) -> Limits:
        lo, hi = cell.limits(robot)
        return cls(lo, hi, cell.max_joint_speed, np.asarray(cell.max_joint_acceleration, float),
                   np.asarray(cell.max_joint_jerk, float))


def time_scale(q: np.ndarray, t: np.ndarray, segment: np.ndarray, limits: Limits,
               settings: JerkSettings) -> tuple[np.ndarray, int, int]:
    """Local time-scaling: lengthen every step faster than ξ (‖Δq‖∞/Δt, Eq. 4.4) and the steps of the
    stencil of every row with |q̈| > a_max or |q⃛| > j_max by the factor that brings it under (acceleration ∝ 1/s², jerk ∝ 1/s³), spread to
    neighbouring steps by at most ``scale_spread`` per step so the stretch itself stays smooth;
    repeated until every row meets the limits. The path and each step's E are unchanged (lower feed).

    Returns the new times (segment starts keep their offsets to the previous row), the rounds used
    and the rows still over a limit (0 unless ``scaling_rounds`` ran out)."""
    t = np.asarray(t, float).copy()
    n = len(t)
    if n < 2:
        return t, 0, 0
    seg = np.asarray(segment)
    inside = seg[1:] == seg[:-1]
    margin = settings.limit_margin
    c = np.log(settings.scale_spread)
    idx = np.arange(n - 1)
    _, seg_rank = np.unique(seg[:-1], return_inverse=True)
    _, seg_of = np.unique(seg, return_inverse=True)
    big = 1e6
    rounds = 0
    start, w = stencils(t, seg)
    win = q[np.minimum(start[:, None] + np.arange(5), n - 1)]
    for rounds in range(1, settings.scaling_rounds + 1):
        acc = np.einsum("nk,nkj->nj", w[:, 1], win)
        jerk = np.einsum("nk,nkj->nj", w[:, 2], win)
        over_a = np.abs(acc) / limits.acceleration
        over_j = np.abs(jerk) / limits.jerk
        speed = np.abs(np.diff(q, axis=0)).max(axis=1) / np.diff(t) / limits.speed
        over_v = np.where(inside, speed, 0.0)
        if (over_a <= 1.0 + 1e-9).all() and (over_j <= 1.0 + 1e-9).all() and (over_v <= 1.0 + 1e-9).all():
            return t, rounds - 1, 0
        f = np.maximum(np.sqrt(over_a.max(axis=1) / margin), np.cbrt(over_j.max(axis=1) / margin))
        f = np.maximum(f, 1.0)
        # a row's stencil covers steps start..start+3 (within its segment)
        step_f = np.ones(n - 1)
        for k in range(4):
            s = np.minimum(start + k, n - 2)
            np.maximum.at(step_f, s, np.where(inside[s], f, 1.0))
        step_f = np.maximum(step_f, np.where(over_v > 1.0, over_v / margin, 1.0))  # ξ (Eq. 4.4)
        # spread the stretch: log f decays by c per step, never across a segment boundary
        lf = np.log(step_f)
        fwd = np.maximum.accumulate(lf + c * idx + big * seg_rank) - c * idx - big * seg_rank
        rev_rank = seg_rank.max() - seg_rank
        bwd = (np.maximum.accumulate((lf - c * idx + big * rev_rank)[::-1])[::-1] + c * idx - big * rev_rank)
        lf = np.maximum(lf, np.maximum(fwd, bwd))
        dt = np.diff(t)
        dt = np.where(inside, dt * np.exp(lf), dt)
        t = t[0] + np.r_[0.0, np.cumsum(dt)]
        # new stencil weights only in the segments stretched (the others' steps are as they were)
        hot = np.zeros(seg_of.max() + 1, bool)
        hot[seg_of[:-1][(lf > 0) & inside]] = True
        sub = np.flatnonzero(hot[seg_of])
        w[sub] = stencils(t[sub], seg[sub])[1]
    acc = np.einsum("nk,nkj->nj", w[:, 1], win)
    jerk = np.einsum("nk,nkj->nj", w[:, 2], win)
    left = int(((np.abs(acc) > limits.acceleration * (1 + 1e-9)) | (np.abs(jerk) > limits.jerk * (1 + 1e-9))).any(axis=1).sum())
    speed = np.abs(np.diff(q, axis=0)).max(axis=1) / np.diff(t)
    left += int((inside & (speed > limits.speed * (1 + 1e-9))).sum())
    return t, rounds, left


def rest_to_rest(qa: np.ndarray, qb: np.ndarray, limits: Limits) -> float:
    """Duration (s) of the time-optimal jerk-limited joint move from rest at qa to rest at qb
    (Ruckig, all joints synchronized), within ξ, a_max and j_max."""
    zero = np.zeros(len(qa))
    return state_to_state(qa, zero, zero, qb, zero, zero, limits)


def state_to_state(qa: np.ndarray, va: np.ndarray, aa: np.ndarray, qb: np.ndarray, vb: np.ndarray, ab: np.ndarray,
                   limits: Limits) -> float:
    """Duration (s) of the time-optimal jerk-limited joint move (Ruckig, all joints synchronized) from
    the state (qa, q̇a, q̈a) to (qb, q̇b, q̈b), within ξ, a_max and j_max; a joint whose end state
    reaches a speed over ξ (|q̇| + q̈²/2j_max: the polynomial of Eq. 4.7 at a segment's end row, while
    ξ bounds its steps) may move that fast."""
    from ruckig import InputParameter, Result, Ruckig, RuckigError, Trajectory

    inp = InputParameter(6)
    inp.current_position, inp.current_velocity, inp.current_acceleration = (list(map(float, v)) for v in (qa, va, aa))
    inp.target_position, inp.target_velocity, inp.target_acceleration = (list(map(float, v)) for v in (qb, vb, ab))
    inp.max_acceleration = list(map(float, np.maximum(limits.acceleration, np.maximum(np.abs(aa), np.abs(ab)) * (1 + 1e-9))))
    inp.max_jerk = list(map(float, limits.jerk))
    # the speed an end state reaches (or came from) while its acceleration ramps to 0 at j_max
    reach = np.maximum(np.abs(va) + aa**2 / (2 * limits.jerk), np.abs(vb) + ab**2 / (2 * limits.jerk))
    speed = np.maximum(limits.speed, reach * (1 + 1e-6))
    traj = Trajectory(6)
    for _ in range(20):  # Ruckig's own reach test is a little stricter than the estimate: widen where it needs
        inp.max_velocity = list(map(float, speed))
        try:
            result = Ruckig(6).calculate(inp, traj)
            break
        except RuckigError:
            speed = np.where(reach * (1 + 1e-6) > limits.speed, speed * 1.02, speed)
    else:
        raise RuntimeError("ruckig could not plan a move between segments: an end state beyond its limits")
    if result not in (Result.Working, Result.Finished):
        raise RuntimeError(f"ruckig could not plan a move between segments: {result}")
    return float(traj.duration)


def end_states(q: np.ndarray, t: np.ndarray, segment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joint velocity and acceleration (n, 6) at every row by Eq. 4.7-4.10 within its segment: at a
    segment's first and last row, the state a move between segments starts from or must reach."""
    vel, acc, _ = derivatives(q, t, segment)
    return vel, acc


def retime_moves(q: np.ndarray, t: np.ndarray, segment: np.ndarray, limits: Limits, min_step: float) -> tuple[np.ndarray, float]:
    """Times where every move between segments takes Ruckig's time-optimal duration from the state
    the segment ends in to the state the next one starts in (Eq. 4.7-4.10 at those rows: the segments
    do not end at rest), at least ``min_step``; steps inside segments are kept. Returns the times and
    the moves' total (s)."""
    n = len(t)
    if n < 2:
        return np.asarray(t, float).copy(), 0.0
    dt = np.diff(t)
    moves = np.flatnonzero(segment[1:] != segment[:-1])
    vel, acc = end_states(q, t, segment) if len(moves) else (None, None)
    total = 0.0
    for i in moves:
        dt[i] = max(state_to_state(q[i], vel[i], acc[i], q[i + 1], vel[i + 1], acc[i + 1], limits), min_step)
        total += dt[i]
    return t[0] + np.r_[0.0, np.cumsum(dt)], total
