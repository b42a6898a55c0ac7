"""Jerk-optimized joint trajectories (thesis §4.3.2, Algorithm 6) within a real controller's limits.

The graph search of §4.3.1 (:mod:`curvslice.motion`) picks, per waypoint, one of p sampled
rotations θ about the nozzle axis (Eq. 4.3): its joint path minimizes the transition cost (Eq. 4.6),
not the jerk. This module improves it:

1. **Derivatives at waypoints** (Eq. 4.7-4.10): at every row, the degree-4 polynomial through the
   five nearest rows of its motion segment (centred where the segment allows, Eq. 4.7) on the real,
   non-uniform times; its derivatives at t_i are fixed linear combinations of the five joint values
   (the inverse Vandermonde matrix of Eq. 4.9). They are assembled into sparse operators D1, D2, D3
   (n × n), so q̇ = D1 q, q̈ = D2 q, q⃛ = D3 q. With a constant step h, D3 is Eq. 4.11.
2. **The redundancy as the unknown**: every row keeps its IK branch and is parametrized by its
   rotation θ_i about the nozzle axis, q_i = IK_b(x_i, θ_i) (Eq. 4.3), and by a tilt (α_i, β_i) of
   its tool axis bounded by ``max_tilt_deg`` (the workcell's bounded axis deviation; the
   orientations' own zig-zags, which θ cannot absorb, otherwise dominate the slow-downs). Every
   discrete-time constraint x_i = f(q_i) of Eq. 4.2/4.12 then holds by construction, to IK precision.
3. **Global filter** (Eq. 4.12 with the window = the whole segment): projected, damped Gauss-Newton
   on J = Σ‖q⃛_i‖²_W (Eq. 4.2) plus quadratic penalties on the joint limits, on ξ (‖Δq‖∞/Δt,
   Eq. 4.4) and on a_max; all segments of a print form one sparse banded system (stencils never
   cross a segment); a step is kept per segment only where it lowers that segment's cost, and a
   segment that stopped gaining leaves the system. A few steps on every row, then only on the
   stretches still over a limit. Then fcl checks every moved row (§4.3.3); a colliding one is
   projected (Eq. 4.13) or goes back to its last collision-free pose and its neighbours are re-filtered.
4. **Algorithm 6** (§4.3.2): at the free row of largest ‖q⃛‖_W above j_max, the local problem
   Eq. 4.12 over θ_{c-d..c+d} by SQP (scipy's SLSQP) with the joint limits, ξ and a_max as hard
   constraints; d = 5, +5 up to d_max = 20 while it fails; a window that still fails is locked, a
   success frees it again; at most ``max_iterations`` windows per segment (off by default, see
   :class:`JerkSettings`).
5. **Limits a controller has** (Eq. 4.2's last line): where the redundancy cannot bring |q̈| ≤ a_max
   and |q⃛| ≤ j_max, the stretch is slowed down (:func:`time_scale`): the steps around the row are
   lengthened (same path, same E per step, lower feed) until every row meets them.
6. **Moves between segments**: time-optimal, jerk-limited motions by Ruckig from the state (q, q̇, q̈
   by Eq. 4.7-4.10) the segment ends in to the state the next one starts in
   (:func:`curvslice.time_scaling.state_to_state`; segments do not end at rest); the time between the
   two rows is that move's duration.

Deviation from the thesis: J_local sums the jerk of rows a-2..b+2 (every row whose stencil holds a
variable) instead of a..b, so a window cannot push jerk onto its margin.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.linalg import solveh_banded
from scipy.optimize import minimize

from curvslice.derivatives import (combined_stats, derivative_operators, derivatives, group_stats, motion_stats,
                                   segment_bounds, stencils)
from curvslice.kinematics import Robot, fk, ik, joint_placements, rigid_inverse
from curvslice.motion import PrintMotion
from curvslice.orientation import angles_between
from curvslice.time_scaling import Limits, rest_to_rest, retime_moves, time_scale
from curvslice.workcell import Workcell, deposition_frames


@dataclass(frozen=True)
class JerkSettings:
    """Parameters of the jerk stage (defaults: §4.3.2 where the thesis gives them)."""

    window: int = 5  # d, the margin of a local path (§4.3.2)
    window_step: int = 5  # d grows by this when the local filter fails (Alg. 6 line 12)
    max_window: int = 20  # d_max (§4.3.2)
    # Alg. 6 windows per segment. The thesis uses 100 per path; on the kitten's first 10 layers
    # after the global filter below, 69 windows took 71 s CPU (~1 s each, SLSQP) and lowered J by
    # 1.0 % (alone on the graph path: 90 windows, 83 s, -2.0 %), so the default skips them; 100
    # runs the thesis's Algorithm 6.
    max_iterations: int = 0
    # Gauss-Newton steps of the whole-segment filter (0 = Alg. 6 only); kitten layers 66-83: 30 (8 on every row)
    # took 4.2 s CPU for J -99.78 %, +0.54 % time; 22 (6): 3.7 s, -99.72 %, +0.59 %, but the dome of tests/test_jerk.py
    # then keeps a projected row's spike (J -83 %)
    global_iterations: int = 30
    whole_iterations: int = 8  # ... of them on every row; the rest only near rows over a limit
    focus_rounds: int = 3  # the penalized rows are found again this many times during the rest
    focus_margin: int = 16  # rows around a penalized stencil that vary with it
    focus_level: float = 1.0  # ... over this fraction of a limit
    penalty: float = 1e4  # weight of the squared excesses over the joint limits and ξ in the global filter
    acceleration_penalty: float = 1e4  # ... over a_max (lowers what the time-scaling must add)
    # ... over j_max: J alone spreads the effort over all rows while the time-scaling answers to the largest; on
    # bunny layers 34-37 this penalty cut the time the time-scaling adds from 8.6 % to 5.0 % (1e4: 6.7 %, too stiff)
    jerk_penalty: float = 100.0
    limit_margin: float = 0.97  # the filters aim at this fraction of ξ and a_max, the time-scaling of a_max, j_max
    max_step: float = 0.3  # rad, largest change of one θ in one Gauss-Newton step (stays on the IK branch)
    # first Levenberg-Marquardt damping of a segment (÷3 on a kept step, ×4 on a rejected one): 1e-3 overshot
    # into collisions (kitten layers 66-83: 143 rows projected, 1.4 % time-scaling, 139 steps; 0.1: 22, 0.5 %, 83)
    damping: float = 0.1
    refilter_damping: float = 1e-3  # ... in the focus and collision rounds (a reverted row's spike needs full steps)
    refilter_iterations: int = 7  # Gauss-Newton steps of each collision round's re-filter
    # a segment is done when a kept step lowers its cost by less than this fraction (the steps go on
    # over the others only)
    converged: float = 1e-3
    shrink: float = 0.7  # the filter's problem is cut down to the segments still converging below this share
    # filter, fcl-check the moved rows (§4.3.3), fix each colliding row half-way back to its last
    # collision-free pose (or at it), re-filter the 10 rows around it; repeat
    collision_rounds: int = 3
    sqp_iterations: int = 5  # SQP steps per local problem of Alg. 6
    projection_step: float = np.pi / 500  # rad, the θ re-sampling of Eq. 4.13 (§4.3.3)
    projection_batch: int = 16  # candidates per colliding row fcl-checks at a time, nearest first
    projection_checks: int = 256  # candidates per row at most; a row without a free one goes back to its safe pose
    scaling_rounds: int = 80  # rounds of local time-scaling at most
    # neighbouring steps' stretch factors differ by at most this ratio (the feed changes by at most 30 % a step;
    # 1.15 stretched 2.2x more rows than needed: bunny layers 34-37 +5.0 % -> +3.7 % with the j_max penalty)
    scale_spread: float = 1.3
    max_tilt_deg: float = 8.0  # the global filter may tilt a tool axis this far (0 = θ only; within the workcell's bound)
    tilt_weight: float = 1.0  # μ: pull of a tilt (rad²) back to the planned axis, against J (rad²/s⁶)
    fd_step: float = 1e-6  # rad, finite-difference step of q(θ) in Alg. 6 for dq/dθ
    weights: tuple[float, ...] | None = None  # diagonal of W (Eq. 4.2); None = I


# ---------------------------------------------------------------------------------------------
# q(θ): the redundancy about the nozzle axis (Eq. 4.3) on a fixed IK branch


@dataclass
class Redundancy:
    """Rows parametrized by z = (θ, α, β): the rotation θ about the nozzle axis (Eq. 4.3) and a tilt
    (α, β) of the axis t_i towards two fixed perpendicular directions (the bounded axis deviation of
    the workcell), on each row's fixed IK branch. z = 0 tilt is the row's own axis."""

    robot: Robot
    cell: Workcell
    positions: np.ndarray  # (n, 3) waypoint c_i in the model frame
    axes: np.ndarray  # (n, 3) the rows' tool axes t_i
    basis: np.ndarray  # (n, 2, 3) two unit directions perpendicular to t_i
    branch: np.ndarray  # (n,) IK branch, -1 where none reproduces the row (the row stays fixed)

    def subset(self, rows: np.ndarray, branch: np.ndarray | None = None) -> Redundancy:
        """The parametrization of ``rows`` only (with ``branch`` (n,) instead of the own, if given)."""
        b = self.branch if branch is None else branch
        return Redundancy(self.robot, self.cell, self.positions[rows], self.axes[rows], self.basis[rows], b[rows])

    def axis(self, z: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Unit tool axes of ``rows`` at tilt z[:, 1:] (rows of z without tilt keep t_i)."""
        n = self.axes[rows].copy()
        if z.shape[1] > 1:
            n += np.einsum("ik,ikj->ij", z[:, 1:3], self.basis[rows])
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def flange(self, z: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """T_E^B of ``rows`` at z (Eq. 2.3 with T_O^P = [R0(t) Rz(θ), c], Eq. 4.3)."""
        T = deposition_frames(self.positions[rows], self.axis(z, rows), np.zeros(1))[:, 0]
        c, s = np.cos(z[:, 0]), np.sin(z[:, 0])
        Rz = np.zeros((len(rows), 3, 3))
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
        T[:, :3, :3] = T[:, :3, :3] @ Rz
        return self.cell.nozzle @ rigid_inverse(T) @ rigid_inverse(self.cell.platform_mount)

    def joints(self, z: np.ndarray, rows: np.ndarray, near: np.ndarray, check: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """q (k, 6) on each row's branch at z ((k,) θ only, or (k, 3) θ and tilt), unwound to the
        turn nearest ``near``, and whether that branch exists there (``check``: and reproduces the
        pose by FK, see :func:`curvslice.kinematics.ik`)."""
        z = np.asarray(z, float)
        z = z[:, None] if z.ndim == 1 else z
        T = self.flange(z, rows)
        # the row's own branch only (an eighth of the full solve; -1 rows are fixed, any branch will do)
        q, ok = ik(self.robot, T, check=False, branch=self.branch[rows] % 8, chunk=CHUNK)
        if check:  # ik's FK re-check (its tolerances), on the one branch kept
            back = fk(self.robot, q)
            ok &= (np.linalg.norm(back[:, :3, 3] - T[:, :3, 3], axis=1) <= 1e-3) & \
                (np.abs(back[:, :3, :3] - T[:, :3, :3]).max(axis=(1, 2)) <= 1e-6)
        q = near + (q - near + np.pi) % (2 * np.pi) - np.pi
        return q, ok


#: rows per batch of the filter's kinematics (one branch per row): the stacked 4x4 products stay in
#: cache (kitten block of 19k rows: joint_rates 31 % and the one-branch IK 36 % faster than at once / by 512)
CHUNK = 4096


def joint_rates(red: Redundancy, z: np.ndarray, rows: np.ndarray, q: np.ndarray) -> np.ndarray:
    """dq/dz (k, 6, m) at the rows' poses q: the flange's spatial twist per unit of each variable
    mapped through the inverse of the arm's spatial Jacobian (columns [p_j × a_j; a_j] from the joint
    frames) — no IK needed. z moves the deposition frame T_O^P = [R0(t) Rz(θ), c] about its origin,
    so the flange turns about the nozzle tip p_n (Eq. 2.3): twist [p_n × ω; ω], ω = R_n ω_O with
    ω_O = -e_z for θ and -Rz(θ)ᵀ R0(t)ᵀ ω_t for a tilt, ω_t the angular velocity of the minimal
    rotation R0 (+Z to t) as t moves by ṫ: t × ṫ - ((t × ṫ)·e_z / (1 + t_z)) t (its spin about t
    keeps R0's x axis from turning about +Z). In batches of :data:`CHUNK` rows."""
    if len(z) > CHUNK:
        return np.concatenate([joint_rates(red, z[s:s + CHUNK], rows[s:s + CHUNK], q[s:s + CHUNK])
                               for s in range(0, len(z), CHUNK)])
    F = joint_placements(red.robot, q)
    axis = red.robot.chain[0][1:]
    a = np.stack([F[:, j + 1, :3, axis[j]] for j in range(6)], axis=2)  # (k, 3, 6)
    p = F[:, 1:, :3, 3].transpose(0, 2, 1)
    J = np.concatenate([np.cross(p, a, axis=1), a], axis=1)  # (k, 6, 6) spatial Jacobian
    m, k = z.shape
    w = np.zeros((m, 3, k))  # ω_O per variable, deposition frame
    w[:, 2, 0] = -1.0
    if k > 1:
        b = red.basis[rows]  # (m, 2, 3): t(z) = n / |n|, n = t_i + α b_1 + β b_2
        n = red.axes[rows] + np.einsum("ik,ikj->ij", z[:, 1:3], b)
        size = np.linalg.norm(n, axis=1)
        t = n / size[:, None]
        dt = (b - t[:, None] * np.einsum("ikj,ij->ik", b, t)[..., None]) / size[:, None, None]  # (m, 2, 3)
        spin = np.cross(t[:, None], dt)
        spin -= (spin[..., 2] / (1.0 + t[:, 2, None]))[..., None] * t[:, None]
        R0 = deposition_frames(np.zeros((m, 3)), t, np.zeros(1))[:, 0, :3, :3]
        vee = -np.einsum("iab,ika->ikb", R0, spin)  # -R0ᵀ ω_t per tilt variable (m, 2, 3)
        c, s = np.cos(z[:, 0])[:, None], np.sin(z[:, 0])[:, None]
        w[:, 0, 1:] = c * vee[..., 0] + s * vee[..., 1]  # Rz(θ)ᵀ vee
        w[:, 1, 1:] = -s * vee[..., 0] + c * vee[..., 1]
        w[:, 2, 1:] = vee[..., 2]
    Rn, pn = red.cell.nozzle[:3, :3], red.cell.nozzle[:3, 3]
    omega = Rn @ w  # (m, 3, k), base frame
    twist = np.concatenate([np.cross(pn[None, :, None], omega, axis=1), omega], axis=1)  # (m, 6, k)
    with np.errstate(all="ignore"):
        try:
            out = np.linalg.solve(J, twist)
        except np.linalg.LinAlgError:  # an exactly singular row: solve one by one
            out = np.array([np.linalg.lstsq(Jk, tk, rcond=1e-12)[0] for Jk, tk in zip(J, twist)])
    return np.nan_to_num(out)


def redundancy(robot: Robot, cell: Workcell, positions: np.ndarray, normals: np.ndarray,
               q: np.ndarray, tol: float = 1e-6) -> tuple[Redundancy, np.ndarray]:
    """θ_i and IK branch of each row q_i (the inverse of Eq. 2.3 and 4.3): returns the
    parametrization and θ (n,). Rows no branch reproduces within ``tol`` rad get branch -1."""
    positions = np.asarray(positions, float)
    axes = np.asarray(normals, float) / np.linalg.norm(normals, axis=1, keepdims=True)
    frames = deposition_frames(positions, axes, np.zeros(1))[:, 0, :3, :3]
    T_OP = rigid_inverse(fk(robot, q) @ cell.platform_mount) @ cell.nozzle
    M = np.swapaxes(frames, 1, 2) @ T_OP[:, :3, :3]  # = Rz(θ)
    theta = np.arctan2(M[:, 1, 0], M[:, 0, 0])
    basis = np.swapaxes(frames[:, :, :2], 1, 2)  # x and y of the θ = 0 frame: perpendicular to t_i
    red = Redundancy(robot, cell, positions, axes, basis, np.zeros(len(q), int))
    cand, ok = ik(robot, red.flange(theta[:, None], np.arange(len(q))))
    gap = np.abs((cand - q[:, None] + np.pi) % (2 * np.pi) - np.pi).max(axis=2)
    gap[~ok] = np.inf
    red.branch = np.where(gap.min(axis=1) <= tol, gap.argmin(axis=1), -1)
    return red, theta


# ---------------------------------------------------------------------------------------------
# the filters


def _excess(value: np.ndarray, bound: np.ndarray) -> np.ndarray:
    return np.sign(value) * np.maximum(np.abs(value) - bound, 0.0)


class _Problem:
    """Eq. 4.12 on a set of rows: jerk residuals and limit penalties as functions of q, each residual
    group in stencil form (its first row ``start`` (m,), weights (m, 5) on rows start..start+4), so
    the Gauss-Newton normal equations assemble straight into band storage (:func:`_normal_band`)."""

    def __init__(self, t: np.ndarray, segment: np.ndarray, limits: Limits, settings: JerkSettings):
        n = len(t)
        self.start, w = stencils(t, segment)
        cols = np.minimum(self.start[:, None] + np.arange(5), max(n - 1, 0))
        self.D2, self.D3 = (sp.csr_matrix((w[:, r].ravel(), (np.repeat(np.arange(n), 5), cols.ravel())), shape=(n, n))
                            for r in (1, 2))
        self.W2, self.W3 = w[:, 1], w[:, 2]
        same = segment[1:] == segment[:-1]
        dt = np.diff(t)
        # forward differences Δq/Δt inside segments (the ξ test of Eq. 4.4)
        rows = np.flatnonzero(same)
        m = np.arange(len(rows))
        self.F = sp.csr_matrix((np.r_[-1 / dt[rows], 1 / dt[rows]], (np.r_[m, m], np.r_[rows, rows + 1])),
                               shape=(len(rows), n))
        self.WF = np.zeros((len(rows), 5))
        self.WF[:, 0], self.WF[:, 1] = -1 / dt[rows], 1 / dt[rows]
        self.WI = np.zeros((n, 5))
        self.WI[:, 0] = 1.0
        self.frow = rows
        self.w = np.ones(6) if settings.weights is None else np.asarray(settings.weights, float)
        self.rho = settings.penalty
        self.rho_a = settings.acceleration_penalty
        self.rho_j = settings.jerk_penalty
        m = settings.limit_margin
        self.lim = limits
        self.vmax, self.amax, self.jmax = m * limits.speed, m * limits.acceleration, m * limits.jerk

    def residual_parts(self, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """(first rows, stencil weights, residual (m, 6), per-joint squared scale (m, 6), 0 where the
        penalty is inactive) for: jerk, j_max, a_max, ξ, joint limits."""
        n = len(q)
        acc, vel, jerk = self.D2 @ q, self.F @ q, self.D3 @ q
        lims = np.minimum(q - self.lim.lower, 0.0) + np.maximum(q - self.lim.upper, 0.0)
        ea, ev, ej = _excess(acc, self.amax), _excess(vel, self.vmax), _excess(jerk, self.jmax)
        return [
            (self.start, self.W3, jerk, np.broadcast_to(self.w, (n, 6))),
            (self.start, self.W3, ej, self.rho_j * (ej != 0)),
            (self.start, self.W2, ea, self.rho_a * (ea != 0)),
            (self.frow, self.WF, ev, self.rho * (ev != 0)),
            (np.arange(n), self.WI, lims, self.rho * (lims != 0)),
        ]

    def cost_by_row(self, q: np.ndarray) -> np.ndarray:
        """Each residual's squared norm, attributed to the row owning the residual (n,)."""
        out = np.zeros(len(q))
        for first, _, r, c in self.residual_parts(q):
            v = (r**2 * c).sum(axis=1)
            if first is self.frow:
                np.add.at(out, self.frow, v)
            else:
                out += v
        return out


def _segment_sums(values: np.ndarray, segment: np.ndarray) -> np.ndarray:
    _, inv = np.unique(segment, return_inverse=True)
    return np.bincount(inv, weights=values)


def _normal_band(parts: list, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton normal equations JᵀJ, Jᵀr of the residual groups ``parts`` (see
    :meth:`_Problem.residual_parts`) w.r.t. z, where dq_l/dz_l = G[l] (n, 6, k): the upper band
    (u+1, N) of JᵀJ as :func:`scipy.linalg.solveh_banded` reads it (u = 5k-1: a stencil spans 5 rows)
    and Jᵀr (N,), N = (n+4)·k (4 padding rows so stencils need no clipping).

    Per joint j, JᵀJ's block (l, l+o) is S_j[o, l] · G[l, j] ⊗ G[l+o, j] with S_j = Aᵀ C_j A the
    (banded) scalar normal matrix of a group's operator A and squared scales C_j: S is summed from
    the stencils first, then meets G once per offset o."""
    n, _, k = G.shape
    m = n + 4
    Gp = np.concatenate([G, np.zeros((4, 6, k))])
    N, u = m * k, 5 * k - 1
    S = np.zeros((5, m * 6))
    y = np.zeros(m * 6)  # Aᵀ C r per row and joint
    groups = []  # the live residuals of every group, summed in one pass
    for first, W, r, c in parts:
        live = np.flatnonzero(c.any(axis=1))
        if len(live):
            groups.append((first[live], W[live], c[live], (c * r)[live]))
    if groups:
        first, W, c, cr = (np.concatenate(x) for x in zip(*groups))
        for a in range(5):
            idx = ((first + a)[:, None] * 6 + np.arange(6)).ravel()
            y += np.bincount(idx, (W[:, a, None] * cr).ravel(), m * 6)
            for o in range(5 - a):
                S[o] += np.bincount(idx, (W[:, a, None] * W[:, a + o, None] * c).ravel(), m * 6)
    S, y = S.reshape(5, m, 6), y.reshape(m, 6)
    grad = (y[:, :, None] * Gp).sum(axis=1).ravel()
    band = np.zeros((u + 1, N))
    for o in range(5):
        blk = (Gp[: m - o] * S[o, : m - o, :, None]).transpose(0, 2, 1) @ Gp[o:]  # (m-o, k, k)
        for p in range(k):
            for s in range(p if o == 0 else 0, k):
                band[u - o * k + p - s, o * k + s::k] += blk[:, p, s]
    return band, grad


def global_filter(red: Redundancy, z: np.ndarray, q: np.ndarray, t: np.ndarray, segment: np.ndarray,
                  limits: Limits, settings: JerkSettings, tilt_bound: np.ndarray | None = None,
                  history: list | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Eq. 4.12 with the window = every segment, by projected, damped Gauss-Newton over all rows'
    z = (θ) or (θ, α, β) at once.

    Residuals: √W q⃛ (Eq. 4.2), √ρ × the excess over the joint limits, ξ and a_max, and √μ × the
    tilt (a small pull back to the planned axis). The normal equations are banded (a row's stencil
    spans 5 rows): assembled in band storage and solved by a banded Cholesky factorization for the
    whole print; the tilt of row i is projected onto the disc of radius ``tilt_bound[i]`` (rad); a
    step is kept in a segment only where it lowers that segment's cost, else that segment's damping
    grows. A segment whose kept step lowered its cost by less than ``settings.converged`` (relative),
    or that cannot improve any more, is done: segments are independent (stencils never cross one), so
    the steps go on over the segments still converging only (the problem is cut down to them whenever
    they hold under ``settings.shrink`` of its rows). Rows of branch -1 stay fixed. ``history``
    (optional) collects the max |q⃛| per joint after every step (Fig. 4.3). Returns z, q and the steps
    taken."""
    z = np.asarray(z, float)
    z = (z[:, None] if z.ndim == 1 else z).copy()
    q = np.asarray(q, float).copy()
    n = len(z)
    bound = np.zeros(n) if tilt_bound is None else np.asarray(tilt_bound, float)
    rows = np.arange(n)
    left, steps = settings.global_iterations, 0
    done_jerk = np.zeros(6)  # max |q⃛| of the segments done (they no longer change)
    while left > 0 and len(rows):
        part = None if history is None else []
        zs, qs, used, live = _gauss_newton(red.subset(rows), z[rows], q[rows], t[rows], segment[rows], limits, settings,
                                           bound[rows], left, part)
        if history is not None:
            history.extend(np.maximum(h, done_jerk) for h in part)
            if (~live).any():
                gone = rows[~live]
                done_jerk = np.maximum(done_jerk, np.abs(derivatives(qs[~live], t[gone], segment[gone])[2]).max(axis=0))
        z[rows], q[rows] = zs, qs
        steps, left = steps + used, left - used
        rows = rows[live]
    return z, q, steps


def _gauss_newton(red: Redundancy, z: np.ndarray, q: np.ndarray, t: np.ndarray, segment: np.ndarray, limits: Limits,
                  settings: JerkSettings, bound: np.ndarray, iterations: int, history: list | None
                  ) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """Steps of :func:`global_filter` on these rows until ``iterations`` are used, every segment is
    done, or the segments still converging hold under ``settings.shrink`` of the rows. Returns z, q,
    the steps and which rows belong to a segment still converging (all False when the filter is done)."""
    n, k = z.shape
    prob = _Problem(t, segment, limits, settings)
    cols = np.flatnonzero(red.branch >= 0)
    if len(cols) == 0:
        return z, q, 0, np.zeros(n, bool)
    mu = settings.tilt_weight

    def row_cost(qq: np.ndarray, zz: np.ndarray) -> np.ndarray:
        c = prob.cost_by_row(qq)
        return c + mu * (zz[:, 1:] ** 2).sum(axis=1) if k > 1 else c

    _, seg_of = np.unique(segment, return_inverse=True)
    lam = np.full(seg_of.max() + 1, settings.damping)
    cost = _segment_sums(row_cost(q, z), segment)
    active = np.bincount(seg_of[cols], minlength=len(lam)) > 0  # segments with a row to move
    fixed = np.ones(n + 4, bool)
    fixed[cols] = False
    fixed = np.repeat(fixed, k)
    u = 5 * k - 1
    steps = 0
    moved = True
    G = np.zeros((n, 6, k))
    stale = np.ones(n, bool)  # rows whose dq/dz is not that of their current pose
    for _ in range(iterations):
        if moved:  # the linearization at the current z (a step rejected everywhere keeps it)
            live = cols[active[seg_of[cols]]]
            gone = np.ones(n, bool)
            gone[live] = False
            G[gone] = 0.0  # rows of finished segments are fixed
            new = live[stale[live]]  # rows of a segment whose last step was rejected keep theirs
            G[new] = joint_rates(red, z[new], new, q[new])
            stale[new] = False
            normal, grad = _normal_band(prob.residual_parts(q), G)
            if k > 1:  # the tilt's pull back to the planned axis
                tilt = np.zeros((n + 4, k))
                tilt[:n, 1:] = mu
                normal[u] += tilt.ravel()
                grad[: n * k] += (tilt[:n] * z).ravel()
            grad[fixed] = 0.0
            diag = normal[u].copy()
        band = normal.copy()
        damp = np.repeat(np.r_[lam[seg_of], np.zeros(4)], k)
        band[u] = np.where(fixed, 1.0, diag + damp * (diag + 1e-9 * diag.max() + 1e-12))
        try:
            delta = -solveh_banded(band, grad, check_finite=False)[: n * k].reshape(n, k)
        except np.linalg.LinAlgError:  # not positive definite (round-off): damp every segment more
            lam, moved = lam * 4, False
            continue
        delta = np.clip(np.nan_to_num(delta), -settings.max_step, settings.max_step)
        live = cols[active[seg_of[cols]]]
        new_z = z.copy()
        new_z[live] += delta[live]
        if k > 1:  # projection onto the allowed tilt
            r = np.linalg.norm(new_z[:, 1:], axis=1)
            new_z[:, 1:] *= np.minimum(1.0, bound / np.maximum(r, 1e-300))[:, None]
        new_q = q.copy()
        qn, ok = red.joints(new_z[live], live, q[live])
        new_q[live] = qn
        bad_seg = ~active.copy()
        bad_seg[seg_of[live[~ok]]] = True
        new_cost = _segment_sums(row_cost(new_q, new_z), segment)
        better = (new_cost < cost) & ~bad_seg
        keep = better[seg_of]
        stale |= keep
        z = np.where(keep[:, None], new_z, z)
        q = np.where(keep[:, None], new_q, q)
        improved = np.where(better, (cost - new_cost) / np.maximum(cost, 1e-300), 0.0)
        cost = np.where(better, new_cost, cost)
        lam = np.where(better, np.maximum(lam / 3, 1e-7), lam * 4)
        moved = bool(better.any())
        steps += 1
        if history is not None:
            history.append(np.abs(prob.D3 @ q).max(axis=0))
        # done: a nearly undamped step (λ fell 27-fold from its start) that gained little, or no step left
        active &= ~(better & (improved < settings.converged) & (lam < settings.damping / 10)) & (lam <= 1e6)
        if not active.any():
            return z, q, steps, np.zeros(n, bool)
        rows_live = active[seg_of]
        if rows_live.sum() < settings.shrink * n:
            return z, q, steps, rows_live
    return z, q, steps, np.zeros(n, bool)


def local_filter(red: Redundancy, z: np.ndarray, q: np.ndarray, t: np.ndarray, segment: np.ndarray,
                 limits: Limits, settings: JerkSettings, history: list | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Algorithm 6 on every segment: windows of Eq. 4.12 around the free row of largest ‖q⃛‖_W while
    some |q⃛| > j_max, solved by SLSQP over θ with hard joint limits, ξ and a_max (never worse than
    the window already is); d = 5, +5 to d_max; locking/unlocking. Only θ = z[:, 0] varies; tilts
    stay. ``history`` (optional) collects the max |q⃛| per joint after every iteration (Fig. 4.3).
    Returns z, q and the iterations."""
    z, q = z.copy(), q.copy()
    _, D2, D3 = derivative_operators(t, segment)
    w = np.ones(6) if settings.weights is None else np.asarray(settings.weights, float)
    first, last = segment_bounds(segment)
    dt = np.diff(t)
    jerk = D3 @ q
    locked = red.branch < 0
    iterations = 0
    for seg in np.unique(segment):
        rows = np.flatnonzero(segment == seg)
        a0, b0 = rows[0], rows[-1]
        count = 0
        while count < settings.max_iterations:
            norm = np.sqrt((jerk[a0:b0 + 1] ** 2) @ w)
            over = (np.abs(jerk[a0:b0 + 1]) > limits.jerk).any(axis=1) & ~locked[a0:b0 + 1]
            if not over.any():
                break
            c = a0 + int(np.argmax(np.where(over, norm, -1.0)))
            d = settings.window
            success = False
            while not success and d <= settings.max_window:
                a, b = max(a0, c - d), min(b0, c + d)
                success = _solve_window(red, z, q, D2, D3, dt, segment, a, b, first[c], last[c],
                                        limits, settings, w, ~locked)
                if not success:
                    d += settings.window_step
            a, b = max(a0, c - min(d, settings.max_window)), min(b0, c + min(d, settings.max_window))
            locked[a:b + 1] = (not success) | (red.branch[a:b + 1] < 0)
            lo, hi = max(a0, a - 2), min(b0, b + 2)
            jerk[lo:hi + 1] = D3[lo:hi + 1] @ q
            count += 1
            iterations += 1
            if history is not None:
                history.append(np.abs(jerk).max(axis=0))
    return z, q, iterations


def _solve_window(red, z, q, D2, D3, dt, segment, a, b, seg_first, seg_last, limits, settings, w,
                  movable) -> bool:
    """Eq. 4.12 over θ_a..θ_b (J_local on rows a-2..b+2) by SQP: each step solves the QP of the model
    q ≈ q(θ) + (dq/dθ) δ with the constraints (joint limits, ξ, a_max never worse than the window
    already is) by SLSQP, then backtracks on the exact q(θ) (IK), so every kept row satisfies
    x_i = f(q_i) and the constraints exactly. Updates z and q in place when J_local went down.
    Rows of branch -1 stay fixed."""
    var = np.arange(a, b + 1)
    var = var[movable[var] & (red.branch[var] >= 0)]
    if len(var) == 0:
        return False
    lo, hi = max(seg_first, a - 2), min(seg_last, b + 2)
    obj_rows = np.arange(lo, hi + 1)
    ctx_lo, ctx_hi = max(seg_first, lo - 2), min(seg_last, hi + 2)
    ctx = np.arange(ctx_lo, ctx_hi + 1)
    D3w = D3[obj_rows][:, ctx].toarray()
    D2w = D2[obj_rows][:, ctx].toarray()
    step_rows = np.arange(lo, hi)  # forward steps inside the local path
    step_rows = step_rows[segment[step_rows] == segment[step_rows + 1]]
    pos = var - ctx_lo
    q0 = q[ctx].copy()
    base_acc = np.abs(D2w @ q0)
    acc_bound = np.maximum(settings.limit_margin * limits.acceleration, base_acc * (1 + 1e-9) + 1e-12)
    base_vel = np.abs(q0[step_rows + 1 - ctx_lo] - q0[step_rows - ctx_lo]) / dt[step_rows, None]
    vel_bound = np.maximum(settings.limit_margin * limits.speed, base_vel * (1 + 1e-9) + 1e-12)
    sw = np.sqrt(w)
    k = len(var)
    sel = (var[None, :] == step_rows[:, None] + 1).astype(float) - (var[None, :] == step_rows[:, None])

    def exact(x: np.ndarray, check: bool = True) -> tuple[np.ndarray, bool]:
        qq, ok = red.joints(np.c_[x, z[var, 1:]], var, q[var], check=check)
        Q = q0.copy()
        Q[pos] = qq
        return Q, bool(ok.all())

    def local_cost(Q: np.ndarray) -> float:
        return float(((D3w @ Q * sw) ** 2).sum())

    def violations(Q: np.ndarray) -> np.ndarray:
        acc = D2w @ Q
        vel = (Q[step_rows + 1 - ctx_lo] - Q[step_rows - ctx_lo]) / dt[step_rows, None]
        return np.concatenate([(acc_bound - np.abs(acc)).ravel(), (vel_bound - np.abs(vel)).ravel(),
                               (Q[pos] - limits.lower).ravel(), (limits.upper - Q[pos]).ravel()])

    x = z[var, 0].copy()
    Q = q0
    before = cost = local_cost(Q)
    for _ in range(settings.sqp_iterations):
        Qp, okp = exact(x + settings.fd_step, check=False)
        G = np.where(okp, (Qp[pos] - Q[pos]) / settings.fd_step, 0.0)  # (k, 6) dq/dθ of the window's rows
        # the QP of this SQP step: J_local and the constraints on the model Q + G δ
        A3 = D3w[:, pos][:, None, :] * G.T[None] * sw[None, :, None]  # (rows, 6, k)
        A2 = D2w[:, pos][:, None, :] * G.T[None]
        AV = sel[:, None, :] * G.T[None] / dt[step_rows, None, None]
        j0, a0 = D3w @ Q * sw, D2w @ Q
        v0 = (Q[step_rows + 1 - ctx_lo] - Q[step_rows - ctx_lo]) / dt[step_rows, None]
        M3, M2, MV = A3.reshape(-1, k), A2.reshape(-1, k), AV.reshape(-1, k)
        MQ = np.zeros((k, 6, k))
        MQ[np.arange(k), :, np.arange(k)] = G
        MQ = MQ.reshape(-1, k)
        r3 = j0.ravel()
        cons_A = np.vstack([-M2, M2, -MV, MV, MQ, -MQ])
        cons_b = np.concatenate([(acc_bound - a0).ravel(), (acc_bound + a0).ravel(), (vel_bound - v0).ravel(),
                                 (vel_bound + v0).ravel(), (Q[pos] - limits.lower).ravel(), (limits.upper - Q[pos]).ravel()])
        near = cons_b < np.abs(cons_A).sum(axis=1) * settings.max_step  # only these can become active
        cons_A, cons_b = cons_A[near], cons_b[near]
        unit = 1.0 / max(cost, 1e-300)  # J_local scaled to 1 at δ = 0
        res = minimize(lambda d: (unit * float(((r3 + M3 @ d) ** 2).sum()), 2 * unit * M3.T @ (r3 + M3 @ d)),
                       np.zeros(k), jac=True, method="SLSQP", bounds=[(-settings.max_step, settings.max_step)] * k,
                       constraints=[{"type": "ineq", "fun": lambda d: cons_b + cons_A @ d, "jac": lambda d: cons_A}],
                       options={"maxiter": 100, "ftol": 1e-10})
        step = res.x
        for _ in range(4):  # backtracking on the exact q(θ)
            Qn, ok = exact(x + step)
            cn = local_cost(Qn)
            if ok and cn < cost and (violations(Qn) >= -1e-9).all():
                break
            step = step / 2
        else:
            break
        x, Q, cost = x + step, Qn, cn
    if not cost < before * (1 - 1e-6):
        return False
    z[var, 0] = x
    q[ctx] = Q
    return True


def _penalized(prob: _Problem, q: np.ndarray, margin: int, level: float = 1.0) -> np.ndarray:
    """Rows within ``margin`` of a row over ``level`` × a limit (a_max, j_max, ξ) or outside the joint
    limits: the stretches the time-scaling would have to slow down."""
    lim = prob.lim
    over = ((np.abs(prob.D2 @ q) > level * lim.acceleration) | (np.abs(prob.D3 @ q) > level * lim.jerk)).any(axis=1)
    over |= lim.beyond(q)
    fast = (np.abs(prob.F @ q) > level * lim.speed).any(axis=1)
    live = np.r_[np.flatnonzero(over) - 2, prob.frow[fast]]  # a row's stencil starts up to 2 rows before it
    hot = np.zeros(len(q) + 1, int)
    np.add.at(hot, np.clip(live - margin, 0, len(q)), 1)
    np.add.at(hot, np.clip(live + 5 + margin, 0, len(q)), -1)
    return np.cumsum(hot)[:-1] > 0


def _settle(red: Redundancy, z: np.ndarray, q: np.ndarray, t: np.ndarray, segment: np.ndarray, limits: Limits,
            settings: JerkSettings, bound: np.ndarray, free: np.ndarray, history: list | None = None
            ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """The global filter, then Algorithm 6, with only the ``free`` rows varying, solved on the
    stretches within 8 rows of them (a free row's residuals reach 4 rows, their stencils 2 more: rows
    farther away are fixed and their stencils see fixed rows only, so the sub-problem is exact).
    ``history`` gets the max |q⃛| per joint over the whole trajectory after every step (Fig. 4.3).
    Returns z, q, the Gauss-Newton steps and the Alg. 6 iterations."""
    n = len(q)
    sub = np.arange(n) if free.all() else np.flatnonzero(np.convolve(free, np.ones(17), "same") > 0)
    part = np.cumsum(np.r_[True, (np.diff(sub) > 1) | (segment[sub][1:] != segment[sub][:-1])])
    sub_red = red.subset(sub, np.where(free, red.branch, -1))
    fig = None if history is None else []
    zs, qs, s = global_filter(sub_red, z[sub], q[sub], t[sub], part, limits, settings, bound[sub], fig)
    it = 0
    if settings.max_iterations > 0:
        zs, qs, it = local_filter(sub_red, zs, qs, t[sub], part, limits, settings, fig)
    if history is not None and fig:
        rest = np.ones(n, bool)
        rest[sub] = False
        _, _, jerk = derivatives(q[rest], t[rest], segment[rest]) if rest.any() else (None, None, np.zeros((1, 6)))
        history.extend(np.maximum(h, np.abs(jerk).max(axis=0)) for h in fig)
    z, q = z.copy(), q.copy()
    z[sub], q[sub] = zs, qs
    return z, q, s, it


# ---------------------------------------------------------------------------------------------
# §4.3.3: the collision-free projection of a final row


def dense_projection(red: Redundancy, z: np.ndarray, q: np.ndarray, rows: np.ndarray, limits: Limits,
                     collides: Callable[[np.ndarray], np.ndarray] | None, settings: JerkSettings
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Eq. 4.13: for each row whose pose q_d collides (or left the joint limits), θ re-sampled about
    the waypoint every π/500 (``projection_step``) on the row's IK branch, tilt kept; of the samples
    whose pose exists, keeps the joint limits and is collision-free, the one nearest q_d in ‖·‖∞.
    Candidates are fcl-checked nearest first, ``projection_batch`` per row at a time, at most
    ``projection_checks`` per row. Returns z, q (k, ·), found (k,) and the collision checks made."""
    m = len(rows)
    step = settings.projection_step
    count = int(np.pi / step)
    offsets = step * np.r_[np.arange(1, count + 1), -np.arange(1, count + 1)]
    Z = np.repeat(z, len(offsets), axis=0)
    Z[:, 0] += np.tile(offsets, m)
    idx = np.repeat(np.arange(m), len(offsets))
    Q, ok = red.joints(Z, rows[idx], q[idx])
    ok &= ~limits.beyond(Q)
    dist = np.where(ok, np.abs(Q - q[idx]).max(axis=1), np.inf).reshape(m, -1)
    order = np.argsort(dist, axis=1)
    found = np.zeros(m, bool)
    pick = np.zeros(m, int)
    checks = 0
    for s in range(0, settings.projection_checks, settings.projection_batch):
        cand = order[:, s:s + settings.projection_batch]
        live = ~found[:, None] & np.isfinite(np.take_along_axis(dist, cand, axis=1))
        if not live.any():
            break
        r, c = np.nonzero(live)
        flat = r * len(offsets) + cand[r, c]
        free = ~collides(Q[flat]) if collides is not None else np.ones(len(flat), bool)
        checks += len(flat) if collides is not None else 0
        for rr, f in zip(r[free][::-1], flat[free][::-1]):  # the nearest free candidate of each row wins
            found[rr], pick[rr] = True, f
    out = np.flatnonzero(found)
    z_out, q_out = z.copy(), q.copy()
    z_out[out], q_out[out] = Z[pick[out]], Q[pick[out]]
    return z_out, q_out, found, checks


# ---------------------------------------------------------------------------------------------
# the stage


def optimize_print(robot: Robot, cell: Workcell, positions: np.ndarray, motion,
                   collides_for_layer: Callable[[int], Callable[[np.ndarray], np.ndarray] | None] | None = None,
                   layer_of_row: np.ndarray | None = None,
                   settings: JerkSettings = JerkSettings(), history: list | None = None,
                   path_of_row: np.ndarray | None = None):
    """Jerk-optimize a :class:`curvslice.motion.PrintMotion` (§4.3.2-4.3.3) and bring it within the
    workcell's a_max and j_max (time-scaling), moves between segments by Ruckig.

    ``positions`` are the waypoints of the motion's rows (R, 3). Rows whose optimized pose collides
    (``collides_for_layer(layer)(q)``, fcl: §4.3.3) are put back to their graph pose (collision-free
    by construction of the graph) and the filters run again with them fixed. ``path_of_row``: the
    tool-path piece of each row; a jump to another piece (extruder off) then ends the segment and
    becomes a Ruckig move like the moves between segments, instead of a stretch of the segment that the
    time-scaling must slow down (the stencils of the rows beside a jump span its long step: on bunny
    layers 34-37, 35 % of the time the time-scaling added was next to jumps). Returns the new motion
    and a report (evidence per layer and overall; "before" on the graph's own segments)."""
    start, cpu = time.perf_counter(), time.process_time()
    limits = Limits.of(robot, cell)
    q0, t0, seg = motion.q, motion.t, motion.segment
    graph_seg = seg
    w = None if settings.weights is None else np.asarray(settings.weights, float)
    if path_of_row is not None and len(seg):
        cut = np.r_[False, (seg[1:] != seg[:-1]) | (path_of_row[1:] != path_of_row[:-1])]
        seg = seg[0] + np.cumsum(cut)
        motion = replace(motion, segment=seg, extruding=motion.extruding & ~cut)
    red, theta0 = redundancy(robot, cell, positions, motion.normals, q0)
    tilt = min(np.radians(settings.max_tilt_deg), cell.max_axis_deviation)
    z0 = np.c_[theta0, np.zeros((len(q0), 2))] if tilt > 0 else theta0[:, None]
    # a row's tilt and its deviation so far (the axis smoothing, a tilt for a collision) stay within the bound
    bound = np.clip(cell.max_axis_deviation - motion.deviation, 0.0, tilt)
    branch = red.branch.copy()
    z, q = z0.copy(), q0.copy()
    safe_z, safe_q = z0.copy(), q0.copy()  # the last pose of each row known collision-free (the graph's first)
    free = branch >= 0
    pinned = np.zeros(len(q), bool)  # rows fixed after a collision
    steps = iterations = checks = reverted = beyond = projected = 0
    if free.any():
        # the whole print for a few steps (the jerk drops most), then only the stretches where a
        # penalty (a_max, ξ, joint limits) is still active, which converge slowly
        whole = min(settings.whole_iterations, settings.global_iterations)
        z, q, steps, iterations = _settle(red, z, q, t0, seg, limits, replace(settings, global_iterations=whole),
                                          bound, free, history)
        left = settings.global_iterations - whole
        whole_problem = _Problem(t0, seg, limits, settings)
        for f in range(settings.focus_rounds):
            share = left // settings.focus_rounds + (f < left % settings.focus_rounds)
            focus = _penalized(whole_problem, q, settings.focus_margin, settings.focus_level) & free
            if share == 0 or not focus.any():
                break
            z, q, s, it = _settle(red, z, q, t0, seg, limits, replace(settings, global_iterations=share,
                                  damping=settings.refilter_damping), bound, focus, history)
            steps, iterations = steps + s, iterations + it
    # §4.3.3 layer by layer (its collision scene is set once; segments never span layers): fcl on the
    # moved rows, the dense-θ projection (Eq. 4.13) of those that collide or left the joint limits
    # (else back to their graph pose), which stay fixed while the 10 rows either side are filtered
    # again (a quarter of the steps); repeated
    fewer = replace(settings, global_iterations=settings.refilter_iterations, damping=settings.refilter_damping)
    groups = [np.arange(len(q))] if layer_of_row is None else [np.flatnonzero(layer_of_row == v) for v in np.unique(layer_of_row)]
    for rows in groups:
        value = None if layer_of_row is None else int(layer_of_row[rows[0]])
        collides = collides_for_layer(value) if collides_for_layer is not None and value is not None else None
        for k in range(settings.collision_rounds + 1):
            moved = rows[np.abs(q[rows] - safe_q[rows]).max(axis=1) > 1e-12]
            hit = limits.beyond(q[moved])  # the joint limits are hard: the filter only penalizes them
            beyond += int(hit.sum())
            if collides is not None:
                hit |= collides(q[moved])
                checks += len(moved)
            bad = moved[hit]
            ok = moved[~hit]
            safe_z[ok], safe_q[ok] = z[ok], q[ok]
            if not len(bad):
                break
            pz, pq, found, used = dense_projection(red, z[bad], q[bad], bad, limits, collides, settings)
            checks += used
            projected += int(found.sum())
            reverted += int((~found).sum())
            safe_z[bad[found]], safe_q[bad[found]] = pz[found], pq[found]
            z[bad], q[bad] = safe_z[bad], safe_q[bad]  # fixed from now on
            pinned[bad] = True
            if k < settings.collision_rounds:
                near = np.zeros(len(q) + 1, int)
                np.add.at(near, np.clip(bad - 10, 0, len(q)), 1)
                np.add.at(near, np.clip(bad + 11, 0, len(q)), -1)
                free = np.zeros(len(q), bool)
                free[rows] = (np.cumsum(near)[:-1] > 0)[rows] & (branch[rows] >= 0) & ~pinned[rows]
                if free.any():
                    z, q, s, it = _settle(red, z, q, t0, seg, limits, fewer, bound, free)
                    steps, iterations = steps + s, iterations + it
    normals = red.axis(z, np.arange(len(q)))
    tilted = angles_between(normals, red.axes)
    filtered = time.perf_counter() - start
    t_scaled, rounds, left = time_scale(q, t0, seg, limits, settings)
    scaled_added = float((t_scaled[-1] - t_scaled[0]) - (t0[-1] - t0[0])) if len(t0) else 0.0
    t_new, moves = retime_moves(q, t_scaled, seg, limits, cell.min_step_time)
    out = replace(motion, q=q, t=t_new, normals=normals, deviation=np.where(tilted > 1e-6, motion.deviation + tilted, motion.deviation))
    group = np.zeros(len(q), int) if layer_of_row is None else layer_of_row  # segments never span layers
    stats_before, stats_after = group_stats(q0, t0, graph_seg, group, w), group_stats(q, t_new, seg, group, w)
    before, after = combined_stats(stats_before.values(), t0), combined_stats(stats_after.values(), t_new)
    inside = np.r_[seg[1:] == seg[:-1]] if len(seg) > 1 else np.zeros(0, bool)
    print_steps = float(np.diff(t0)[inside].sum()) if len(inside) else 0.0
    report = {
        "trajectory": "jerk",
        "before": before,
        "after": after,
        "gauss_newton_steps": steps,
        "alg6_iterations": iterations,
        "time_scaling_rounds": rounds,
        "rows_over_limits": left,
        "time_scaling_added_s": round(scaled_added, 3),
        "time_scaling_added_pct": round(100 * scaled_added / print_steps, 3) if print_steps > 0 else 0.0,
        "print_steps_s": round(print_steps, 3),  # the graph's time of the steps inside the segments
        "moves_s": round(moves, 3),
        "collision_checks": checks,
        "rows_reverted_for_collision": reverted,
        "rows_reverted_for_joint_limits": beyond,
        "rows_projected": projected,
        "rows_fixed": int((red.branch < 0).sum()),
        "rows_tilted": int((tilted > 1e-6).sum()),
        "max_tilt_deg": round(float(np.degrees(tilted.max())), 3) if len(tilted) else 0.0,
        "seconds_filter": round(filtered, 3),
        "seconds": round(time.perf_counter() - start, 3),
        "cpu_s": round(time.process_time() - cpu, 3),  # this process's CPU: comparable under load
        "limits": {"speed": limits.speed, "acceleration": limits.acceleration.tolist(), "jerk": limits.jerk.tolist()},
    }
    if layer_of_row is not None:
        report["layers"] = []
        added = np.r_[np.where(inside, np.diff(t_scaled) - np.diff(t0), 0.0), 0.0] if len(inside) else np.zeros(len(q))
        for value in np.unique(layer_of_row):
            r = layer_of_row == value
            report["layers"].append({"layer": int(value), "before": stats_before[int(value)],
                                     "after": stats_after[int(value)],
                                     "time_scaling_added_s": round(float(added[r].sum()), 3)})
    return out, report


#: jerk report figures that add up over the print
SUMMED = ("gauss_newton_steps", "alg6_iterations", "rows_over_limits", "time_scaling_added_s", "collision_checks",
          "rows_reverted_for_collision", "rows_reverted_for_joint_limits", "rows_projected", "rows_fixed", "rows_tilted",
          "print_steps_s", "cpu_s",
          "seconds_filter", "seconds")


def rest_to_rest_time(robot: Robot, cell: Workcell) -> Callable[[np.ndarray, np.ndarray], float]:
    """The jerk-limited move between layers from rest to rest (Ruckig), at least one step: a first
    clock for :func:`curvslice.motion.join_motions`; :func:`retime_joins` then makes every move start
    from the state its segment really ends in."""
    limits = Limits.of(robot, cell)
    return lambda qa, qb: max(rest_to_rest(qa, qb, limits), cell.min_step_time)


def retime_joins(robot: Robot, cell: Workcell, motion: PrintMotion) -> PrintMotion:
    """The joined print with every move between segments (those between blocks of layers too) lasting
    Ruckig's time-optimal duration from the state its segment ends in to the state the next starts in
    (:func:`curvslice.time_scaling.retime_moves`); steps inside segments are kept."""
    t, _ = retime_moves(motion.q, motion.t, motion.segment, Limits.of(robot, cell), cell.min_step_time)
    return replace(motion, t=t)


def merge_reports(robot: Robot, cell: Workcell, graph, final, reports: list[dict], trajectory: str,
                  settings: JerkSettings = JerkSettings()) -> dict:
    """The print's trajectory report from its parts' (:func:`trajectory_stage` on blocks of layers): derivatives of the
    joined graph motion ("before") and of the final one ("after", Eq. 4.7-4.10), summed counts, the
    print time added by the time-scaling against the graph's printing steps, and the moves' total."""
    limits = Limits.of(robot, cell)
    w = None if settings.weights is None else np.asarray(settings.weights, float)
    out: dict = {"trajectory": trajectory, "before": motion_stats(graph.q, graph.t, graph.segment, w)}
    if trajectory == "jerk":
        out["after"] = motion_stats(final.q, final.t, final.segment, w)
        for key in SUMMED:
            out[key] = round(sum(r[key] for r in reports), 3) if reports else 0
        out["time_scaling_rounds"] = max((r["time_scaling_rounds"] for r in reports), default=0)
        out["max_tilt_deg"] = max((r["max_tilt_deg"] for r in reports), default=0.0)
        steps = out["print_steps_s"]  # the graph's time of the steps the time-scaling may stretch
        out["time_scaling_added_pct"] = round(100 * out["time_scaling_added_s"] / steps, 3) if steps > 0 else 0.0
        moves = final.segment[1:] != final.segment[:-1]
        out["moves_s"] = round(float(np.diff(final.t)[moves].sum()), 3) if len(final.t) > 1 else 0.0
    out["limits"] = {"speed": limits.speed, "acceleration": limits.acceleration.tolist(), "jerk": limits.jerk.tolist()}
    out["layers"] = [entry for r in reports for entry in r["layers"]]
    return out


def trajectory_stage(robot: Robot, cell: Workcell, toolpaths: dict[str, np.ndarray], motion: PrintMotion,
                     trajectory: str = "jerk",
                     collides_for_layer: Callable[[int], Callable[[np.ndarray], np.ndarray] | None] | None = None,
                     settings: JerkSettings = JerkSettings()) -> tuple[PrintMotion, dict]:
    """The robot stage's last step on a graph motion (one layer, a block of layers or the whole print):
    ``trajectory`` = "jerk" returns :func:`optimize_print`'s motion and report; "graph" keeps the graph
    search's motion (§4.3.1, for comparison) and reports its derivatives (Eq. 4.7-4.10)."""
    layer = np.asarray(toolpaths["layer"])[motion.index]
    if trajectory == "jerk":
        if not len(motion.q):  # no pose reached: nothing to filter
            return motion, {**dict.fromkeys(SUMMED, 0), "time_scaling_rounds": 0, "max_tilt_deg": 0.0, "layers": []}
        return optimize_print(robot, cell, np.asarray(toolpaths["positions"], float)[motion.index], motion,
                              collides_for_layer, layer, settings, path_of_row=np.asarray(toolpaths["path"])[motion.index])
    if trajectory != "graph":
        raise ValueError(f"trajectory must be 'jerk' or 'graph' (got {trajectory!r})")
    w = None if settings.weights is None else np.asarray(settings.weights, float)
    stats = group_stats(motion.q, motion.t, motion.segment, layer, w)
    return motion, {"trajectory": "graph", "layers": [{"layer": int(v), "before": stats[int(v)]} for v in np.unique(layer)]}
