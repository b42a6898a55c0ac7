"""Analytic IK (§3.5.3) against pinocchio's FK on the URDFs, and against a dense numerical search."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from curvslice.errors import CurvsliceError
from curvslice.kinematics import ROBOT_NAMES, fk, fk_reference, ik, link_placements, load_robot


@pytest.fixture(scope="module", params=ROBOT_NAMES)
def robot(request):
    return load_robot(request.param)


def _random_q(robot, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi), (n, 6))


def _circ(a, b):
    return np.abs((a - b + np.pi) % (2 * np.pi) - np.pi)


def _rot_err(Ra, Rb):
    """Rotation angle (rad) between stacks of rotation matrices."""
    c = (np.einsum("nij,nij->n", Ra, Rb) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def test_analytic_fk_matches_pinocchio(robot):
    q = _random_q(robot, 500, 0)
    assert np.abs(fk(robot, q) - fk_reference(robot, q)).max() < 1e-6


def test_every_ik_solution_reproduces_the_pose(robot):
    """10,000 random reachable poses: each returned branch is checked by pinocchio FK."""
    q = _random_q(robot, 10_000, 1)
    T = fk_reference(robot, q)
    sols, ok = ik(robot, T)
    assert ok.any(axis=1).all()
    flat = sols[ok]
    target = np.repeat(T, ok.sum(axis=1), axis=0)
    back = fk_reference(robot, flat)
    pos = np.linalg.norm(back[:, :3, 3] - target[:, :3, 3], axis=1)
    assert pos.max() < 1e-3  # mm, i.e. 1e-6 m
    assert _rot_err(back[:, :3, :3], target[:, :3, :3]).max() < 1e-6
    # the configuration that generated each pose is among the solutions (modulo 2 pi)
    d = _circ(sols, q[:, None]).max(axis=2)
    d[~ok] = np.inf
    assert (d.min(axis=1) < 1e-6).all()


def _numerical_solutions(robot, T, starts, rng):
    """Damped least-squares IK from many random starts with pinocchio; converged results."""
    model, data = robot.model, robot.model.createData()
    target = pin.SE3(T[:3, :3], T[:3, 3] / 1000.0)
    found = []
    for q in rng.uniform(-np.pi, np.pi, (starts, 6)):
        for _ in range(80):
            pin.forwardKinematics(model, data, q)
            current = pin.updateFramePlacement(model, data, robot.tool_frame)
            err = pin.log6(current.actInv(target)).vector
            if np.linalg.norm(err) < 1e-11:
                found.append((q + np.pi) % (2 * np.pi) - np.pi)
                break
            J = pin.computeFrameJacobian(model, data, q, robot.tool_frame, pin.LOCAL)
            q = q + J.T @ np.linalg.solve(J @ J.T + 1e-8 * np.eye(6), err)
    return np.array(found)


def _cluster(qs, tol=1e-4):
    reps = []
    for q in qs:
        if not any(_circ(q, r).max() < tol for r in reps):
            reps.append(q)
    return np.array(reps)


def test_solution_count_matches_dense_numerical_search(robot):
    rng = np.random.default_rng(7)
    q = _random_q(robot, 6, 2)
    T = fk_reference(robot, q)
    sols, ok = ik(robot, T)
    for i in range(len(q)):
        numeric = _cluster(_numerical_solutions(robot, T[i], 150, rng))
        analytic = _cluster(sols[i][ok[i]])
        assert len(numeric) == len(analytic), (robot.name, i, len(numeric), len(analytic))
        # every numerically found solution is one of the analytic ones
        for s in numeric:
            assert _circ(analytic, s).max(axis=1).min() < 1e-4


def test_one_branch_solve_equals_that_branch_of_the_full_solve(robot):
    T = fk(robot, _random_q(robot, 400, 5))
    branch = np.random.default_rng(6).integers(0, 8, len(T))
    q, ok = ik(robot, T)
    qb, okb = ik(robot, T, branch=branch)
    k = np.arange(len(T))
    np.testing.assert_array_equal(okb, ok[k, branch])
    assert okb.mean() > 0.5
    np.testing.assert_allclose(qb[okb], q[k, branch][okb], atol=1e-12)


def test_unreachable_pose_has_no_solution(robot):
    T = np.eye(4)
    T[0, 3] = 5000.0  # 5 m away: beyond every arm's reach
    _, ok = ik(robot, T[None])
    assert not ok.any()


def test_collision_bodies_follow_the_links(robot):
    q = _random_q(robot, 3, 3)
    poses = link_placements(robot, q)
    assert poses.shape == (3, len(robot.links), 4, 4)
    # the body carried by the last joint moves rigidly with the flange
    last = [k for k, s in enumerate(robot.links) if s.joint == 6][0]
    flange = fk_reference(robot, q)
    rel = np.linalg.inv(flange) @ poses[:, last]
    assert np.abs(rel - rel[0]).max() < 1e-6


def test_unknown_robot_is_a_user_error():
    with pytest.raises(CurvsliceError):
        load_robot("kuka")
