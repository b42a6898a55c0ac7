"""Ladder graph and rung-by-rung multi-source shortest path (§3.5.3, §4.3.1) against scipy's
Dijkstra, the lazy collision filter against an up-front one, and a planned dome spiral re-checked
by pinocchio FK in the UR5 workcell."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from curvslice.collision import SMALL_DISTINCT, CollisionScene, _distinct, rotation_sweep
from curvslice.kinematics import fk, fk_reference, load_robot
from curvslice.ladder import (
    DENSE_WINDOW,
    EdgeMemo,
    RungMemo,
    blocked_rungs,
    circular_joints,
    deviate_axes,
    edge_weights,
    held_frames,
    hopeless_rungs,
    joint_steps,
    ladder,
    ladder_at,
    reference_shortest_path,
    shortest_path,
    sparse_edges,
    tilted_axes,
    turned_frames,
)
from curvslice.motion import (BAND, BUMPS, Remembered, _band_fill, _band_windows, _fill, _Found, coarse_rungs, deviation_windows, plan_layer, plan_motion,
                              ramp_steps, reach_cone, step_times, unwind)
from curvslice.workcell import load_workcell, rotation_samples, waypoints_from_flange


def _random_ladder(rng, m_max=30, k_max=8):
    m = int(rng.integers(2, m_max))
    K = int(rng.integers(1, k_max))
    if rng.random() < 0.5:  # wide steps (dense edge search) on scattered nodes
        q = rng.uniform(-np.pi, np.pi, (m, K, 6))
        dt = rng.uniform(0.5, 3.0, m - 1)  # with ξ = 1 many transitions are too fast: disconnections
    else:  # short steps (sorted-window edge search) on nodes drifting near their predecessors
        K = 4 * K
        q = np.cumsum(rng.normal(0, 0.15, (m, K, 6)), axis=0) + rng.uniform(-np.pi, np.pi, (1, K, 6))
        q = (q + np.pi) % (2 * np.pi) - np.pi
        dt = rng.uniform(0.05, 0.6, m - 1)
    valid = rng.random((m, K)) < 0.7
    valid[rng.random(m) < 0.1] = False  # whole rungs without a feasible pose
    circ = rng.random(6) < 0.5
    return q, valid, dt, circ


def test_edge_weights_follow_eq_3_4_and_4_4_4_5():
    rng = np.random.default_rng(0)
    qa, qb = rng.uniform(-np.pi, np.pi, (5, 6)), rng.uniform(-np.pi, np.pi, (4, 6))
    circ = np.array([True, False, True, True, False, True])
    W = rng.uniform(0.5, 2, 6)
    for cost in ("l1", "quadratic"):
        got = edge_weights(qa, qb, 2.0, 1.0, circ, cost, W)
        for i in range(5):
            for j in range(4):
                d = np.abs(qb[j] - qa[i])
                d[circ] = np.minimum(d[circ], 2 * np.pi - d[circ])  # circular distance (winding)
                want = (W * d).sum() if cost == "l1" else (W * d * d).sum()
                if d.max() / 2.0 > 1.0:
                    assert got[i, j] == np.inf
                else:
                    assert got[i, j] == pytest.approx(want, rel=1e-12)


def test_dag_shortest_path_equals_scipy_dijkstra():
    rng = np.random.default_rng(1)
    splits = empty = 0
    for trial in range(400):
        q, valid, dt, circ = _random_ladder(rng)
        cost = "l1" if trial % 2 else "quadratic"
        got, _, _ = shortest_path(q, valid, dt, 1.0, circ, cost)
        ref = reference_shortest_path(q, valid, dt, 1.0, circ, cost)
        assert got.cost == pytest.approx(ref.cost, rel=1e-12, abs=1e-12)
        np.testing.assert_array_equal(got.node, ref.node)
        np.testing.assert_array_equal(got.segment, ref.segment)
        # the chosen path is feasible: every consecutive pair inside a segment is a graph edge
        for i in range(len(q) - 1):
            if got.segment[i] >= 0 and got.segment[i] == got.segment[i + 1]:
                w = edge_weights(q[i, [got.node[i]]], q[i + 1, [got.node[i + 1]]], dt[i], 1.0, circ, cost)
                assert np.isfinite(w).all()
        splits += int(got.segment.max() > 0)
        empty += int((got.node < 0).any())
    assert splits > 50 and empty > 50  # the randomized cases really exercise disconnections


def test_sparse_edges_equal_the_dense_matrix():
    rng = np.random.default_rng(3)
    for _ in range(200):
        q, valid, dt, circ = _random_ladder(rng)
        q = np.where(valid[..., None], q, np.nan)
        for i in range(len(q) - 1):
            dense = edge_weights(q[i], q[i + 1], dt[i], 1.0, circ, "quadratic")
            ia, ib, w = sparse_edges(q[i], q[i + 1], dt[i], 1.0, circ, "quadratic")
            got = np.full_like(dense, np.inf)
            got[ia, ib] = w
            assert len(set(zip(ia.tolist(), ib.tolist()))) == len(ia)  # no duplicate edges
            np.testing.assert_array_equal(got, dense)


def test_wide_windows_on_large_rungs_equal_the_dense_matrix():
    """Steps of 1-2 rad (ξΔt) between rungs of more than DENSE_PAIRS node pairs take the sorted
    window, not the dense matrix: the same edges and weights, none twice."""
    rng = np.random.default_rng(9)
    for K in (150, 400):
        q = rng.uniform(-np.pi, np.pi, (6, K, 6))
        q[rng.random((6, K)) < 0.2] = np.nan
        circ = rng.random(6) < 0.5
        for i, dt in enumerate(rng.uniform(1.0, DENSE_WINDOW, 5)):
            dense = edge_weights(q[i], q[i + 1], dt, 1.0, circ)
            ia, ib, w = sparse_edges(q[i], q[i + 1], dt, 1.0, circ)
            assert len(set(zip(ia.tolist(), ib.tolist()))) == len(ia)
            got = np.full_like(dense, np.inf)
            got[ia, ib] = w
            np.testing.assert_array_equal(got, dense)


def test_lazy_node_filter_equals_filtering_first():
    rng = np.random.default_rng(2)
    for _ in range(100):
        q, valid, dt, circ = _random_ladder(rng)
        blocked = rng.random(valid.shape) < 0.3
        asked = []

        def node_ok(rungs, nodes):
            asked.append(len(rungs))
            return ~blocked[rungs, nodes]

        lazy, _, count = shortest_path(q, valid, dt, 1.0, circ, node_ok=node_ok)
        eager = reference_shortest_path(q, valid & ~blocked, dt, 1.0, circ)
        np.testing.assert_array_equal(lazy.node, eager.node)
        np.testing.assert_array_equal(lazy.segment, eager.segment)
        assert lazy.cost == pytest.approx(eager.cost, rel=1e-12, abs=1e-12)
        assert count == sum(asked)


def test_lazy_search_over_a_node_superset_with_shared_edges_equals_scipy():
    """Edges over a superset of the usable nodes (``nodes``, shared by calls through one
    ``edge_cache``) and the relaxation stopping where a rung comes out as before (dense blocking:
    many disconnections, so many rungs restart as sources) give scipy's shortest path on the
    usable, collision-free nodes, bit for bit the nodes of the plain lazy search."""
    rng = np.random.default_rng(11)
    for trial in range(150):
        q, valid, dt, circ = _random_ladder(rng)
        blocked = rng.random(valid.shape) < rng.uniform(0.2, 0.8)
        group = np.arange(valid.shape[1]) % 3
        cache: dict = {}
        for usable in (valid & (rng.random(valid.shape) < 0.7), valid):  # two calls, one cache
            lazy, _, _ = shortest_path(q, usable, dt, 1.0, circ, node_ok=lambda r, k: ~blocked[r, k], group=group,
                                       edge_cache=cache, nodes=valid)
            plain, _, _ = shortest_path(q, usable, dt, 1.0, circ, node_ok=lambda r, k: ~blocked[r, k], group=group)
            eager = reference_shortest_path(q, usable & ~blocked, dt, 1.0, circ)
            np.testing.assert_array_equal(lazy.node, eager.node)
            np.testing.assert_array_equal(lazy.segment, eager.segment)
            np.testing.assert_array_equal(lazy.node, plain.node)
            assert lazy.cost == pytest.approx(eager.cost, rel=1e-12, abs=1e-12)


def test_reach_cone_keeps_every_path_between_pinned_ends():
    """With the first and last rung pinned to one node each, the search on the nodes inside
    reach_cone finds scipy's shortest path over the whole ladder whenever that one connects the
    pins without a split (the cone drops no node of any such path)."""
    rng = np.random.default_rng(5)
    connected = 0
    for trial in range(300):
        q, valid, dt, circ = _random_ladder(rng)
        if trial % 2:  # node 0 of every rung in reach of the one before: the pins connect
            d = np.abs(np.diff(q[:, 0], axis=0))
            d[:, circ] = np.minimum(d[:, circ], 2 * np.pi - d[:, circ])
            dt = np.maximum(dt, d.max(axis=1) * rng.uniform(1.0, 1.3, len(dt)))
            valid[:, 0] = True
        valid[[0, -1]] = False
        valid[0, 0] = valid[-1, 0] = True
        cost = "l1" if trial % 4 < 2 else "quadratic"
        ref = reference_shortest_path(q, valid, dt, 1.0, circ, cost)
        cone = reach_cone(np.where(valid[..., None], q, np.nan), (q[0, 0], q[-1, 0]), dt, 1.0, circ)
        if (ref.node < 0).any() or ref.segment.max() > 0:
            continue
        connected += 1
        assert cone[np.arange(len(q)), ref.node].all()
        got, _, _ = shortest_path(q, valid & cone, dt, 1.0, circ, cost)
        np.testing.assert_array_equal(got.node, ref.node)
        assert got.cost == pytest.approx(ref.cost, rel=1e-12, abs=1e-12)
    assert connected > 100


def test_deviation_windows_cover_the_changed_rows():
    changed = np.zeros(100, bool)
    changed[[3, 10, 50, 97]] = True
    windows = deviation_windows(changed, 4)
    assert windows == [(0, 14, True, True), (46, 54, True, True), (93, 99, True, True)]


def test_unwind_keeps_joints_in_range_and_splits_beyond_it():
    # joint 6 turns 5 revolutions in small steps; limits ±2π (4π of range): at least one split
    m = 400
    angle = np.linspace(0, 10 * np.pi, m)
    q = np.zeros((m, 6))
    q[:, 5] = (angle + np.pi) % (2 * np.pi) - np.pi
    lower, upper = np.full(6, -2 * np.pi), np.full(6, 2 * np.pi)
    lower[2], upper[2] = -np.pi, np.pi  # a joint without a full extra turn: never wrapped
    out, splits = unwind(q, np.zeros(m, int), lower, upper)
    assert len(splits) >= 2
    assert (out >= lower - 1e-9).all() and (out <= upper + 1e-9).all()
    cuts = set(splits)
    step = np.diff(out[:, 5])
    for i in range(m - 1):
        if i + 1 not in cuts:  # inside a piece the joint moves by the short way, no jump
            assert abs(step[i]) < 0.1
    # same angles modulo 2π
    assert np.allclose(np.cos(out[:, 5]), np.cos(angle)) and np.allclose(np.sin(out[:, 5]), np.sin(angle))


def test_unwind_random_walks_stay_in_range():
    rng = np.random.default_rng(5)
    lower = np.array([-2 * np.pi, -2 * np.pi, -np.pi, -2 * np.pi, -2 * np.pi, np.radians(-400)])
    upper = -lower
    for _ in range(50):
        m = 300
        walk = np.cumsum(rng.normal(0, 0.3, (m, 6)), axis=0) + rng.uniform(-np.pi, np.pi, 6)
        walk[:, 2] = np.clip(walk[:, 2], -3.0, 3.0)  # the non-circular joint stays inside by itself
        q = (walk + np.pi) % (2 * np.pi) - np.pi
        q[:, 2] = walk[:, 2]
        segment = np.repeat(np.arange(3), m // 3)
        out, splits = unwind(q, segment, lower, upper)
        assert (out >= lower).all() and (out <= upper).all()
        cuts = set(splits) | {m // 3, 2 * m // 3}
        steps = np.diff(out, axis=0)
        wrapped = (np.diff(q, axis=0) + np.pi) % (2 * np.pi) - np.pi
        wrapped[:, 2] = np.diff(q[:, 2])
        keep = np.array([i + 1 not in cuts for i in range(m - 1)])
        np.testing.assert_allclose(steps[keep], wrapped[keep], atol=1e-9)  # the short way, no jumps


def _dome_spiral(m, turns=3, tilt_deg=60.0, radius=40.0):
    s = np.linspace(0, 1, m)
    pol = np.radians(tilt_deg) * (1 - s)
    az = 2 * np.pi * turns * s
    t = np.stack([np.sin(pol) * np.cos(az), np.sin(pol) * np.sin(az), np.cos(pol)], 1)
    return radius * t, t


@pytest.fixture(scope="module")
def ur5():
    return load_robot("ur5"), load_workcell("ur5")



def _assert_realizes(robot, cell, scene, motion, c, t) -> np.ndarray:
    """FK of every row reproduces its waypoint (position, axis), joint limits, ξ inside the motions and
    no collision; returns the rows' same-motion mask."""
    pos, axis = waypoints_from_flange(cell, fk_reference(robot, motion.q))
    assert np.abs(pos - c).max() < 1e-6
    assert np.abs(axis - t).max() < 1e-9
    lo, hi = cell.limits(robot)
    assert (motion.q >= lo).all() and (motion.q <= hi).all()
    same = motion.segment[1:] == motion.segment[:-1]
    speed = np.abs(np.diff(motion.q, axis=0)).max(axis=1) / np.diff(motion.t)
    assert speed[same].max() <= cell.max_joint_speed * (1 + 1e-9)
    assert not scene.collisions(motion.q).any()
    return same

def test_planned_dome_spiral_is_reproduced_by_pinocchio_fk(ur5):
    robot, cell = ur5
    c, t = _dome_spiral(300)
    dt = step_times(c, cell.linear_speed, cell.min_step_time)
    scene = CollisionScene(robot, cell)
    motion = plan_motion(robot, cell, c, t, dt, collides=scene.collisions)
    rows = motion.segment >= 0
    assert rows.all()
    assert (motion.solutions > 0).all()
    _assert_realizes(robot, cell, scene, motion, c, t)
    assert motion.collision_checks < motion.solutions.sum()  # lazy: fewer checks than nodes


def test_split_when_the_axis_flips_faster_than_xi(ur5):
    robot, cell = ur5
    c, t = _dome_spiral(60, turns=0.0, tilt_deg=40.0)
    t[30:, :2] *= -1  # the tool axis jumps by 80° between waypoints 29 and 30
    dt = step_times(c, cell.linear_speed, cell.min_step_time)
    motion = plan_motion(robot, dataclasses.replace(cell, rotations=4), c, t, dt, max_rotations=8)
    assert motion.splits == [30]
    assert motion.rotations == 4  # doubling p could not remove this split: the coarser ladder is kept
    assert motion.segment[29] != motion.segment[30]
    # a joint move (at ξ) between the two motions
    jump = np.abs(motion.q[30] - motion.q[29]).max()
    assert motion.t[30] - motion.t[29] >= jump / cell.max_joint_speed - 1e-12


def test_rotations_double_until_a_path_exists(ur5):
    robot, cell = ur5
    m = 40
    c = np.stack([np.linspace(-20, 20, m), np.zeros(m), np.full(m, 5.0)], 1)
    t = np.tile([0.0, 0.0, 1.0], (m, 1))
    dt = step_times(c, cell.linear_speed, cell.min_step_time)

    def collides(q):  # forbid every pose whose deposition frame has x pointing to -X (θ = -π)
        T_NP = np.linalg.inv(fk(robot, q) @ cell.platform_mount) @ cell.nozzle
        return T_NP[:, 0, 0] < 0

    motion = plan_motion(robot, dataclasses.replace(cell, rotations=1), c, t, dt, collides=collides)
    assert motion.rotations == 2
    assert (motion.segment == 0).all() and motion.splits == []
    assert not collides(motion.q).any()


def test_step_times_give_the_tool_time_to_turn():
    c = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [2.0, 0, 0]])
    t = np.array([[0.0, 0, 1], [0.0, 0, 1], [np.sin(0.2), 0, np.cos(0.2)], [np.sin(0.2), 0, np.cos(0.2)]])
    dt = step_times(c, 10.0, 0.008)  # thesis: Δt = ‖Δc‖ / v̄, floored
    np.testing.assert_allclose(dt, [0.1, 0.1, 0.008])
    dt = step_times(c, 10.0, 0.008, t, 0.5)  # a 0.2 rad turn at 0.5 rad/s takes 0.4 s
    np.testing.assert_allclose(dt, [0.1, 0.4, 0.008])


def test_ramped_steps_are_the_least_times_whose_neighbours_differ_by_the_ratio():
    """ramp_steps against its definition, brute force: Δt'_i = max_j Δt_j / r^|i-j| over the steps
    j of i's path run (a jump between paths is a run of its own), on random times and paths."""
    def brute(dt, pid, r):
        run = [int(pid[i]) if pid[i] == pid[i + 1] else -1 - i for i in range(len(dt))]
        return np.array([max(dt[j] / r ** abs(i - j) for j in range(len(dt))
                             if all(run[k] == run[i] for k in range(min(i, j), max(i, j) + 1)))
                         for i in range(len(dt))])

    rng = np.random.default_rng(7)
    for _ in range(200):
        m = int(rng.integers(2, 30))
        dt, pid = rng.exponential(1.0, m - 1), np.sort(rng.integers(0, 4, m))
        np.testing.assert_allclose(ramp_steps(dt, pid, 1.3), brute(dt, pid, 1.3), rtol=1e-12)
    # one slow step (the tool turning) on a path of 0.1 s steps: the feed ramps down 1.3x a step and back up
    out = ramp_steps(np.r_[np.full(5, 0.1), 1.0, np.full(5, 0.1)], np.zeros(12, int), 1.3)
    np.testing.assert_allclose(out[5 - np.arange(6)], np.maximum(1.0 / 1.3 ** np.arange(6), 0.1))
    np.testing.assert_allclose(out, out[::-1])


def test_the_arm_follows_the_smoothed_axis_and_prints_a_jittery_pass_faster(ur5):
    """A 30 mm pass on the platform whose axis jitters ±5° from sample to sample (0.5 mm apart):
    with the workcell's axis smoothing the arm follows axes within half the deviation bound of the
    tool-path's (recorded as the deviation, reproduced by FK) and turns the tool less, so the pass
    takes far less time than the arm turning the jitter at ω̄; with the smoothing off the axes
    are the tool-path's."""
    robot, cell = ur5
    n = 61
    tilt = np.radians(20.0 + 5.0 * (-1.0) ** np.arange(n))
    tp = dict(positions=np.c_[np.linspace(-15, 15, n), np.zeros(n), np.full(n, 5.0)],
              normals=np.c_[np.sin(tilt), np.zeros(n), np.cos(tilt)], path=np.zeros(n, int), layer=np.ones(n, int),
              feed=np.full(n, 600.0), extrusion=np.r_[0.0, np.full(n - 1, 0.05)])
    rows = np.arange(n)
    smooth = plan_layer(robot, cell, tp, rows)
    plain = plan_layer(robot, dataclasses.replace(cell, axis_smoothing=0.0), tp, rows)
    assert len(smooth.index) == len(plain.index) == n
    np.testing.assert_allclose(plain.normals, tp["normals"], atol=1e-12)
    assert np.allclose(plain.deviation, 0.0)
    realized = np.arccos(np.clip(np.einsum("ij,ij->i", smooth.normals, tp["normals"]), -1, 1))
    np.testing.assert_allclose(smooth.deviation, realized, atol=1e-9)
    assert 0 < realized.max() <= cell.max_axis_deviation / 2 + 1e-9
    tip = np.linalg.inv(fk(robot, smooth.q) @ cell.platform_mount) @ cell.nozzle  # the nozzle in the model frame
    np.testing.assert_allclose(tip[:, :3, 2], smooth.normals, atol=1e-6)
    np.testing.assert_allclose(tip[:, :3, 3], tp["positions"], atol=1e-6)
    assert smooth.t[-1] < 0.5 * plain.t[-1]  # 10° turns at ω̄ = 30°/s set the plain pass's pace


def test_circular_joints_of_the_shipped_robots():
    ur = load_robot("ur5")
    assert circular_joints(ur.lower, ur.upper).tolist() == [True, True, False, True, True, True]
    abb = load_robot("irb120")
    assert circular_joints(abb.lower, abb.upper).tolist() == [False] * 5 + [True]


def test_tilted_axes_lie_on_the_cone_vertical_first():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a = rng.normal(size=3)
        a /= np.linalg.norm(a)
        angle = rng.uniform(0.01, 0.5)
        d = tilted_axes(a, angle, 8)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
        np.testing.assert_allclose(np.arccos(np.clip(d @ a, -1, 1)), angle, atol=1e-7)
        assert d[0, 2] == pytest.approx(d[:, 2].max())  # towards +Z first ...
        assert d[-1, 2] == pytest.approx(d[:, 2].min())  # ... away from it last
    np.testing.assert_allclose(np.arccos(tilted_axes(np.array([0.0, 0, 1]), 0.2, 4)[:, 2]), 0.2)


def _platform_waypoints(tilts_deg, height=1.0):
    a = np.radians(np.asarray(tilts_deg, float))
    c = np.stack([np.linspace(-2, 2, len(a)), np.zeros(len(a)), np.full(len(a), height)], 1)
    return c, np.stack([np.sin(a), np.zeros(len(a)), np.cos(a)], 1)


def test_axis_deviation_frees_a_waypoint_whose_heater_hits_the_platform(ur5):
    """1 mm above the platform at 55° tilt the heater block (5.5 mm above the tip, 8 mm half-width)
    dips below z = 0 (1 + 5.5 cos 55° − 8 sin 55° < 0) for every θ and branch; tilting back within
    the 20° bound frees it, at 80° no tilt within the bound does."""
    robot, cell = ur5
    scene = CollisionScene(robot, cell)
    c, t = _platform_waypoints([55.0, 80.0])
    for j in range(2):
        q, ok = ladder(robot, cell, c[j : j + 1], t[j : j + 1], cell.rotations)
        assert scene.collisions(q[0, ok[0]]).all()  # the planned axis is unrealizable
    axes, dev = deviate_axes(robot, cell, c, t, np.array([True, True]), scene.collisions, cell.rotations)
    assert 0 < dev[0] <= cell.max_axis_deviation + 1e-12
    assert np.arccos(np.clip(axes[0] @ t[0], -1, 1)) == pytest.approx(dev[0], abs=1e-9)
    assert np.arccos(axes[0, 2]) < np.arccos(t[0, 2])  # towards the vertical
    q, ok = ladder(robot, cell, c[:1], axes[:1], cell.rotations)
    assert not scene.collisions(q[0, ok[0]]).all()
    assert dev[1] == 0 and np.allclose(axes[1], t[1], atol=1e-15)  # beyond the bound: left as planned


def test_blocked_rungs_collide_at_every_rotation_and_branch(ur5):
    """The scene's whole-rung test (the heater block's inscribed cylinder about the nozzle axis
    against the platform) marks the 55° and 80° waypoints above, whose every node fcl finds in
    contact at p = 2 × the workcell's, and not the upright or 20° ones."""
    robot, cell = ur5
    scene = CollisionScene(robot, cell)
    c, t = _platform_waypoints([0.0, 20.0, 55.0, 80.0])
    dead = blocked_rungs(scene, c, t)
    np.testing.assert_array_equal(dead, [False, False, True, True])
    assert not blocked_rungs(scene.collisions, c, t).any()  # a bare predicate: no whole-rung test
    q, ok = ladder(robot, cell, c, t, 2 * cell.rotations)
    for j in np.flatnonzero(dead):
        assert ok[j].any() and scene.collisions(q[j, ok[j]]).all()


def test_ladder_at_equals_the_ladder_nodes_at_the_sampled_rotations(ur5):
    robot, cell = ur5
    c, t = _dome_spiral(20)
    p = 6
    q, ok = ladder(robot, cell, c, t, p)
    rng = np.random.default_rng(7)
    s, b = rng.integers(0, p, len(c)), rng.integers(0, 8, len(c))
    got, got_ok = ladder_at(robot, cell, c, t, rotation_samples(p)[s], b)
    k = np.arange(len(c))
    np.testing.assert_array_equal(got_ok, ok[k, 8 * s + b])
    np.testing.assert_allclose(got[got_ok], q[k, 8 * s + b][got_ok], atol=1e-9)


def test_coarse_rungs_keep_every_path_end_and_every_step():
    path = np.repeat([0, 1, 2, 3], [1, 20, 3, 17])
    keep = coarse_rungs(path, 8)
    ends = np.flatnonzero(np.r_[True, path[1:] != path[:-1]] | np.r_[path[1:] != path[:-1], True])
    assert keep[ends].all()
    for pid in range(4):
        rows = np.flatnonzero(path == pid)
        gaps = np.diff(np.flatnonzero(keep[rows]))
        assert (gaps <= 8).all()  # at most step waypoints between kept rungs inside a path
    assert keep.sum() < len(path) / 2
    assert coarse_rungs(path, 1).all()


def test_coarse_to_fine_matches_the_full_search_on_a_dome_spiral(ur5):
    """Every row realized, FK back on the waypoints, limits, ξ and collisions re-checked; the path cost
    (Eq. 3.4) within 5 % of the full ladder's, with far fewer collision checks."""
    robot, cell = ur5
    c, t = _dome_spiral(400)
    dt = step_times(c, cell.linear_speed, cell.min_step_time)
    scene = CollisionScene(robot, cell)
    full = plan_motion(robot, cell, c, t, dt, collides=scene.collisions)
    fast = plan_motion(robot, cell, c, t, dt, collides=scene.collisions, keep=coarse_rungs(np.zeros(len(c)), 8))
    assert (fast.segment >= 0).all() and len(fast.splits) <= len(full.splits)
    same = _assert_realizes(robot, cell, scene, fast, c, t)
    # the recomputed cost of the chosen rows is Eq. 3.4 summed inside the motions
    steps = np.abs(np.diff(fast.q, axis=0)).sum(axis=1)
    assert fast.cost == pytest.approx(steps[same].sum(), rel=1e-9)
    assert fast.cost <= full.cost * 1.05
    assert fast.collision_checks < full.collision_checks / 2
    assert (fast.solutions[coarse_rungs(np.zeros(len(c)), 8)] > 0).all()


def test_coarse_to_fine_falls_back_to_the_full_search_where_filling_fails(ur5):
    """The axis flip of test_split_when_the_axis_flips_faster_than_xi inside a coarse gap, and a
    waypoint inside a gap without a collision-free pose: same splits and skips as the full search."""
    robot, cell = ur5
    c, t = _dome_spiral(60, turns=0.0, tilt_deg=40.0)
    t[30:, :2] *= -1
    dt = step_times(c, cell.linear_speed, cell.min_step_time)
    small = dataclasses.replace(cell, rotations=4)
    keep = coarse_rungs(np.zeros(len(c)), 8)
    full = plan_motion(robot, small, c, t, dt, max_rotations=8)
    fast = plan_motion(robot, small, c, t, dt, max_rotations=8, keep=keep)
    assert fast.splits == full.splits == [30]

    def collides(q):  # every pose of waypoint 13 (between kept rungs 8 and 16) collides
        pos, _ = waypoints_from_flange(small, fk(robot, q))
        return np.linalg.norm(pos - c[13], axis=1) < 1e-6

    full = plan_motion(robot, small, c[:30], t[:30], dt[:29], collides=collides, max_rotations=8)
    fast = plan_motion(robot, small, c[:30], t[:30], dt[:29], collides=collides, max_rotations=8, keep=keep[:30])
    np.testing.assert_array_equal(fast.segment, full.segment)  # skipped at 13, a new motion after it
    assert fast.segment[13] == -1 and fast.splits == full.splits == [14]
    assert not collides(fast.q[fast.segment >= 0]).any()


def test_batched_axis_deviation_equals_one_waypoint_at_a_time(ur5):
    robot, cell = ur5
    scene = CollisionScene(robot, cell)
    c, t = _platform_waypoints([55.0, 80.0, 50.0, 62.0, 10.0])
    stuck = np.array([True, True, True, True, False])
    axes, dev = deviate_axes(robot, cell, c, t, stuck, scene.collisions, 4)
    for j in range(len(c)):
        one = np.zeros(len(c), bool)
        one[j] = stuck[j]
        a1, d1 = deviate_axes(robot, cell, c, t, one, scene.collisions, 4)
        assert d1[j] == dev[j]
        np.testing.assert_allclose(a1[j], axes[j], atol=1e-15)
    assert dev[4] == 0 and (dev[[0, 2]] > 0).all()  # (62° and 80° need more than the 20° bound)


def test_remembered_collisions_ask_each_configuration_once():
    asked = []

    def collides(q):
        asked.append(len(q))
        return q[:, 0] > 0

    memo = Remembered(collides)
    q = np.random.default_rng(0).normal(size=(50, 6))
    first = memo(np.r_[q[:30], q[:5]])
    again = memo(q)
    np.testing.assert_array_equal(first, np.r_[q[:30], q[:5]][:, 0] > 0)
    np.testing.assert_array_equal(again, q[:, 0] > 0)
    assert asked == [30, 20] and memo.asked == 50


def test_rung_memo_gives_the_ladder_nodes_at_any_p(ur5):
    """Remembered rungs equal fresh ones bit for bit, whether the memo holds a finer p (every other
    θ sample), a coarser one (only the new samples solved) or neither."""
    robot, cell = ur5
    c, t = _dome_spiral(12)
    memo = RungMemo()
    for p, rows in ((6, slice(0, 8)), (3, slice(0, 12)), (12, slice(2, 10)), (4, slice(0, 12)), (12, slice(0, 12))):
        got, got_ok = memo.ladder(robot, cell, c[rows], t[rows], p)
        want, want_ok = ladder(robot, cell, c[rows], t[rows], p)
        np.testing.assert_array_equal(got_ok, want_ok)
        np.testing.assert_array_equal(got, want)


def test_edge_memo_keeps_the_shortest_path_and_is_reused():
    rng = np.random.default_rng(11)
    for _ in range(30):
        q, valid, dt, circ = _random_ladder(rng)
        memo, small = EdgeMemo(), EdgeMemo(budget=2000)
        want, _, _ = shortest_path(q, valid, dt, 1.0, circ)
        got, _, _ = shortest_path(q, valid, dt, 1.0, circ, edge_memo=memo)
        size = len(memo.held)
        again, _, _ = shortest_path(q, valid, dt, 1.0, circ, edge_memo=memo)
        for _ in range(2):
            tight, _, _ = shortest_path(q, valid, dt, 1.0, circ, edge_memo=small)  # entries dropped, same path
            assert small.size <= small.budget
        for path in (got, again, tight):
            np.testing.assert_array_equal(path.node, want.node)
            assert path.cost == want.cost
        assert len(memo.held) == size  # the second search computed no edges


def test_held_frames_collide_on_every_branch_at_that_rotation(ur5):
    """A nozzle frame whose extruder meets the platform (one fcl test) makes every IK node at that θ
    collide (fcl node by node); both answers occur on waypoints near the platform."""
    robot, cell = ur5
    scene = CollisionScene(robot, cell)
    c, t = _platform_waypoints([0.0, 30.0, 45.0, 55.0, 65.0, 80.0], height=2.0)
    p = cell.rotations
    q, ok = ladder(robot, cell, c, t, p)
    j, s = np.divmod(np.arange(len(c) * p), p)
    held = held_frames(scene, c[j], t[j], rotation_samples(p)[s])
    assert held.any() and not held.all()
    assert not held_frames(scene.collisions, c[j], t[j], rotation_samples(p)[s]).any()  # bare predicate: no test
    for jj, ss in zip(j[held], s[held]):
        nodes = np.arange(8 * ss, 8 * ss + 8)
        nodes = nodes[ok[jj, nodes]]
        assert scene.collisions(q[jj, nodes]).all()


def test_held_frames_and_node_checks_share_fcl_answers_without_changing_them(ur5):
    """held_blocked and collisions keep one fcl answer per relative pose of a carried and a static
    body: asked in either order, with a printed part carried, the answers equal fcl on every pair
    (no memory), and the second asker tests fewer poses with fcl."""
    import fcl

    robot, cell = ur5
    c, t = _platform_waypoints([0.0, 30.0, 45.0, 55.0, 65.0, 80.0], height=2.0)
    p = cell.rotations
    j, s = np.divmod(np.arange(len(c) * p), p)
    frames = turned_frames(c[j], t[j], rotation_samples(p)[s])
    part = trimesh.creation.box((6.0, 30.0, 3.0))
    part.apply_translation([4.0, 0.0, 1.5])  # printed layers beside the waypoints

    def fresh() -> CollisionScene:
        scene = CollisionScene(robot, cell)
        scene.set_part(part)
        return scene

    ref_scene = fresh()
    held = ref_scene.nozzle @ np.linalg.inv(frames)
    request = fcl.CollisionRequest()
    want = []
    for T in held:
        for carried in ref_scene.carried:
            carried.obj.setRotation(T[:3, :3])
            carried.obj.setTranslation(T[:3, 3])
        want.append(any(fcl.collide(a.obj, b.obj, request, fcl.CollisionResult())
                        for a in ref_scene.carried for b in ref_scene.static))
    want = np.array(want)
    assert want.any() and not want.all()
    q, ok = ladder(robot, cell, c, t, p)
    nodes = q[ok]
    first = fresh()
    np.testing.assert_array_equal(first.held_blocked(frames), want)
    node_answers = first.collisions(nodes)
    np.testing.assert_array_equal(node_answers, [bool(x) for x in first.colliding_pairs(nodes)])
    second = fresh()
    tested = []
    inner = second._test_pair
    second._test_pair = lambda placed, k, *fixed: tested.append(len(placed)) or inner(placed, k, *fixed)
    np.testing.assert_array_equal(second.collisions(nodes), node_answers)
    alone = sum(tested)
    np.testing.assert_array_equal(second.held_blocked(frames), want)
    assert sum(tested) - alone < len(frames)  # frames answered from the nodes' relative poses


def test_rotation_sweep_holds_the_box_at_every_rotation(ur5):
    """The sweep cylinder of the UR5 heater block holds the block's corners turned by any θ about the
    nozzle axis, and touches its farthest edge (radius = half the footprint's diagonal); the mount
    beam, reaching 440 mm off the axis, has none (its sweep would meet everything)."""
    _, cell = ur5
    heater, beam = (b for b in cell.extruder if b.name in ("heater_block", "mount_beam"))
    geom, pose = rotation_sweep(heater)
    half = np.asarray(heater.dims) / 2
    corners = np.array(np.meshgrid(*[[-h, h] for h in half], indexing="ij")).reshape(3, -1).T
    inside_N = corners @ heater.pose[:3, :3].T + heater.pose[:3, 3]
    for theta in np.linspace(0, 2 * np.pi, 37):
        c, s = np.cos(theta), np.sin(theta)
        turned = inside_N @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T - pose[:3, 3]
        assert (np.hypot(turned[:, 0], turned[:, 1]) <= geom.radius + 1e-9).all()
        assert (np.abs(turned[:, 2]) <= geom.lz / 2 + 1e-9).all()
    assert geom.radius == pytest.approx(np.hypot(half[0], half[1]))
    assert rotation_sweep(beam) is None


def test_blocked_frames_answer_the_axis_bodies_without_changing_answers(ur5):
    """After :meth:`CollisionScene.blocked` of the waypoints' frames (its free frames answer the
    nozzle cone and extruder cylinder at every θ from memory), node checks still equal fcl's
    exhaustive answers (:meth:`CollisionScene.colliding_pairs`), and fewer pair tests reach fcl."""
    robot, cell = ur5
    c, t = _platform_waypoints([0.0, 30.0, 45.0, 55.0, 65.0, 80.0], height=2.0)
    part = trimesh.creation.box((6.0, 30.0, 3.0))
    part.apply_translation([4.0, 0.0, 1.5])
    q, ok = ladder(robot, cell, c, t, cell.rotations)
    nodes = q[ok]
    counts = []
    for first_blocked in (False, True):
        scene = CollisionScene(robot, cell)
        scene.set_part(part)
        tested = []
        inner = scene._test_pair
        scene._test_pair = lambda placed, k, *fixed: tested.append(len(placed)) or inner(placed, k, *fixed)
        if first_blocked:
            blocked = scene.blocked(turned_frames(c, t, np.zeros(len(c))))
            assert not blocked.all()
        np.testing.assert_array_equal(scene.collisions(nodes), [bool(x) for x in scene.colliding_pairs(nodes)])
        counts.append(sum(tested))
    assert counts[1] < counts[0]


def test_distinct_groups_rows_by_value_small_or_sorted():
    """_distinct (a dict for few rows, a sort for many): each row's group holds its value, one first
    row per value (its first occurrence), the values' bytes in the first rows' order."""
    rng = np.random.default_rng(8)
    for n in (1, 7, SMALL_DISTINCT, SMALL_DISTINCT + 1, 500):
        key = rng.integers(0, 4, (n, 3)).astype(np.int64)
        first, group, names = _distinct(key)
        np.testing.assert_array_equal(key[first[group]], key)
        assert len({k.tobytes() for k in key[first]}) == len(first)
        assert all(first[g] == np.flatnonzero(group == g)[0] for g in range(len(first)))
        assert names == [key[i].tobytes() for i in first]


def test_hopeless_rungs_never_drop_a_waypoint_with_a_free_pose(ur5):
    """A rung marked hopeless at p has no collision-free node at p (exhaustive fcl); rungs with one
    are never marked; the 80° waypoint is (no θ keeps the heater block above the platform)."""
    robot, cell = ur5
    scene = CollisionScene(robot, cell)
    c, t = _platform_waypoints([0.0, 20.0, 40.0, 50.0, 55.0, 60.0, 70.0, 80.0], height=1.5)
    p = 2 * cell.rotations
    hopeless = hopeless_rungs(scene, c, t, p)
    q, ok = ladder(robot, cell, c, t, p)
    free = np.array([(~scene.collisions(q[j, ok[j]])).any() if ok[j].any() else False for j in range(len(c))])
    assert not (hopeless & free).any()
    assert hopeless[-1] and free[0]


def test_early_skips_plan_the_same_layer_as_the_full_search(ur5):
    """plan_layer with the scene (its whole-rung and per-frame tests find the hopeless rungs before
    the search, whose axes are then deviated before it) realizes, deviates and skips exactly the
    waypoints the node-by-node search does (which deviates them after searching); its joints
    reproduce the deviated waypoints, within the limits, ξ and free of collision."""
    robot, cell = ur5
    cell = dataclasses.replace(cell, rotations=8)
    scene = CollisionScene(robot, cell)
    c, t = _platform_waypoints([10.0, 55.0, 62.0, 80.0, 30.0], height=1.5)
    tp = {"positions": c, "normals": t, "path": np.zeros(len(c), int), "feed": np.full(len(c), 1200.0),
          "layer": np.ones(len(c), int), "extrusion": np.ones(len(c))}
    rows = np.arange(len(c))
    fast = plan_layer(robot, cell, tp, rows, scene, coarse_step=1)
    full = plan_layer(robot, cell, tp, rows, scene.collisions, coarse_step=1)
    assert 0 < len(fast.index) < len(c) and (fast.deviation > 0).any()
    np.testing.assert_array_equal(fast.index, full.index)
    np.testing.assert_array_equal(fast.deviation, full.deviation)
    np.testing.assert_allclose(fast.normals, full.normals, atol=1e-12)
    for motion in (fast, full):
        _assert_realizes(robot, cell, scene, motion, c[motion.index], motion.normals)


def _dome_gap(robot, cell, n: int):
    """The first ``n`` waypoints of the dome spiral as a gap to fill: positions, axes, step times,
    elapsed times, the circular joints, and an IK branch that reaches every waypoint at θ = 0.35 rad."""
    c, t = _dome_spiral(200)
    c, t = c[:n], t[:n]
    dt = step_times(c, cell.linear_speed, cell.min_step_time)
    lo, hi = cell.limits(robot)
    branch = next(b for b in range(8) if ladder_at(robot, cell, c, t, np.full(n, 0.35), np.full(n, b))[1].all())
    return c, t, dt, np.r_[0.0, np.cumsum(dt)], circular_joints(lo, hi), branch


def test_band_fill_goes_round_a_blocked_range_of_rotations_and_leaves_a_dead_gap_open(ur5):
    """_band_fill on two gaps in one ladder: where every θ within 22.5° of the interpolation collides
    at one inner waypoint, its path takes a θ outside that range; every node reproduces its waypoint
    on the gap's branch, ξ holds on every step, no node collides. A gap whose inner waypoint
    collides at every band θ stays open and its rows untouched."""
    robot, cell = ur5
    c, t, dt, elapsed, circ, branch = _dome_gap(robot, cell, 17)
    ends = np.array([0, 8, 16])
    theta = np.array([0.3, 0.4, 0.5])
    q_end, ok = ladder_at(robot, cell, c[ends], t[ends], theta, np.full(3, branch))
    assert ok.all()
    u = (elapsed[4] - elapsed[0]) / (elapsed[8] - elapsed[0])
    near = BAND[np.abs(BAND) <= np.radians(22.5) + 1e-9]
    blocked, _ = ladder_at(robot, cell, np.repeat(c[4:5], len(near), 0), np.repeat(t[4:5], len(near), 0),
                           0.3 + 0.1 * u + near, np.full(len(near), branch))

    def collides(q):
        return (np.abs(q[:, None] - blocked[None]).max(axis=2) < 1e-9).any(axis=1)

    chosen = np.full((17, 6), np.nan)
    chosen[ends] = q_end
    link = np.zeros(17, bool)
    filled, asked = _band_fill(robot, cell, c, t, dt, elapsed, ends[:2], ends[1:], theta[:2], theta[1:],
                               np.full(2, branch), collides, circ, chosen, link)
    assert filled.all() and link[1:].all() and asked > 0
    assert not collides(chosen).any()
    pos, axis = waypoints_from_flange(cell, fk_reference(robot, chosen))
    assert np.abs(pos - c).max() < 1e-6 and np.abs(axis - t).max() < 1e-9
    step = joint_steps(chosen[:-1], chosen[1:], circ)[1]
    assert (step <= cell.max_joint_speed * dt * (1 + 1e-9)).all()

    def dead(q):
        frames = waypoints_from_flange(cell, fk_reference(robot, q))[0]
        return np.linalg.norm(frames - c[4], axis=1) < 1e-6  # every pose of waypoint 4

    chosen = np.full((17, 6), np.nan)
    chosen[ends] = q_end
    link = np.zeros(17, bool)
    filled, _ = _band_fill(robot, cell, c, t, dt, elapsed, ends[:2], ends[1:], theta[:2], theta[1:],
                           np.full(2, branch), dead, circ, chosen, link)
    assert not filled[0] and filled[1]
    assert np.isnan(chosen[1:8]).all() and not link[1:9].any() and link[9:].all()


def test_band_windows_widen_merge_and_keep_ends_on_one_motion_and_branch():
    """_band_windows: each open gap widened by ``step`` coarse rungs (clipped to the path), windows that
    overlap merged into one, and a window kept only where both its ends are on the coarse path, in one
    motion and on one IK branch (its pinned ends)."""
    n = 20
    node = np.zeros(n, int)
    node[17] = -1  # a rung without a node
    segment = np.r_[np.zeros(12, int), np.ones(8, int)]  # a split between rungs 11 and 12
    branch = np.zeros(n, int)
    branch[8] = 3  # inside a window: no matter

    def windows(ca, cb, step):
        coarse = _Found(node, segment, np.zeros((n, 6)), np.zeros(n), branch, 15, np.full(n, 8), 0)
        a, b = _band_windows(np.array(ca), np.array(cb), coarse, step)
        return list(zip(a.tolist(), b.tolist()))

    # 1-2, 3-4, 6-7 widen to 0-4, 1-6, 4-9 and merge to 0-9; 12-13 and 15-16 to 10-15 and 13-18, merged
    # to 10-18, which crosses the split
    assert windows([1, 3, 6, 12, 15], [2, 4, 7, 13, 16], 2) == [(0, 9)]
    assert windows([13], [14], 1) == [(12, 15)]
    assert windows([14], [15], 2) == []  # 12-17 ends on the rung without a node
    assert windows([17], [18], 5) == [(12, 19)]  # clipped to the path's last rung
    branch[19] = 3
    assert windows([17], [18], 5) == []  # its ends on two branches


def test_a_gap_whose_interpolated_rotation_collides_is_filled_by_a_bump(ur5):
    """_fill: where a node of the θ interpolated in time collides, a smooth bump δ·sin²(πu) of θ
    (δ from BUMPS, smallest first) fills the gap instead: the colliding node is avoided, every
    node reproduces its waypoint on the gap's IK branch, ξ holds on every step, and θ leaves the
    interpolation by at most the bump."""
    robot, cell = ur5
    c, t, dt, elapsed, circ, branch = _dome_gap(robot, cell, 9)
    qa, ok = ladder_at(robot, cell, c[[0, 8]], t[[0, 8]], np.array([0.3, 0.4]), np.full(2, branch))
    assert ok.all()
    u = (elapsed[1:8] - elapsed[0]) / (elapsed[8] - elapsed[0])
    straight, _ = ladder_at(robot, cell, c[1:8], t[1:8], 0.3 + 0.1 * u, np.full(7, branch))
    blocked = straight[3]

    def collides(q):
        return np.abs(q - blocked).max(axis=1) < 1e-9

    chosen = np.full((9, 6), np.nan)
    chosen[[0, 8]] = qa
    link = np.zeros(9, bool)
    good, asked = _fill(robot, cell, c, t, dt, elapsed, np.array([0]), np.array([8]), np.array([0.3]),
                        np.array([0.4]), np.array([branch]), collides, circ, chosen, link)
    assert good.all() and link[1:].all() and asked > 7
    assert not collides(chosen).any()
    pos, axis = waypoints_from_flange(cell, fk_reference(robot, chosen))
    assert np.abs(pos - c).max() < 1e-6 and np.abs(axis - t).max() < 1e-9
    step = joint_steps(chosen[:-1], chosen[1:], circ)[1]  # circular joints the short way round
    assert (step <= cell.max_joint_speed * dt * (1 + 1e-9)).all()
    bumped = [ladder_at(robot, cell, c[1:8], t[1:8], 0.3 + 0.1 * u + d * np.sin(np.pi * u) ** 2,
                        np.full(7, branch))[0] for d in np.r_[-BUMPS, BUMPS]]
    assert any(np.abs(q - chosen[1:8]).max() < 1e-12 for q in bumped)  # one of the bumps, exactly
