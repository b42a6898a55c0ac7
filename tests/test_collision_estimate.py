"""Collision estimation (§4.4): the sphere proxy never calls a colliding configuration free, its
covers, support functions and distance field are conservative, pruning with it never changes
fcl's answer (checked against fcl on every pair), and the learned indication function is safe on
its training samples; all checked against fcl / trimesh's exact distances."""

from __future__ import annotations

import dataclasses

import fcl
import numpy as np
import pytest
import trimesh

from curvslice.collision import CollisionScene
from curvslice.collision_estimate import (
    LearnedCollision,
    cluster_spheres,
    contact_centred_samples,
    contact_configurations,
    distance_grid,
    solid_cover,
    sphere_cover,
    support,
)
from curvslice.kinematics import load_robot
from curvslice.workcell import Body, load_workcell, pose_matrix


def _inside_some_sphere(points, centre, radius):
    return (np.linalg.norm(points[:, None] - centre[None], axis=2) <= radius[None] + 1e-9).any(axis=1)


def test_sphere_covers_contain_the_surface():
    for mesh in (trimesh.creation.box((16, 20, 12)), trimesh.creation.cone(4.2, 5.0), load_robot("ur5").links[2].mesh):
        pts = trimesh.sample.sample_surface(mesh, 3000, seed=1)[0]
        for centre, radius in (sphere_cover(mesh, 3.0 if mesh.scale < 100 else 40.0), cluster_spheres(mesh, 12)):
            assert _inside_some_sphere(pts, centre, radius).all()
            assert _inside_some_sphere(np.asarray(mesh.vertices), centre, radius).all()


@pytest.mark.parametrize("body", [Body("b", "box", (16.0, 20.0, 12.0), np.eye(4)), Body("c", "cylinder", (15.0, 100.0), np.eye(4)),
                                  Body("n", "cone", (4.2, 5.0), np.eye(4))])
def test_primitive_support_and_solid_cover_hold_the_solid(body):
    """Points fcl finds inside the solid primitive lie in the solid cover, and no projection exceeds
    the support function (fcl's cone: base at -h/2, apex at +h/2)."""
    rng = np.random.default_rng(5)
    x = rng.uniform(-1, 1, (4000, 3)) * (np.array(body.dims if body.kind == "box" else (body.dims[0] * 2,) * 2 + (body.dims[1],)) / 2 + 1)
    geom = fcl.Box(*body.dims) if body.kind == "box" else (fcl.Cylinder if body.kind == "cylinder" else fcl.Cone)(*body.dims)
    solid = fcl.CollisionObject(geom, fcl.Transform())
    probe = fcl.CollisionObject(fcl.Sphere(1e-4), fcl.Transform())
    inside = []
    for p in x:
        probe.setTranslation(p)
        inside.append(fcl.collide(solid, probe, fcl.CollisionRequest(), fcl.CollisionResult()) > 0)
    inside = x[np.array(inside)]
    assert len(inside) > 100
    centre, radius = solid_cover(body, 3.0)
    assert _inside_some_sphere(inside, centre, radius + 1e-4).all()
    v = rng.normal(size=(50, 3))
    assert (inside @ v.T <= support(body, v) + 1e-3).all()


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


def _every_pair(scene: CollisionScene, q: np.ndarray) -> np.ndarray:
    """The reference: fcl on every checked pair, no bounds, witness or shared answers."""
    return np.array([bool(scene.colliding_pairs(x)) for x in q])


def test_sphere_proxy_has_no_false_free_near_a_known_obstacle(obstacle_scene):
    robot, cell, surface = obstacle_scene
    rng = np.random.default_rng(2)
    q = contact_configurations(robot, cell, surface, 100, rng)
    q = np.vstack([q, q + rng.normal(0, 0.05, q.shape)])
    proxy = CollisionScene(robot, cell)
    truth = _every_pair(proxy, q)
    maybe = proxy.maybe_colliding(q)
    assert 0.05 < truth.mean() < 0.95  # the obstacle really is in the way of some configurations
    assert not (truth & ~maybe).any()  # no false "free"
    assert (~maybe).any()  # and it does clear some
    np.testing.assert_array_equal(proxy.collisions(q), truth)  # pruning pairs never changes fcl's answer
    np.testing.assert_array_equal(CollisionScene(robot, cell, bounds=False).collisions(q), truth)


def test_answers_equal_fcl_on_every_pair_with_a_printed_part(obstacle_scene):
    """A part carried on the platform, the nozzle on its top (every configuration touches the
    contact C-space): the scene's answers (distance field, relative-pose answers shared between
    configurations and batches) equal fcl on every pair, for colliding and free configurations."""
    robot, cell, _ = obstacle_scene
    part = trimesh.creation.icosphere(3, 25.0)
    part.update_faces(part.triangles_center[:, 2] < 8)  # the layers printed so far
    part.apply_translation([0, 0, 25.0])
    top = trimesh.creation.icosphere(3, 25.0)
    top.update_faces((top.triangles_center[:, 2] > 8.3) & (top.triangles_center[:, 2] < 14))  # the next layer
    top.apply_translation([0, 0, 25.0])
    rng = np.random.default_rng(6)
    q = contact_configurations(robot, cell, top, 50, rng)
    q = np.vstack([q, q + rng.normal(0, 0.05, q.shape)])
    scene = CollisionScene(robot, cell)
    scene.set_part(part)
    touching = [scene.colliding_pairs(x) for x in q]
    truth = np.array([bool(t) for t in touching])
    assert 0.05 < truth.mean() < 0.95
    for pair in (("part", "nozzle"), ("part", "heater_block"), ("part", "forearm_link")):
        assert any(pair in t for t in touching)  # the part itself is hit, not only the platform
    np.testing.assert_array_equal(scene.collisions(q[::2]), truth[::2])
    np.testing.assert_array_equal(scene.collisions(q), truth)  # the second time partly from shared answers


def test_learned_indication_is_safe_on_its_samples(obstacle_scene):
    robot, cell, surface = obstacle_scene
    exact = CollisionScene(robot, cell)
    q, label = contact_centred_samples(robot, cell, surface, exact.collisions, initial=150, total=900,
                                       rng=np.random.default_rng(3))
    assert len(q) > 300 and 0 < label.mean() < 1
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
