"""Conservative voxelization (§3.4.1): every point of H lies in an occupied voxel (H ⊂ H̄)."""

import numpy as np
import pytest
import trimesh

from curvslice.errors import CurvsliceError
from curvslice.voxelize import RayWinding, centres_inside, check_memory, voxelize


def _in_occupied(grid, pts):
    """For each point: does some closed occupied voxel contain it (faces shared by two voxels)?"""
    rel = (pts - grid.origin) / grid.voxel_size + 0.5
    base = np.floor(rel).astype(int)
    hit = np.zeros(len(pts), bool)
    for off in np.array(np.meshgrid([0, -1], [0, -1], [0, -1])).T.reshape(-1, 3):
        on_face = (off == 0) | (np.abs(rel - np.round(rel)) < 1e-9)
        idx = base + off
        ok = on_face.all(1) & (idx >= 0).all(1) & (idx < grid.shape).all(1)
        s = np.flatnonzero(ok)
        hit[s] |= grid.occupied[idx[s, 0], idx[s, 1], idx[s, 2]]
    return hit


def _placed(mesh):
    mesh = mesh.copy()
    mesh.apply_translation([0, 0, -mesh.bounds[0, 2]])
    return mesh


def _sphere():
    rng = np.random.default_rng(0)
    u = rng.normal(size=(30000, 3))
    inner = u / np.linalg.norm(u, axis=1, keepdims=True) * 7.2 * rng.random((30000, 1)) ** (1 / 3)
    return trimesh.creation.icosphere(subdivisions=4, radius=7.3), inner


def _torus():
    rng = np.random.default_rng(1)
    a, b, r = rng.random(30000) * 2 * np.pi, rng.random(30000) * 2 * np.pi, 2.15 * np.sqrt(rng.random(30000))
    inner = np.column_stack([(8 + r * np.cos(b)) * np.cos(a), (8 + r * np.cos(b)) * np.sin(a), r * np.sin(b)])
    return trimesh.creation.torus(major_radius=8.0, minor_radius=2.2, major_sections=96, minor_sections=48), inner


def _plate():
    """A plate thinner than a voxel, tilted so it cuts voxels at arbitrary angles."""
    rot = trimesh.transformations.rotation_matrix(0.37, [1.0, 0.4, 0.2])
    rng = np.random.default_rng(2)
    inner = (rng.random((30000, 3)) - 0.5) * [20.0, 14.0, 0.3]
    return trimesh.creation.box([20.0, 14.0, 0.3]).apply_transform(rot), inner @ rot[:3, :3].T


SOLIDS = {"sphere": _sphere, "torus": _torus, "thin plate": _plate}


@pytest.mark.parametrize("name", SOLIDS)
@pytest.mark.parametrize("w", [0.7, 0.9])
def test_sampled_surface_and_interior_points_fall_in_occupied_voxels(name, w):
    mesh, inner = SOLIDS[name]()
    shift = -mesh.bounds[0, 2]
    mesh.apply_translation([0, 0, shift])
    grid = voxelize(mesh, w)
    pts = np.vstack([trimesh.sample.sample_surface(mesh, 30000, seed=2)[0], inner + [0, 0, shift], mesh.vertices])
    assert _in_occupied(grid, pts).all()


def test_interior_centres_match_analytic_sphere():
    r, w = 10.0, 0.7
    mesh = _placed(trimesh.creation.icosphere(subdivisions=5, radius=r))
    grid = voxelize(mesh, w)
    c = grid.centres(np.argwhere(np.ones(grid.shape, bool))).reshape(*grid.shape, 3)
    d = np.linalg.norm(c - [0, 0, r], axis=-1)
    # the icosphere's chord error is < 0.01 mm; stay clear of the surface by that and by w·√3/2
    assert grid.occupied[d < r - 0.02].all()
    assert not grid.occupied[d > r + w * np.sqrt(3) / 2 + 0.02].any()


def test_grid_sits_on_platform_and_pads_the_model():
    grid = voxelize(_placed(trimesh.creation.box([5.0, 6.0, 7.0])), 1.0)
    assert grid.origin[2] == pytest.approx(0.5)  # row k=0 spans [0, w]
    assert not grid.occupied[[0, -1]].any() and not grid.occupied[:, [0, -1]].any()
    assert not grid.occupied[:, :, -1].any()
    # a box aligned with voxel faces: its 5x6x7 cells, plus the closed neighbours its faces touch
    inner = grid.occupied[1:6, 1:7, 0:7]
    assert inner.all() and grid.occupied.sum() <= 7 * 8 * 8


def test_memory_guard_refuses_and_suggests_a_voxel_size():
    mesh = _placed(trimesh.creation.box([500.0, 500.0, 500.0]))
    with pytest.raises(CurvsliceError, match=r"use --voxel [0-9.]+ or larger"):
        check_memory(mesh, 0.05)
    check_memory(mesh, 5.0)


def test_ray_winding_counts_overlapping_shells_and_matches_the_voxel_centres():
    """RayWinding is the integer winding number: on two overlapping boxes given as one unmerged mesh it
    is the number of boxes holding the point (analytic, 0, 1 or 2), and on a torus (genus 1) at every
    voxel centre it decides exactly as centres_inside, the voxelizer's rule (the same tie rule, so also
    where the ray meets an edge of the mesh)."""
    a = trimesh.creation.box(extents=[6.0, 6.0, 6.0])
    b = trimesh.creation.box(extents=[5.0, 4.0, 7.0])
    b.apply_transform(trimesh.transformations.rotation_matrix(0.5, [1.0, 2.0, 0.5]))
    b.apply_translation([3.1, 1.3, 0.6])
    pts = np.random.default_rng(3).uniform(-4.5, 7.5, (20000, 3))

    def holds(box):  # inside a convex box by its face planes
        return (np.einsum("ij,kj->ik", pts, box.face_normals)
                - np.einsum("ij,ij->i", box.triangles_center, box.face_normals)).max(axis=1) < 0

    wn = RayWinding.of(trimesh.util.concatenate([a, b]).triangles)(pts)
    assert (wn == holds(a).astype(int) + holds(b)).all()
    assert (wn == 2).sum() > 500
    torus = trimesh.creation.torus(major_radius=5.0, minor_radius=2.0, major_sections=48, minor_sections=24)
    w = 0.5
    origin = np.array([-8.0, -8.0, -3.0])
    shape = (33, 33, 13)
    tri = np.asarray(torus.triangles, float)
    centres = origin + w * np.indices(shape).reshape(3, -1).T
    off = np.abs(trimesh.proximity.signed_distance(torus, centres)) > 1e-9  # on the skin: either side
    assert (~off).sum() < 50
    assert ((RayWinding.of(tri)(centres) > 0) == centres_inside(tri, origin, w, shape).ravel())[off].all()
