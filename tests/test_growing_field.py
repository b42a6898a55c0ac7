"""Growing field (§3.4.2-3.4.4): constraints re-checked by the independent verifier, the
procedural arch/tee where greedy growth misses voxels, hand-made violations, determinism."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from curvslice.convex_front import grow, hull_of, inside, newly_inside, plane_distance
from curvslice.growing_field import ASN_OFFSETS, growing_field
from curvslice.peeling_field import peeling_field
from curvslice.platform import disc_platform
from curvslice.solid import load_solid
from curvslice.verify.field import accessibility_violations, conservative_misses, support_violations
from curvslice.voxelize import voxelize

MODELS = Path(__file__).resolve().parents[1] / "models"


def _field(model: Path, w: float, method: str, **kw):
    solid, _ = load_solid(model)
    grid = voxelize(solid, w)
    platform = disc_platform(solid).vertices
    peel = peeling_field(grid, platform) if method == "pg-sp-gcfa" else None
    growing, stats = growing_field(grid, platform, method, peeling=peel, **kw)
    return grid, platform, peel, growing, stats


def _verified(grid, platform, growing, eps=1.0):
    off, unsup = support_violations(growing, grid.origin, grid.voxel_size)
    bad, _ = accessibility_violations(growing, grid.origin, grid.voxel_size, platform, eps)
    return len(off) == 0 and len(unsup) == 0 and len(bad) == 0


def test_asn_is_the_18_face_and_edge_neighbours():
    l1 = np.abs(ASN_OFFSETS).sum(axis=1)
    assert len(ASN_OFFSETS) == 18 and set(l1) == {1, 2} and len({tuple(o) for o in ASN_OFFSETS}) == 18


@pytest.mark.parametrize("model", ["arch", "tee"])
def test_greedy_misses_overhangs_that_peeling_governed_growth_reaches(model):
    grid, platform, _, g_greedy, s_greedy = _field(MODELS / f"{model}.stl", 1.5, "gcfa")
    grid, platform, _, g_pg, s_pg = _field(MODELS / f"{model}.stl", 1.5, "pg-sp-gcfa")
    assert s_greedy.missed > 0
    assert s_pg.missed == 0 and ((g_pg > 0) == grid.occupied).all()
    # missed greedy voxels are the overhang underside, above the platform
    missed = np.argwhere(grid.occupied & (g_greedy == 0))
    assert missed[:, 2].min() > 0
    for g in (g_greedy, g_pg):
        assert _verified(grid, platform, g)


def test_shadow_prevention_alone_also_reaches_the_arch():
    grid, platform, _, g, stats = _field(MODELS / "arch.stl", 1.5, "sp-gcfa")
    assert stats.missed == 0 and stats.shadow_tests > 1 and _verified(grid, platform, g)


def test_identical_input_gives_identical_field():
    a = _field(MODELS / "arch.stl", 2.0, "pg-sp-gcfa")[3]
    b = _field(MODELS / "arch.stl", 2.0, "pg-sp-gcfa")[3]
    assert np.array_equal(a, b)


def test_verifier_catches_hand_made_violations():
    grid, platform, _, g, _ = _field(MODELS / "tee.stl", 2.0, "pg-sp-gcfa")
    assert _verified(grid, platform, g)
    # (a) an unsupported voxel: give a top voxel layer 2, far from layer 1
    bad = g.copy()
    top = np.argwhere(g == g.max())[0]
    bad[tuple(top)] = 2
    off, unsup = support_violations(bad, grid.origin, grid.voxel_size)
    assert any((u == top).all() for u in unsup)
    # (b) a voxel inside the hull of earlier layers: push a low interior voxel to the last layer
    bad = g.copy()
    low = np.argwhere(g == 2)
    low = low[np.argmin(np.abs(low[:, 0] - low[:, 0].mean()) + np.abs(low[:, 1] - low[:, 1].mean()))]
    bad[tuple(low)] = g.max() + 1
    found, depth = accessibility_violations(bad, grid.origin, grid.voxel_size, platform, 1.0)
    assert any((f == low).all() for f in found) and depth >= grid.voxel_size


def test_newly_inside_equals_brute_force():
    rng = np.random.default_rng(3)
    base = hull_of(rng.normal(size=(200, 3)))
    new = rng.normal(size=(15, 3)) * 1.8
    grown = grow(base, new)
    x = rng.normal(size=(5000, 3)) * 2.0
    x = x[~inside(base, x, 0.1)]
    expect = np.flatnonzero(inside(grown, x, 0.1))
    got = np.sort(newly_inside(base, grown, new, x, 0.1))
    assert np.array_equal(got, expect) and len(expect) > 0


def test_plane_distance_is_the_distance_to_a_cube_boundary_inside():
    cube = hull_of(np.array(np.meshgrid(*[[0.0, 2.0]] * 3)).T.reshape(-1, 3))
    x = np.random.default_rng(4).random((1000, 3)) * 2.0
    assert np.allclose(-plane_distance(cube, x), np.minimum(x, 2.0 - x).min(axis=1))


@pytest.mark.slow
def test_real_kitten_at_coarse_voxels_is_fully_reached_and_verified(shared_model):
    grid, platform, peel, g, stats = _field(shared_model("kitten"), 2.0, "pg-sp-gcfa")
    assert stats.missed == 0 and _verified(grid, platform, g)
    assert peel[grid.occupied].min() == 1


def test_conservative_check_counts_a_face_on_a_voxel_face_inside_and_a_point_off_it_outside(tmp_path):
    """verify's H ⊂ H̄ test: samples of a box whose underside lies exactly on a voxel face (z = 2w, the
    voxels below it empty, as under an overhang) are inside H̄ whichever way their rounding falls (the
    test tried only the voxel below a sample it found on a face); the same box reaching one voxel lower,
    against the same voxels, has samples outside."""
    w = 1.6
    occupied = np.zeros((4, 4, 13), bool)
    occupied[:, :, 10:] = True  # voxel centres at 0.8, 2.4, ...: the occupied ones span z 16 .. 20.8 mm
    origin = np.full(3, 0.5 * w)
    box = trimesh.creation.box(bounds=[[0.5, 0.5, 16.0], [5.9, 5.9, 20.0]])  # (16 - 0.8) / 1.6 rounds below 9.5
    box.export(tmp_path / "on_face.stl")
    assert conservative_misses(occupied, origin, w, tmp_path / "on_face.stl")[0] == 0
    lower = trimesh.creation.box(bounds=[[0.5, 0.5, 14.0], [5.9, 5.9, 20.0]])
    lower.export(tmp_path / "lower.stl")
    assert conservative_misses(occupied, origin, w, tmp_path / "lower.stl")[0] > 0
