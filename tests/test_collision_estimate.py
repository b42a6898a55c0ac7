"""Collision estimation (§4.4): the sphere proxy never calls a colliding configuration free, its
covers and distance field are conservative, and the learned indication function is safe on its
training samples; all checked against fcl / trimesh's exact distances."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from curvslice.collision import CollisionScene
from curvslice.collision_estimate import (
    LearnedCollision,
    axis_spheres,
    contact_centred_samples,
    contact_configurations,
    distance_grid,
    sphere_cover,
)
from curvslice.kinematics import load_robot
from curvslice.workcell import Body, load_workcell, pose_matrix


def _inside_some_sphere(points, centre, radius):
    return (np.linalg.norm(points[:, None] - centre[None], axis=2) <= radius[None] + 1e-9).any(axis=1)


def test_sphere_covers_contain_the_surface():
    for mesh in (trimesh.creation.box((16, 20, 12)), trimesh.creation.cone(4.2, 5.0), load_robot("ur5").links[2].mesh):
        pts = trimesh.sample.sample_surface(mesh, 3000, seed=1)[0]
        for centre, radius in (sphere_cover(mesh, 3.0 if mesh.scale < 100 else 40.0), axis_spheres(mesh, 6)):
            assert _inside_some_sphere(pts, centre, radius).all()
            assert _inside_some_sphere(np.asarray(mesh.vertices), centre, radius).all()


def test_distance_grid_is_a_lower_bound():
    mesh = trimesh.creation.icosphere(2, 10.0)
    mesh.update_faces(mesh.triangles_center[:, 2] > 2)  # an open cap, like a layer
    grid = distance_grid(mesh, 0.8)
    x = np.random.default_rng(1).uniform(-16, 16, (4000, 3))
    exact = trimesh.proximity.closest_point(mesh, x)[1]
    bound = grid(x)
    assert (bound <= exact + 1e-9).all()
    close = exact < 1.5  # inside the grid's box: slack of at most a few cells
    assert close.sum() > 100 and (bound[close] > exact[close] - 2.0).all()


@pytest.fixture(scope="module")
def obstacle_scene():
    """The UR5 cell with a known obstacle: a box right beside the nozzle, where the platform swings."""
    robot, cell = load_robot("ur5"), load_workcell("ur5")
    box = Body("block", "box", (60.0, 60.0, 60.0), pose_matrix([450.0, 120.0, 420.0], [0, 0, 0]))
    cell = dataclasses.replace(cell, obstacles=cell.obstacles + (box,))
    surface = trimesh.creation.icosphere(2, 30.0)
    surface.update_faces(surface.triangles_center[:, 2] > 5)
    return robot, cell, surface


def test_sphere_proxy_has_no_false_free_near_a_known_obstacle(obstacle_scene):
    robot, cell, surface = obstacle_scene
    rng = np.random.default_rng(2)
    q = contact_configurations(robot, cell, surface, 100, rng)
    q = np.vstack([q, q + rng.normal(0, 0.05, q.shape)])
    exact = CollisionScene(robot, cell)
    proxy = CollisionScene(robot, cell, bounds=True)
    truth = exact.collisions(q)
    maybe = proxy.maybe_colliding(q)
    assert 0.05 < truth.mean() < 0.95  # the obstacle really is in the way of some configurations
    assert not (truth & ~maybe).any()  # no false "free"
    assert (~maybe).any()  # and it does clear some
    np.testing.assert_array_equal(proxy.collisions(q), truth)  # pruning pairs never changes fcl's answer


def test_learned_indication_is_safe_on_its_samples(obstacle_scene):
    robot, cell, surface = obstacle_scene
    exact = CollisionScene(robot, cell)
    q, label = contact_centred_samples(robot, cell, surface, exact.collisions, initial=150, total=900,
                                       rng=np.random.default_rng(3))
    assert len(q) > 300 and 0 < label.mean() < 1
    np.testing.assert_array_equal(exact.collisions(q), label)
    svm = LearnedCollision(q, label)
    assert (svm.indication(q[label]) >= 0).all()  # the shifted bias keeps every contact on the safe side
    assert svm.shift >= 1.0 and 0 < svm.kernels <= len(q)


def test_box_witness_is_a_contact_fcl_reports(obstacle_scene):
    """The cheap exact witness (a link vertex in a static box, or a link piece through the table's
    slab) only flags configurations where fcl finds a contact, and flags the table collisions of
    elbow-down branches."""
    robot, cell, surface = obstacle_scene
    scene = CollisionScene(robot, cell)
    rng = np.random.default_rng(4)
    q = contact_configurations(robot, cell, surface, 120, rng)
    lo, hi = cell.limits(robot)
    q = np.vstack([q, rng.uniform(np.maximum(lo, -np.pi), np.minimum(hi, np.pi), (300, 6))])
    poses = scene._poses(q)
    witness = np.zeros(len(q), bool)
    for T_inv, half, _ in scene._boxes:
        witness |= scene._inside_box(poses, T_inv, half)
    assert witness.sum() > 20
    assert all(scene.colliding_pairs(x) for x in q[witness])
    np.testing.assert_array_equal(scene.collisions(q), [bool(scene.colliding_pairs(x)) for x in q])
