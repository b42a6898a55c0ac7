"""Jerk stage (§4.3.2): Eq. 4.7-4.10 against Eq. 4.11 and exact polynomials, the verifier's own
derivatives against the planner's, Algorithm 6 and the global filter on a path with injected jerk
spikes (every row still on its waypoint by pinocchio FK), time-scaling to the limits, Ruckig moves
against the closed-form time-optimal duration, and the verifier failing the unsmoothed graph path."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from curvslice.collision import CollisionScene
from curvslice.exporters.joints_csv import write_robot_outputs
from curvslice.derivatives import combined_stats, derivatives, group_stats, motion_stats, uniform_jerk
from curvslice.jerk import (JerkSettings, dense_projection, global_filter, joint_rates, local_filter, redundancy,
                            trajectory_stage)
from curvslice.time_scaling import Limits, rest_to_rest, state_to_state, time_scale
from curvslice.kinematics import fk_reference, joint_placements, load_robot
from curvslice.motion import plan_motion, plan_print, step_times
from curvslice.verify import robot as verify_robot
from curvslice.verify.robot import _local_derivatives
from curvslice.workcell import load_workcell, waypoints_from_flange


def test_eq_4_10_reduces_to_eq_4_11_on_uniform_times():
    rng = np.random.default_rng(1)
    q = rng.normal(size=(40, 6))
    h = 0.037
    t = 5.0 + h * np.arange(40)
    _, _, jerk = derivatives(q, t, np.zeros(40, int))
    assert np.allclose(jerk[2:-2], uniform_jerk(q, h), rtol=1e-9, atol=1e-9 * np.abs(jerk).max())


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_derivatives_exact_on_polynomials_with_non_uniform_times(degree):
    rng = np.random.default_rng(degree)
    n = 30
    t = np.cumsum(rng.uniform(0.01, 0.4, n))
    seg = np.r_[np.zeros(20, int), np.ones(10, int)]
    c = rng.normal(size=(degree + 1, 6))  # q_j(t) = Σ c_k t^k, per joint
    q = sum(c[k] * t[:, None] ** k for k in range(degree + 1))
    want = [sum(np.prod(np.arange(k - r + 1, k + 1)) * c[k] * t[:, None] ** (k - r) for k in range(r, degree + 1))
            if r <= degree else np.zeros((n, 6)) for r in (1, 2, 3)]
    got = derivatives(q, t, seg)
    for r in range(3):  # every row, the segments' end rows (one-sided windows) included
        assert np.allclose(got[r], want[r], rtol=1e-6, atol=1e-6 * (1 + np.abs(want[r]).max()))
    acc, jerk = _local_derivatives(q, t, seg)  # the verifier's independent solve
    assert np.allclose(acc, want[1], rtol=1e-6, atol=1e-6 * (1 + np.abs(want[1]).max()))
    assert np.allclose(jerk, want[2], rtol=1e-6, atol=1e-6 * (1 + np.abs(want[2]).max()))


def test_verifier_and_planner_derivatives_agree_on_short_segments():
    rng = np.random.default_rng(3)
    seg = np.repeat(np.arange(6), [1, 2, 3, 4, 5, 9])
    t = np.cumsum(rng.uniform(0.02, 0.3, len(seg)))
    q = rng.normal(size=(len(seg), 6))
    _, acc, jerk = derivatives(q, t, seg)
    acc2, jerk2 = _local_derivatives(q, t, seg)
    assert np.allclose(acc, acc2, rtol=1e-7, atol=1e-7 * np.abs(acc).max())
    assert np.allclose(jerk, jerk2, rtol=1e-7, atol=1e-7 * np.abs(jerk).max())
    assert (jerk[:6] == 0).all()  # segments of < 4 rows have no third derivative


def test_stats_per_layer_from_one_pass_equal_each_layers_own():
    rng = np.random.default_rng(5)
    seg = np.repeat(np.arange(7), [9, 3, 12, 1, 8, 6, 11])
    layer = np.repeat([4, 4, 5, 5, 5, 9, 9], [9, 3, 12, 1, 8, 6, 11])  # segments never span layers
    t = np.cumsum(rng.uniform(0.02, 0.3, len(seg)))
    q = rng.normal(size=(len(seg), 6))
    got = group_stats(q, t, seg, layer)
    for v in (4, 5, 9):
        assert got[v] == motion_stats(q[layer == v], t[layer == v], seg[layer == v])
    whole, joined = motion_stats(q, t, seg), combined_stats(got.values(), t)
    assert joined["max_jerk"] == whole["max_jerk"] and joined["max_acceleration"] == whole["max_acceleration"]
    assert joined["total_squared_jerk"] == pytest.approx(whole["total_squared_jerk"], rel=1e-5)


@pytest.fixture(scope="module")
def dome():
    """A spiral on a dome (tilts up to 25°) in the UR5 workcell, planned by the graph search."""
    cell, robot = load_workcell("ur5"), load_robot("ur5")
    m = 70
    s = np.linspace(0, 1, m)
    pol, az = np.radians(25) * (1 - s), 2 * np.pi * 1.5 * s
    nor = np.stack([np.sin(pol) * np.cos(az), np.sin(pol) * np.sin(az), np.cos(pol)], 1)
    pos = 30 * nor
    dt = step_times(pos, 10.0, cell.min_step_time, nor, cell.tool_turn_speed)
    motion = plan_motion(robot, cell, pos, nor, dt)
    assert (motion.segment == 0).all()
    return cell, robot, pos, nor, motion


def _on_waypoints(cell, robot, q, pos, nor):
    p, a = waypoints_from_flange(cell, fk_reference(robot, q))
    return np.linalg.norm(p - pos, axis=1).max(), np.arccos(np.clip(np.einsum("ij,ij->i", a, nor), -1, 1)).max()


def test_joint_rates_are_the_derivatives_of_the_ik_in_theta_and_tilt(dome):
    """dq/dz of the Gauss-Newton filter (Jacobian and the minimal rotation's angular velocity, no
    IK) against central differences of q(z) by IK on each row's branch, at tilted axes."""
    cell, robot, pos, nor, motion = dome
    red, theta = redundancy(robot, cell, pos, nor, motion.q)
    rows = np.arange(0, len(pos), 7)
    rng = np.random.default_rng(3)
    z = np.c_[theta[rows] + rng.uniform(-0.3, 0.3, len(rows)), rng.uniform(-0.08, 0.08, (len(rows), 2))]
    q, ok = red.joints(z, rows, motion.q[rows])
    assert ok.all()
    G = joint_rates(red, z, rows, q)
    h = 1e-5
    for v in range(3):
        step = np.zeros(3)
        step[v] = h
        (qp, okp), (qm, okm) = red.joints(z + step, rows, q), red.joints(z - step, rows, q)
        assert okp.all() and okm.all()
        np.testing.assert_allclose(G[:, :, v], (qp - qm) / (2 * h), atol=1e-6 * max(1.0, np.abs(G).max()))


@pytest.mark.parametrize("method", ["alg6", "global"])
def test_injected_jerk_spikes_are_smoothed_and_rows_stay_on_their_waypoints(dome, method):
    cell, robot, pos, nor, motion = dome
    t, seg = motion.t, motion.segment
    red, theta = redundancy(robot, cell, pos, nor, motion.q)
    assert (red.branch >= 0).all()
    rows = np.arange(len(pos))
    smooth_z, smooth_q, _ = global_filter(red, theta, motion.q, t, seg, Limits.of(robot, cell), JerkSettings())
    base = np.abs(derivatives(smooth_q, t, seg)[2]).max()
    spiked = smooth_z[:, 0].copy()
    spiked[[20, 35, 50]] += [0.25, -0.3, 0.2]  # the arm turns about the nozzle axis and back
    q, ok = red.joints(spiked, rows, smooth_q)
    assert ok.all()
    before = np.abs(derivatives(q, t, seg)[2]).max()
    assert before > 5 * base
    limits = Limits.of(robot, cell)
    limits.jerk = np.full(6, 1.5 * base)  # j_max between the smooth and the spiked path
    limits.acceleration = np.full(6, 1e3)
    if method == "alg6":
        _, out, iterations = local_filter(red, spiked[:, None], q, t, seg, limits, JerkSettings(max_iterations=40))
        assert 0 < iterations <= 40
        assert np.abs(derivatives(out, t, seg)[2]).max() <= limits.jerk[0]  # Alg. 6 stops when none is over j_max
    else:
        _, out, _ = global_filter(red, spiked, q, t, seg, limits, JerkSettings())
        assert np.abs(derivatives(out, t, seg)[2]).max() <= limits.jerk[0]
    err_pos, err_axis = _on_waypoints(cell, robot, out, pos, nor)
    assert err_pos <= 1e-6 and err_axis <= 1e-6  # x_i = f(q_i) exactly (mm, rad)
    speed = lambda qq: (np.abs(np.diff(qq, axis=0)).max(axis=1) / np.diff(t)).max()  # noqa: E731
    assert speed(out) <= speed(q)  # ξ is met exactly by the time-scaling (next test)


def test_time_scaling_meets_the_limits_at_every_row(dome):
    cell, robot, pos, nor, motion = dome
    limits = Limits.of(robot, cell)
    seg = np.r_[np.zeros(40, int), np.ones(30, int)]
    t = motion.t.copy()
    _, acc, jerk = derivatives(motion.q, t, seg)
    assert (np.abs(jerk) > limits.jerk).any()  # the graph path is over j_max
    new_t, rounds, left = time_scale(motion.q, t, seg, limits, JerkSettings())
    assert left == 0 and rounds > 0
    acc, jerk = _local_derivatives(motion.q, new_t, seg)
    assert (np.abs(acc) <= limits.acceleration * (1 + 1e-9)).all()
    assert (np.abs(jerk) <= limits.jerk * (1 + 1e-9)).all()
    inside = seg[1:] == seg[:-1]
    speed = np.abs(np.diff(motion.q, axis=0)).max(axis=1) / np.diff(new_t)
    assert (speed[inside] <= limits.speed * (1 + 1e-9)).all()
    assert (np.diff(new_t) >= np.diff(t) * (1 - 1e-12)).all()  # only slowed down (same E, lower feed)


def test_rest_to_rest_move_is_time_optimal():
    limits = Limits(np.full(6, -7.0), np.full(6, 7.0), 1.0, np.full(6, 3.0), np.full(6, 15.0))
    # one joint moves 3 rad: reaches ξ and a_max, so T = D/v + v/a + a/j (jerk-limited S-curve)
    duration = rest_to_rest(np.zeros(6), np.r_[3.0, 0.1, 0, 0, -0.2, 0], limits)
    assert duration == pytest.approx(3.0 + 1.0 / 3.0 + 3.0 / 15.0, rel=1e-9)


def test_state_to_state_move_from_rest_is_the_rest_to_rest_one_and_a_moving_start_changes_it():
    limits = Limits(np.full(6, -7.0), np.full(6, 7.0), 1.0, np.full(6, 3.0), np.full(6, 15.0))
    qa, qb, zero = np.zeros(6), np.r_[1.0, 0.3, 0, 0, -0.2, 0], np.zeros(6)
    assert state_to_state(qa, zero, zero, qb, zero, zero, limits) == rest_to_rest(qa, qb, limits)
    toward = state_to_state(qa, np.r_[0.8, 0, 0, 0, 0, 0], zero, qb, zero, zero, limits)
    away = state_to_state(qa, np.r_[-0.8, 0, 0, 0, 0, 0], zero, qb, zero, zero, limits)
    assert toward < rest_to_rest(qa, qb, limits) < away  # already moving toward qb helps, away costs a turn-back


def test_verify_fails_the_graph_path_and_passes_the_jerk_one(dome, tmp_path):
    cell, robot, pos, nor, motion = dome
    # the dome's axes are exact (no facet jitter for the workcell's axis smoothing to remove): the arm follows
    # them as the thesis plans, which the graph search turns into jerk far over j_max
    cell = dataclasses.replace(cell, axis_smoothing=0.0)
    n = len(pos)
    tp = dict(positions=pos, normals=nor, layer=np.ones(n, np.int32), path=np.ones(n, np.int32),
              extrusion=np.r_[0.0, np.full(n - 1, 0.05)], thickness=np.full(n, 0.8), feed=np.full(n, 600.0))
    scene = CollisionScene(robot, cell)
    graph = plan_print(robot, cell, tp, lambda layer: scene.collisions)
    for kind in ("graph", "jerk"):
        out = tmp_path / kind
        out.mkdir()
        np.savez(out / "toolpaths.npz", **tp)
        motion, report = trajectory_stage(robot, cell, tp, graph, kind, lambda layer: scene.collisions)
        write_robot_outputs(out, cell, robot.family, tp, motion)
        failed = {c.name for c in verify_robot.checks(out) if not c.passed}
        if kind == "graph":
            assert "joint jerk within limits" in failed
        else:
            assert not failed, failed
            assert report["after"]["total_squared_jerk"] < 0.1 * report["before"]["total_squared_jerk"]
            assert report["rows_over_limits"] == 0


def _ball_obstacle(robot, centre, radius):
    """A known obstacle: the wrist frame (joint 5) inside a ball of ``radius`` mm about ``centre``."""
    return lambda q: np.linalg.norm(joint_placements(robot, q)[:, 5, :3, 3] - centre, axis=1) < radius


def test_dense_projection_is_the_nearest_free_sample_of_eq_4_13(dome):
    cell, robot, pos, nor, motion = dome
    limits = Limits.of(robot, cell)
    red, theta = redundancy(robot, cell, pos, nor, motion.q)
    rows = np.array([10, 40])
    z = np.c_[theta[rows], np.zeros((2, 2))]
    collides = _ball_obstacle(robot, joint_placements(robot, motion.q[rows[:1]])[0, 5, :3, 3], 40.0)
    assert collides(motion.q[rows[:1]]).all()
    settings = JerkSettings(projection_checks=4000)
    pz, pq, found, checks = dense_projection(red, z, motion.q[rows], rows, limits, collides, settings)
    assert found.all() and checks > 0
    assert not collides(pq).any() and not limits.beyond(pq).any()
    err_pos, err_axis = _on_waypoints(cell, robot, pq, pos[rows], nor[rows])
    assert err_pos <= 1e-6 and err_axis <= 1e-6
    for i, r in enumerate(rows):  # brute force: every θ sample (step π/500), every one fcl-checked
        s = theta[r] + np.pi / 500 * np.r_[np.arange(1, 501), -np.arange(1, 501)]
        qq, ok = red.joints(np.c_[s, np.zeros((len(s), 2))], np.full(len(s), r), np.tile(motion.q[r], (len(s), 1)))
        good = ok & ~limits.beyond(qq) & ~collides(qq)
        best = np.abs(qq[good] - motion.q[r]).max(axis=1).min()
        assert np.abs(pq[i] - motion.q[r]).max() == pytest.approx(best, abs=1e-12)


def test_a_final_row_hitting_an_obstacle_is_projected_not_reverted(dome):
    cell, robot, pos, nor, motion = dome
    n = len(pos)
    tp = dict(positions=pos, normals=nor, layer=np.ones(n, np.int32), path=np.ones(n, np.int32),
              extrusion=np.r_[0.0, np.full(n - 1, 0.05)], thickness=np.full(n, 0.8), feed=np.full(n, 600.0))
    motion = plan_print(robot, cell, tp)
    free_run, _ = trajectory_stage(robot, cell, tp, motion, "jerk")
    # an obstacle where the optimized pose of row 35 puts the wrist, missed by the graph's pose
    centre = joint_placements(robot, free_run.q[[35]])[0, 5, :3, 3]
    radius = 0.5 * np.linalg.norm(joint_placements(robot, motion.q)[:, 5, :3, 3] - centre, axis=1).min()
    collides = _ball_obstacle(robot, centre, radius)
    assert not collides(motion.q).any() and collides(free_run.q).any()
    out, report = trajectory_stage(robot, cell, tp, motion, "jerk", lambda layer: collides)
    assert not collides(out.q).any()
    assert report["rows_projected"] >= 1
    err_pos, err_axis = _on_waypoints(cell, robot, out.q, pos, out.normals)
    assert err_pos <= 1e-6 and err_axis <= 1e-6
    assert report["rows_over_limits"] == 0
    assert report["after"]["total_squared_jerk"] < 0.1 * report["before"]["total_squared_jerk"]


def test_a_jump_between_pieces_becomes_a_ruckig_move(dome):
    cell, robot, pos, nor, motion = dome
    n = len(pos)
    path = np.r_[np.ones(40, np.int32), np.full(n - 40, 2, np.int32)]  # a second piece starts at row 40
    extrusion = np.r_[0.0, np.full(39, 0.05), 0.0, np.full(n - 41, 0.05)]
    tp = dict(positions=pos, normals=nor, layer=np.ones(n, np.int32), path=path, extrusion=extrusion,
              thickness=np.full(n, 0.8), feed=np.full(n, 600.0))
    graph = plan_print(robot, cell, tp)
    assert len(np.unique(graph.segment)) == 1  # the graph search carries on across the jump
    out, report = trajectory_stage(robot, cell, tp, graph, "jerk")
    rows = np.flatnonzero(out.index == 40)[0]
    assert out.segment[rows] != out.segment[rows - 1] and len(np.unique(out.segment)) == 2
    assert not out.extruding[rows]
    limits = Limits.of(robot, cell)
    # the move starts from the state the first piece ends in and reaches the one the second starts in
    # (Eq. 4.7-4.10 by the verifier's own solve at those rows): neither is at rest
    vel, acc, _ = _local_derivatives(out.q, out.t, out.segment, orders=(1, 2, 3))
    assert np.abs(vel[rows - 1]).max() > 1e-3 and np.abs(vel[rows]).max() > 1e-3
    want = max(state_to_state(out.q[rows - 1], vel[rows - 1], acc[rows - 1], out.q[rows], vel[rows], acc[rows], limits),
               cell.min_step_time)
    assert out.t[rows] - out.t[rows - 1] == pytest.approx(want, rel=1e-6)
    assert verify_robot._move_check(out.q, out.t, out.segment, cell, robot).passed
    short = out.t - np.where(np.arange(n) >= rows, 0.1 * want, 0.0)  # the move 10 % too short: the verifier fails it
    assert not verify_robot._move_check(out.q, short, out.segment, cell, robot).passed
    # "before" is the graph's own trajectory (its one segment), as --trajectory graph reports it
    assert report["before"]["total_squared_jerk"] == trajectory_stage(robot, cell, tp, graph, "graph")[1]["layers"][0]["before"]["total_squared_jerk"]
    acc, jerk = _local_derivatives(out.q, out.t, out.segment)
    assert (np.abs(jerk) <= limits.jerk * (1 + 1e-9)).all() and (np.abs(acc) <= limits.acceleration * (1 + 1e-9)).all()


def test_the_tilt_stays_within_what_the_axis_smoothing_leaves_of_the_bound():
    """A pass whose tool-path axis jitters ±6° (the smoothing moves every axis): the jerk stage's tilt comes on
    top of the smoothing's deviation, and every final axis stays within the workcell's bound of the
    tool-path's own (realized by FK), also with a tight bound (2°: 1° of smoothing, 1° left for the tilt). The
    smoothed rows still tilt (they kept their axis while the smoothing counted as a deviation of its own)."""
    robot = load_robot("ur5")
    n = 61
    tilt = np.radians(20.0 + 6.0 * (-1.0) ** np.arange(n))
    nor = np.c_[np.sin(tilt), np.zeros(n), np.cos(tilt)]
    tp = dict(positions=np.c_[np.linspace(-15, 15, n), np.zeros(n), np.full(n, 5.0)], normals=nor,
              path=np.zeros(n, np.int32), layer=np.ones(n, np.int32), feed=np.full(n, 600.0),
              extrusion=np.r_[0.0, np.full(n - 1, 0.05)], thickness=np.full(n, 0.8))
    for bound in (20.0, 2.0):
        # σ = 1 mm (not the default 2.5, which takes nearly all of this jitter out) leaves the stage some to tilt
        cell = dataclasses.replace(load_workcell("ur5"), max_axis_deviation=np.radians(bound), axis_smoothing=1.0)
        graph = plan_print(robot, cell, tp)
        out, _ = trajectory_stage(robot, cell, tp, graph, "jerk")
        realized = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", out.normals, nor[out.index]), -1, 1)))
        smoothed = np.degrees(graph.deviation)
        tilted = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", out.normals, graph.normals), -1, 1)))
        assert len(out.index) == n and smoothed.max() >= min(bound / 2, 4.0) - 1e-6  # the smoothing moved the axes
        assert tilted.max() > 0.05  # and the jerk stage tilted them further
        assert realized.max() <= bound + 1e-6 and (out.deviation >= np.radians(realized) - 1e-9).all()
        T = np.linalg.inv(fk_reference(robot, out.q) @ cell.platform_mount) @ cell.nozzle
        np.testing.assert_allclose(T[:, :3, 2], out.normals, atol=1e-6)
        np.testing.assert_allclose(T[:, :3, 3], tp["positions"][out.index], atol=1e-3)
