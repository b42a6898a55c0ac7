"""Orientation of material accumulation (thesis §3.5.2, Eq. 3.3): closest point, low-pass, slerp."""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import Delaunay

from curvslice.orientation import (accumulation_directions, closest_points, limit_tilt, low_pass, slerp, slerp_subdivide,
                                   smooth_along_paths)
from curvslice.toolpaths import ToolpathSettings, plan_toolpaths


def _angles(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))


def test_closest_points_match_brute_force():
    rng = np.random.default_rng(0)
    mesh = trimesh.creation.icosphere(3, radius=10.0)
    pts = rng.uniform(-14, 14, (400, 3))
    c, d, face = closest_points(pts, mesh.triangles)
    brute = trimesh.triangles.closest_point(np.repeat(mesh.triangles, len(pts), axis=0),
                                            np.tile(pts, (len(mesh.faces), 1))).reshape(len(mesh.faces), len(pts), 3)
    bd = np.linalg.norm(brute - pts[None], axis=2).min(axis=0)
    assert np.allclose(d, bd, atol=1e-9)
    assert np.allclose(np.linalg.norm(c - pts, axis=1), d)


def test_directions_point_from_the_closest_earlier_point():
    q = np.array([[0.0, 0, 1], [1, 1, 2]])
    c = np.array([[0.0, 0, 0], [1, 1, 2]])  # the second touches its closest point: fallback
    t = accumulation_directions(q, c, np.array([[0, 0, 1.0], [0, 1.0, 0]]))
    assert np.allclose(t, [[0, 0, 1], [0, 1, 0]])


def test_low_pass_removes_jumps_and_keeps_smooth_runs():
    rng = np.random.default_rng(1)
    n = 200
    angle = np.linspace(0, np.radians(40), n)
    t = np.c_[np.sin(angle), np.zeros(n), np.cos(angle)]
    noisy = t.copy()
    spikes = rng.choice(np.arange(5, n - 5), 12, replace=False)
    noisy[spikes] = np.c_[rng.normal(size=12), rng.normal(size=12), np.abs(rng.normal(size=12)) + 0.5]
    noisy /= np.linalg.norm(noisy, axis=1, keepdims=True)
    out = low_pass(noisy, np.zeros(n, int), np.radians(10))
    assert np.degrees(_angles(out[1:], out[:-1])).max() <= 10.0 + 1e-6
    far = np.ones(n, bool)
    for s in spikes:
        far[max(s - 30, 0):s + 31] = False
    assert np.allclose(out[far], t[far])  # only the neighbourhoods of the spikes were touched
    # no smoothing across a travel: two paths keep their own orientations
    two = np.r_[np.tile([0, 0, 1.0], (5, 1)), np.tile([1.0, 0, 0], (5, 1))]
    assert np.allclose(low_pass(two, np.r_[np.zeros(5), np.ones(5)]), two)


def test_smoothing_along_paths_removes_jitter_keeps_turns_and_bounds_the_move():
    """A straight pass, 0.5 mm samples, its axis turning steadily by 40° with ±4° of alternating
    jitter (what Eq. 3.3 gives on a faceted layer): the Gaussian (σ = 1 mm) takes the jitter out
    and keeps the steady turn inside the pass (a symmetric kernel passes a linear trend); no axis
    moves beyond the bound, none across a travel, and the angles returned are the moves."""
    n = 81
    x = np.linspace(0.0, 40.0, n)
    steady = np.linspace(0.0, np.radians(40), n)
    jitter = np.radians(4.0) * (-1.0) ** np.arange(n)
    axes = lambda a: np.c_[np.sin(a), np.zeros(len(a)), np.cos(a)]  # noqa: E731
    pos = np.c_[x, np.zeros(n), np.zeros(n)]
    out, moved = smooth_along_paths(pos, axes(steady + jitter), np.zeros(n, int), 1.0, np.radians(10))
    inner = slice(8, n - 8)  # more than 3σ from the pass's ends
    assert np.degrees(_angles(out, axes(steady))[inner]).max() < 0.5  # the jitter is gone, the turn kept
    assert np.degrees(_angles(out[1:], out[:-1])).max() < 2.0  # was 8.5° between samples
    np.testing.assert_allclose(moved, _angles(out, axes(steady + jitter)), atol=1e-12)
    _, capped = smooth_along_paths(pos, axes(steady + jitter), np.zeros(n, int), 1.0, np.radians(2))
    assert capped.max() <= np.radians(2) + 1e-12
    # no smoothing across a travel: two paths keep their own (constant) axes
    two = np.r_[np.tile([0, 0, 1.0], (5, 1)), np.tile([1.0, 0, 0], (5, 1))]
    kept, zero = smooth_along_paths(np.c_[np.arange(10.0), np.zeros((10, 2))], two, np.r_[np.zeros(5), np.ones(5)],
                                    1.0, np.radians(10))
    assert np.allclose(kept, two) and np.allclose(zero, 0)
    # nor across another path between two runs of one path id
    three = np.r_[np.tile([0, 0, 1.0], (5, 1)), np.tile([1.0, 0, 0], (2, 1)), np.tile([0, 1.0, 0], (5, 1))]
    kept, _ = smooth_along_paths(np.zeros((12, 3)), three, np.r_[np.zeros(5), np.ones(2), np.zeros(5)], 1.0,
                                 np.radians(10))
    assert np.allclose(kept, three)


def test_limit_tilt_bounds_the_angle_to_the_layer_normal():
    rng = np.random.default_rng(2)
    t = rng.normal(size=(500, 3))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    n = np.tile([0, 0, 1.0], (500, 1))
    out = limit_tilt(t, n, np.radians(60))
    ang = _angles(out, n)
    assert ang.max() <= np.radians(60) + 1e-9
    ok = _angles(t, n) <= np.radians(60)
    assert np.allclose(out[ok], t[ok])
    assert np.allclose(np.linalg.norm(out, axis=1), 1)


def test_slerp_subdivision_bounds_steps_and_interpolates():
    p = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]])
    t = np.array([[0, 0, 1], [1, 0, 0], [1, 0, 0.0]])  # a 90° crest on the first segment
    pos, nrm, parent, frac = slerp_subdivide(p, t, np.zeros(3, int), np.radians(10))
    assert len(pos) == 9 + 1 + 1
    assert np.degrees(_angles(nrm[1:], nrm[:-1])).max() <= 10.0 + 1e-9
    assert np.allclose(pos[:, 1:], 0) and np.all(np.diff(pos[:, 0]) > 0)
    assert np.allclose(nrm[0], t[0]) and np.allclose(nrm[-1], t[-1])
    mid = slerp(np.array([[0, 0, 1.0]]), np.array([[1.0, 0, 0]]), np.array([0.5]))
    assert np.allclose(mid, [[np.sqrt(0.5), 0, np.sqrt(0.5)]])


def test_stacked_tilted_planes_give_normal_orientation_and_true_thickness():
    """Parallel square layers tilted by 20°, 0.8 mm apart: t = the plane normal, thickness 0.8."""
    tilt = np.radians(20)
    normal = np.array([np.sin(tilt), 0, np.cos(tilt)])
    u = np.array([np.cos(tilt), 0, -np.sin(tilt)])
    grid = np.stack(np.meshgrid(np.linspace(-8, 8, 25), np.linspace(-8, 8, 25)), -1).reshape(-1, 2)
    faces = Delaunay(grid).simplices
    layers = []
    for k in range(1, 4):
        v = 20.0 * np.array([0, 0, 1.0]) + grid[:, :1] * u + grid[:, 1:2] * np.array([0, 1.0, 0]) + 0.8 * k * normal
        m = trimesh.Trimesh(v, faces, process=False)
        if np.dot(m.face_normals.mean(axis=0), normal) < 0:
            m.invert()
        layers.append(m)
    tp = plan_toolpaths(layers, ToolpathSettings(path_width=0.8))
    later = tp.layer >= 2
    assert np.degrees(_angles(tp.normals[later], np.tile(normal, (later.sum(), 1)))).max() < 1.0
    assert np.allclose(tp.thickness[later], 0.8, atol=0.02)
    assert np.all(tp.extrusion[np.r_[True, tp.path[1:] != tp.path[:-1]]] == 0)
