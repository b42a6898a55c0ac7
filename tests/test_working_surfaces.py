"""Working surfaces (§3.4.5, Eq. 3.2): dual contouring against analytic spheres and scikit-image's
marching cubes, exact signed distance against analytic solids, trimming a plane by a box, the
layer policy for jumps, missed voxels and slivers, and the independent verifier on a real field."""

from __future__ import annotations

import re

import numpy as np
import pytest
import trimesh
from skimage.measure import marching_cubes

from conftest import shared_models_dir

from curvslice.cli import main
from curvslice.errors import CurvsliceError
from curvslice.geodesic import boundary_edges
from curvslice.solid import load_solid
from curvslice.verify import layers as verify_layers
from curvslice.voxelize import voxelize
from curvslice.trimming import SolidDistance, VoxelSides, trim_by_solid
from curvslice.working_surfaces import (
    ContinuedField,
    continue_field,
    _triangles_intersect,
    dual_contour,
    extract_working_surfaces,
    layer_levels,
    separate_from,
    write_layers,
)


def _field_of(values: np.ndarray, origin: np.ndarray, w: float) -> ContinuedField:
    """A continued field straight from node values (every interior node a usable corner)."""
    domain = np.zeros(values.shape, bool)
    domain[1:-1, 1:-1, 1:-1] = True
    return ContinuedField(values=values, gradient=np.stack(np.gradient(values, w), axis=-1), domain=domain,
                          solid_nodes=np.ones(values.shape, bool), grown=np.ones(values.shape, bool),
                          origin=origin, voxel_size=w)


def _sphere_field(n: int = 40, w: float = 1.0):
    origin = np.array([-20.0, -20.0, 0.5]) * w
    centre = np.array([0.3, 0.1, 20.2]) * w
    x = origin + w * np.indices((n, n, n)).transpose(1, 2, 3, 0)
    return np.linalg.norm(x - centre, axis=-1) / w, origin, centre


def _boundary_vertices(mesh: trimesh.Trimesh) -> np.ndarray:
    return np.unique(boundary_edges(mesh.faces))


def _box(extents, centre) -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=extents)
    box.apply_translation(centre)
    return box


def _planar(box: trimesh.Trimesh, w: float):
    """Voxels of a box with the planar growing field G = k + 1 (ordinary planar printing)."""
    grid = voxelize(box, w)
    growing = np.where(grid.occupied, np.indices(grid.shape)[2] + 1, 0).astype(np.int32)
    return grid, growing


@pytest.mark.parametrize("radius", [8.3, 11.7, 15.2])
def test_sphere_distance_field_gives_spheres(radius):
    dist, origin, centre = _sphere_field()
    v, f = dual_contour(_field_of(dist, origin, 1.0), radius)
    mesh = trimesh.Trimesh(v, f, process=False)
    err = np.abs(np.linalg.norm(v - centre, axis=1) - radius)
    assert err.max() <= 0.05  # in voxel widths (w = 1)
    assert mesh.is_watertight and mesh.euler_number == 2
    outward = np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles_center - centre)
    assert (outward > 0).all()  # oriented along +∇G
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * radius**3, rel=5e-3)


def test_dual_contouring_has_fewer_polygons_than_marching_cubes_and_the_same_surface():
    dist, origin, centre = _sphere_field()
    radius = 12.4
    v, f = dual_contour(_field_of(dist, origin, 1.0), radius)
    mv, mf, _, _ = marching_cubes(dist, radius)
    mv = origin + mv
    # one quad per crossing edge (the thesis's "DC generates less polygons"); split into
    # triangles the counts agree up to the Euler characteristic of a closed genus-0 surface
    assert len(f) // 2 < len(mf)
    assert len(f) == len(mf) + 4
    d_dc_to_mc = trimesh.proximity.closest_point(trimesh.Trimesh(mv, mf), v)[1]
    assert d_dc_to_mc.max() < 0.1


def test_planar_field_and_box_give_flat_squares_with_boundary_on_the_faces():
    w = 0.8
    extents, centre = np.array([20.3, 15.7, 10.45]), np.array([0.2, -0.1, 10.45 / 2])
    box = _box(extents, centre)
    grid, growing = _planar(box, w)
    layers = extract_working_surfaces(growing, grid.origin, w, box, occupied=grid.occupied)
    assert len(layers) == growing.max() == 14
    lo, hi = centre - extents / 2, centre + extents / 2
    for layer in layers[:-1]:
        z = layer.metadata["layer"] * w  # top of voxel row k = layer - 1
        assert np.allclose(layer.vertices[:, 2], z, atol=1e-9)
        assert np.allclose(layer.face_normals, [0, 0, 1], atol=1e-9)
        b = layer.vertices[_boundary_vertices(layer)]
        on_x = np.isclose(b[:, 0], lo[0]) | np.isclose(b[:, 0], hi[0])
        on_y = np.isclose(b[:, 1], lo[1]) | np.isclose(b[:, 1], hi[1])
        assert (on_x | on_y).all()
        assert ((layer.vertices[:, :2] >= lo[:2] - 1e-9) & (layer.vertices[:, :2] <= hi[:2] + 1e-9)).all()
        # the square minus the four corner chamfers (boundary vertices sit on mesh edges)
        assert extents[0] * extents[1] - 2 * w**2 <= layer.area <= extents[0] * extents[1] + 1e-9
        assert len(layer.split(only_watertight=False)) == 1
    # the last voxel row holds only 0.05 mm of the box: its surface is lowered into that sliver
    last = layers[-1]
    assert last.metadata["lowered"] and len(last.faces)
    assert (12 * w < last.vertices[:, 2]).all() and (last.vertices[:, 2] < hi[2]).all()


def test_trimming_a_plane_by_a_rotated_cube_puts_the_boundary_on_its_faces():
    cube = trimesh.creation.box(extents=[10.0, 10.0, 10.0])
    rot = trimesh.transformations.rotation_matrix(0.4, [1, 2, 3])
    cube.apply_transform(rot)
    w = 0.5
    n = 60
    xs = (np.arange(n) - n / 2) * w
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    plane = trimesh.Trimesh(np.c_[gx.ravel(), gy.ravel(), np.full(n * n, 0.3)], _grid_faces(n), process=False)
    origin = np.array([xs[0], xs[0], xs[0]])
    sides = VoxelSides.of(cube, origin, w, (n, n, n))
    v, f = trim_by_solid(plane.vertices, plane.faces, SolidDistance.of(cube), sides)
    cut = trimesh.Trimesh(v, f, process=False)
    local = trimesh.transform_points(v, np.linalg.inv(rot))
    assert (np.abs(local) <= 5 + 1e-9).all()
    b = local[_boundary_vertices(cut)]
    assert np.isclose(np.abs(b).max(axis=1), 5.0, atol=1e-9).all()  # every boundary vertex on a face
    # the exact section of the cube by the plane is a convex polygon; the cut misses only corner chips
    polygon_area = cube.section(plane_origin=[0, 0, 0.3], plane_normal=[0, 0, 1]).to_2D()[0].area
    assert polygon_area - 2 * w**2 <= cut.area <= polygon_area + 1e-9
    assert np.allclose(cut.face_normals[:, 2], 1.0)
    assert len(cut.split(only_watertight=False)) == 1


def _grid_faces(n: int) -> np.ndarray:
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    return np.concatenate([np.c_[a, a + n, a + n + 1], np.c_[a, a + n + 1, a + 1]])


@pytest.mark.parametrize("solid", ["box", "sphere"])
def test_signed_distance_matches_the_analytic_one(solid):
    rng = np.random.default_rng(1)
    if solid == "box":
        mesh = trimesh.creation.box(extents=[4.0, 6.0, 8.0])
        half = np.array([2.0, 3.0, 4.0])
        # many points near edges and corners, where a closest-feature sign is delicate
        pts = rng.choice([-1, 1], (4000, 3)) * half + rng.normal(scale=0.3, size=(4000, 3))
        q = np.abs(pts) - half
        exact = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)
        tol = 1e-9
    else:
        mesh = trimesh.creation.icosphere(subdivisions=5, radius=5.0)
        pts = rng.normal(size=(4000, 3))
        pts = pts / np.linalg.norm(pts, axis=1, keepdims=True) * rng.uniform(3.0, 7.0, (4000, 1))
        exact = np.linalg.norm(pts, axis=1) - 5.0
        tol = 5.0 * (1 - np.cos(np.pi / 5 / 2**5)) * 2  # the polyhedron's sagitta
    d, q = SolidDistance.of(mesh)(pts)
    assert np.abs(d - exact).max() <= tol
    assert np.allclose(np.abs(d), np.linalg.norm(pts - q, axis=1))
    ref = trimesh.proximity.closest_point(mesh, pts)[1]
    assert np.allclose(np.abs(d), ref, atol=1e-9)


def test_signed_distance_sign_agrees_with_ray_parity_on_a_real_mesh(shared_model):
    solid, _ = load_solid(shared_model("kitten"))
    rng = np.random.default_rng(2)
    pts = trimesh.sample.sample_surface(solid, 3000, seed=3)[0] + rng.normal(scale=0.5, size=(3000, 3))
    d, _ = SolidDistance.of(solid)(pts)
    inside = verify_layers.inside_by_ray_parity(solid, pts)
    clear = np.abs(d) > 1e-4  # the parity test jitters rays by up to 1e-7 of the model size
    assert ((d[clear] < 0) == inside[clear]).all()


def test_winding_number_is_the_exact_inside_test_and_agrees_with_ray_parity(shared_model):
    """A torus (genus 1): the winding number is 1 inside and 0 outside off its polyhedral skin; on
    the kitten it agrees with the verifier's ray parity wherever the signed distance is clear."""
    torus = trimesh.creation.torus(major_radius=5.0, minor_radius=2.0, major_sections=96, minor_sections=48)
    rng = np.random.default_rng(4)
    pts = rng.uniform(-8, 8, (4000, 3))
    tube = np.hypot(np.hypot(pts[:, 0], pts[:, 1]) - 5.0, pts[:, 2]) - 2.0
    clear = np.abs(tube) > 0.05  # the polyhedron's sagitta is ~0.01
    wn = verify_layers.winding_numbers(torus, pts[clear])
    assert np.abs(wn - (tube[clear] < 0)).max() < 0.2
    solid, _ = load_solid(shared_model("kitten"))
    pts = trimesh.sample.sample_surface(solid, 3000, seed=3)[0] + rng.normal(scale=0.5, size=(3000, 3))
    d, _ = SolidDistance.of(solid)(pts)
    clear = np.abs(d) > 1e-3
    assert ((verify_layers.winding_numbers(solid, pts[clear]) > 0.5)
            == verify_layers.inside_by_ray_parity(solid, pts[clear])).all()


def test_winding_numbers_near_large_triangles_are_evaluated_in_bounded_chunks(monkeypatch):
    """A flat plate of 12 triangles (a CAD part's faces): every point near it is near every leaf of the tree,
    so its (point, triangle) pairs are taken WINDING_PAIRS at a time (couplingdown at 70 mm: 110 M pairs, 24 GB
    at once); the answer is that of one pass, and 1 inside, 0 outside."""
    plate = trimesh.creation.box(extents=(70.0, 70.0, 2.0))
    rng = np.random.default_rng(7)
    pts = np.c_[rng.uniform(-40, 40, (3000, 2)), rng.uniform(-3, 3, 3000)]
    clear = (np.abs(np.abs(pts[:, 2]) - 1.0) > 0.05) & (np.abs(pts[:, :2]).max(axis=1) < 34.9) | (np.abs(pts[:, :2]).max(axis=1) > 35.1)
    whole = verify_layers.winding_numbers(plate, pts)
    monkeypatch.setattr(verify_layers, "WINDING_PAIRS", 97)
    chunked = verify_layers.winding_numbers(plate, pts)
    assert np.allclose(chunked, whole, atol=1e-9)
    inside = (np.abs(pts[:, 2]) < 1.0) & (np.abs(pts[:, :2]).max(axis=1) < 35.0)
    assert ((chunked[clear] > 0.5) == inside[clear]).all()


def test_verifier_inside_test_agrees_with_the_signed_distance_on_every_layer_vertex(tmp_path):
    """Issue 18: on the arch (a procedural solid whose opening is an overhang), the verifier's winding
    number and the exact signed distance classify every layer vertex alike off ∂H -- the layers, and
    the same vertices jittered by up to ±0.6 w so that many lie outside. Its "vertices inside H" check
    counts violations only: three vertices pushed 1 w out of one layer are exactly "3 outside" on that
    layer, while the untouched slice, with dozens of vertices on ∂H (winding number ½), has none."""
    import shutil

    from pathlib import Path

    out = tmp_path / "arch"
    model = Path(__file__).resolve().parents[1] / "models" / "arch.stl"
    assert main(["slice", str(model), "--voxel", "2.0", "--out", str(out), "--quiet", "--stages", "layers", "--no-verify"]) == 0
    solid = trimesh.load(out / "solid.stl", force="mesh")
    w = 2.0
    files = sorted((out / "layers").glob("layer_*.ply"))
    verts = np.concatenate([trimesh.load(p, process=False, force="mesh").vertices for p in files])
    rng = np.random.default_rng(5)
    for pts in (verts, verts + rng.uniform(-0.6 * w, 0.6 * w, verts.shape)):
        d, _ = SolidDistance.of(solid)(pts)
        clear = np.abs(d) > verify_layers.TOLERANCE * w
        wn = verify_layers.winding_numbers(solid, pts[clear])
        assert ((wn > 0.5) == (d[clear] < 0)).all()
        assert np.abs(wn - (d[clear] < 0)).max() < 0.1  # 0 or 1, not merely on the right side of ½
    assert (d > 0.1 * w).sum() > 100  # the jittered set does probe the outside

    check = next(c for c in verify_layers.checks(out) if c.name == "vertices inside H")
    on_boundary = int(re.search(r"(\d+) more on ∂H", check.detail).group(1))
    assert check.passed and check.value.startswith("0 outside") and on_boundary > 20
    broken = tmp_path / "broken"
    shutil.copytree(out, broken)
    number = len(files) // 2
    mesh = trimesh.load(files[number - 1], process=False, force="mesh")
    ends = _boundary_vertices(mesh)
    _, dist, tid = trimesh.proximity.closest_point(solid, mesh.vertices[ends])
    on_solid = np.flatnonzero(dist < 1e-6)[:3]  # boundary vertices on ∂H (not at a jump of the field)
    assert len(on_solid) == 3
    mesh.vertices[ends[on_solid]] += w * solid.face_normals[tid[on_solid]]
    mesh.export(broken / "layers" / files[number - 1].name)
    check = next(c for c in verify_layers.checks(broken) if c.name == "vertices inside H")
    assert not check.passed and check.value.startswith("3 outside") and check.layers == (number,)


def test_a_wrong_sign_far_from_the_solid_does_not_change_the_trim():
    """Points in voxels no triangle touches take their voxel's side (a closest-feature sign once said
    "inside" 1.3 w outside the cow at 0.8 mm, which crashed the trimming with an infinite crossing): a
    distance whose sign is wrong everywhere off ∂H's voxels trims a plane exactly as the true one does."""
    cube = trimesh.creation.box(extents=[10.0, 10.0, 10.0])
    cube.apply_transform(trimesh.transformations.rotation_matrix(0.4, [1, 2, 3]))
    w, n = 0.5, 60
    xs = (np.arange(n) - n / 2) * w
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    plane = trimesh.Trimesh(np.c_[gx.ravel(), gy.ravel(), np.full(n * n, 0.3)], _grid_faces(n), process=False)
    sides = VoxelSides.of(cube, np.full(3, xs[0]), w, (n, n, n))
    true = SolidDistance.of(cube)

    def wrong(points, sheet=0.0, side=None):
        d, q = true(points, sheet)
        return np.where(sides(points) != 0, -d, d), q

    expected = trim_by_solid(plane.vertices, plane.faces, true, sides)
    got = trim_by_solid(plane.vertices, plane.faces, wrong, sides)
    assert len(got[1]) == len(expected[1]) > 0 and np.allclose(got[0], expected[0])


def test_layer_levels_follow_eq_3_2():
    assert np.allclose(layer_levels(5, 0.8), [1.5, 2.5, 3.5, 4.5, 5.5])
    # d = 2w: two voxel layers per printed layer, ⌈max G / (d/w)⌉ layers
    assert np.allclose(layer_levels(5, 0.8, 1.6), [2.5, 4.5, 6.5])
    with pytest.raises(CurvsliceError):
        layer_levels(5, 0.8, 0.0)


def test_thicker_layers_span_several_voxel_rows():
    w = 0.5
    box = _box([8.3, 6.3, 5.2], [0.0, 0.0, 2.6])
    grid, growing = _planar(box, w)
    layers = extract_working_surfaces(growing, grid.origin, w, box, layer_height=3 * w, occupied=grid.occupied)
    assert len(layers) == int(np.ceil(growing.max() / 3))
    for layer in layers[:-1]:
        assert np.allclose(layer.vertices[:, 2], 3 * w * layer.metadata["layer"], atol=1e-9)


def test_a_jump_in_the_field_carries_no_layers_in_between():
    """Left half grows one layer per row; the right half waits on row 0 (layer 1), then resumes at
    layer 10: layers 2-8 have no material on the right, so their surfaces stay on the left."""
    w = 1.0
    box = _box([20.5, 10.5, 12.5], [0.0, 0.0, 6.25])
    grid, growing = _planar(box, w)
    centres_x = grid.origin[0] + w * np.arange(grid.shape[0])
    k = np.indices(grid.shape)[2]
    right = (centres_x > 0)[:, None, None] & (k >= 1)
    growing = np.where(grid.occupied & right, k + 9, growing).astype(np.int32)
    layers = extract_working_surfaces(growing, grid.origin, w, box, occupied=grid.occupied)
    assert layers[0].vertices[:, 0].max() > 9  # layer 1 spans both halves
    for layer in layers[1:8]:
        assert layer.vertices[:, 0].max() <= 0.5 + 1e-9
    assert sum(verify_layers.crossing_pairs(a, b) for a, b in zip(layers[:-1], layers[1:])) == 0


def test_missed_voxels_are_bridged_by_the_next_layer():
    w = 1.0
    box = _box([12.5, 12.5, 8.5], [0.0, 0.0, 4.25])
    grid, growing = _planar(box, w)
    i, j = np.array(grid.shape[:2]) // 2
    growing[i, j, 4] = 0  # one missed voxel inside
    layers = extract_working_surfaces(growing, grid.origin, w, box, occupied=grid.occupied)
    for layer in layers[:-1]:
        assert len(layer.split(only_watertight=False)) == 1
        assert layer.area == pytest.approx(12.5 * 12.5, rel=0.01)
        assert len(trimesh.graph.connected_components(boundary_edges(layer.faces))) == 1  # no hole


def test_open_solid_is_a_user_error():
    box = _box([5.0, 5.0, 5.0], [0, 0, 2.5])
    grid, growing = _planar(box, 1.0)
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-1])
    with pytest.raises(CurvsliceError, match="closed"):
        extract_working_surfaces(growing, grid.origin, 1.0, open_box)
    with pytest.raises(CurvsliceError, match="empty"):
        extract_working_surfaces(np.zeros_like(growing), grid.origin, 1.0, box)


@pytest.fixture(scope="module")
def kitten_slice(tmp_path_factory):
    path = shared_models_dir() / "kitten.stl"
    if not path.exists():
        pytest.skip(f"shared model {path} not present")
    out = tmp_path_factory.mktemp("kitten") / "slice"
    assert main(["slice", str(path), "--voxel", "2.0", "--out", str(out), "--quiet", "--stages", "layers", "--no-verify"]) == 0
    return out


def test_real_field_layers_pass_the_verifier(kitten_slice):
    results = verify_layers.checks(kitten_slice)
    failed = [c for c in results if not c.passed]
    assert not failed, failed
    names = {c.name for c in results}
    assert {"vertices inside H", "consecutive layers do not cross", "layer spacing"} <= names


def test_untrimmed_surfaces_end_outside_the_solid(kitten_slice):
    """§3.4.5: trimming is exact only if ∂S* lies outside H; the continued field guarantees it."""
    with np.load(kitten_slice / "field.npz") as f:
        growing, occupied, origin, w = f["growing"], f["occupied"], f["origin"], float(f["voxel_size"])
    solid = trimesh.load(kitten_slice / "solid.stl", force="mesh")
    field = continue_field(growing, occupied, origin, w)
    distance = SolidDistance.of(solid)
    levels = layer_levels(int(growing.max()), w)
    for level in levels[::2]:
        v, f = dual_contour(field, level)  # the plain isosurface: no band, no jump ends inside H
        d, _ = distance(v[np.unique(boundary_edges(f))])
        assert (d > 0).all()


def test_verifier_catches_broken_layers(kitten_slice, tmp_path):
    import shutil

    out = tmp_path / "broken"
    shutil.copytree(kitten_slice, out)
    files = sorted((out / "layers").glob("layer_*.ply"))
    # a vertex pushed 1 mm out of the solid, two layers swapped in print order, one flipped, the last lost
    mesh = trimesh.load(files[5], process=False)
    solid = trimesh.load(out / "solid.stl")
    b = _boundary_vertices(mesh)[0]
    _, _, tid = trimesh.proximity.closest_point(solid, mesh.vertices[[b]])
    mesh.vertices[b] += 1.0 * solid.face_normals[tid[0]]
    mesh.export(files[5])
    a, c = files[10].read_bytes(), files[11].read_bytes()
    files[10].write_bytes(c)
    files[11].write_bytes(a)
    flipped = trimesh.load(files[20], process=False)
    flipped.invert()
    flipped.export(files[20])
    files[-1].unlink()
    failed = {r.name for r in verify_layers.checks(out) if not r.passed}
    assert {"one file per layer", "vertices inside H", "each layer lies on its own voxels",
            "normals towards later layers"} <= failed


def test_material_of_an_empty_layer_is_measured_piece_by_piece(kitten_slice, tmp_path):
    # known answers on a box x in [0, 3.5], y and z in [0, 3] (1 mm voxels, centres at 0.5 + k): a piece of two
    # voxels inside, a separate voxel whose centre lies on the face x = 3.5 (half of the 4x4x4 lattice inside),
    # a third piece outside
    box = trimesh.creation.box(extents=(3.5, 3, 3), transform=trimesh.transformations.translation_matrix((1.75, 1.5, 1.5)))
    vox = np.zeros((6, 6, 6), bool)
    vox[0, 0, 0] = vox[1, 0, 0] = vox[3, 2, 2] = vox[5, 5, 5] = True
    material = verify_layers.layer_material(box, vox, np.full(3, 0.5), 1.0)
    np.testing.assert_allclose(material, [2.0, 0.5, 0.0])
    # a real layer with material emptied: the check fails (and passes on the untouched folder)
    out = tmp_path / "emptied"
    import shutil

    shutil.copytree(kitten_slice, out)
    name = "a surface for every layer with material"
    assert {r.name: r.passed for r in verify_layers.checks(out)}[name]
    files = sorted((out / "layers").glob("layer_*.ply"))
    trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)).export(files[len(files) // 2])
    check = {r.name: r for r in verify_layers.checks(out)}[name]
    assert not check.passed and "1 with material" in check.value


def test_library_and_verifier_intersection_tests_agree():
    rng = np.random.default_rng(4)
    t1 = rng.normal(size=(20000, 3, 3))
    t2 = 0.7 * rng.normal(size=(20000, 3, 3)) + 0.5 * rng.normal(size=(20000, 1, 3))
    edge_test = np.zeros(len(t1), bool)
    for k in range(3):
        edge_test |= verify_layers._segment_hits_triangle(t1[:, k], t1[:, (k + 1) % 3], t2)
        edge_test |= verify_layers._segment_hits_triangle(t2[:, k], t2[:, (k + 1) % 3], t1)
    interval_test = _triangles_intersect(t1, t2)
    assert 0.05 < interval_test.mean() < 0.95
    assert (interval_test == edge_test).all()


def test_a_crossing_layer_is_pushed_clear_of_the_one_before():
    n = 12
    g = np.stack(np.meshgrid(np.linspace(-5, 5, n), np.linspace(-5, 5, n), indexing="ij"), -1).reshape(-1, 2)
    earlier = trimesh.Trimesh(np.c_[g, np.zeros(len(g))], _grid_faces(n), process=False)
    later_v = np.c_[g, 1.0 - 0.1 * (g**2).sum(axis=1)]  # a dome dipping through the flat layer
    v, f, moved, dropped = separate_from(earlier, later_v, _grid_faces(n), 1.0)
    assert moved > 0 and dropped == 0
    assert verify_layers.crossing_pairs(earlier, trimesh.Trimesh(v, f, process=False)) == 0
    assert (v[:, 2] >= 0.01 - 1e-12).all()
    assert np.allclose(v[later_v[:, 2] > 0.01], later_v[later_v[:, 2] > 0.01])  # the rest is untouched


def test_crossing_test_sees_crossing_planes_only():
    def plane(tilt: float, z: float) -> trimesh.Trimesh:
        n = 12
        g = np.stack(np.meshgrid(np.linspace(-5, 5, n), np.linspace(-5, 5, n), indexing="ij"), -1).reshape(-1, 2)
        return trimesh.Trimesh(np.c_[g, z + tilt * g[:, 0]], _grid_faces(n), process=False)

    assert verify_layers.crossing_pairs(plane(0.0, 0.0), plane(0.0, 0.3)) == 0
    assert verify_layers.crossing_pairs(plane(0.0, 0.0), plane(0.1, 0.3)) > 0


def test_slice_cli_rejects_a_bad_layer_height(shared_model, tmp_path, capsys):
    code = main(["slice", str(shared_model("kitten")), "--voxel", "3", "--layer-height", "-1",
                 "--out", str(tmp_path / "o"), "--quiet"])
    assert code == 2
    assert "--layer-height" in capsys.readouterr().err


def test_layers_are_written_in_print_order(tmp_path):
    box = _box([6.5, 6.5, 4.5], [0, 0, 2.25])
    grid, growing = _planar(box, 1.0)
    layers = extract_working_surfaces(growing, grid.origin, 1.0, box, occupied=grid.occupied)
    paths = write_layers(tmp_path, layers)
    assert [p.name for p in paths] == [f"layer_{i:04d}.ply" for i in range(1, len(layers) + 1)]
    heights = [trimesh.load(p).vertices[:, 2].mean() for p in paths]
    assert np.all(np.diff(heights) > 0)


def _overlapping_boxes() -> tuple[trimesh.Trimesh, list[trimesh.Trimesh]]:
    """Two overlapping boxes as one unmerged mesh (each shell closed and outward, so the mesh is
    watertight; their skins cross each other and enclose a region twice), and the two boxes."""
    a = trimesh.creation.box(extents=[6.0, 6.0, 6.0])
    b = trimesh.creation.box(extents=[5.0, 4.0, 7.0])
    b.apply_transform(trimesh.transformations.rotation_matrix(0.5, [1.0, 2.0, 0.5]))
    b.apply_translation([3.1, 1.3, 0.6])
    return trimesh.util.concatenate([a, b]), [a, b]


def _inside_box(box: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Signed distance-like inside test of a convex box by its face planes (independent of trimming)."""
    n, c = box.face_normals, box.triangles_center
    return (np.einsum("ij,kj->ik", points, n) - np.einsum("ij,ij->i", c, n)).max(axis=1)


def test_trimming_by_overlapping_shells_keeps_exactly_their_union():
    """Issue 18 (the cow, whose skin crosses itself): the sign of trimming's distance is a winding number,
    so on two overlapping boxes given as one unmerged mesh a plane keeps exactly its section of the union:
    every kept vertex inside one box, every boundary vertex on a face of one box outside the other (not on
    the skin that lies inside the other box -- the plane's grid has a row of vertices exactly on it), and
    the kept area that of the union of the two sections (shapely) up to the corner chips. The verifier's winding number agrees with the sign everywhere off ∂H."""
    from shapely.geometry import MultiPoint
    from shapely.ops import unary_union

    solid, boxes = _overlapping_boxes()
    assert solid.is_watertight and solid.is_winding_consistent
    w, n, z = 0.25, 64, 0.9
    xs = -4.0 + w * np.arange(n)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    plane = trimesh.Trimesh(np.c_[gx.ravel(), gy.ravel(), np.full(n * n, z)], _grid_faces(n), process=False)
    shape = (n, n, n)
    origin = np.full(3, xs[0])
    distance = SolidDistance.of(solid)
    v, f = trim_by_solid(plane.vertices, plane.faces, distance, VoxelSides.of(solid, origin, w, shape))
    cut = trimesh.Trimesh(v, f, process=False)
    planes = np.stack([_inside_box(b, v) for b in boxes], axis=1)  # ≤ 0 inside that box
    assert (planes.min(axis=1) <= 1e-9).all()
    ends = v[_boundary_vertices(cut)]
    sides = np.stack([_inside_box(b, ends) for b in boxes], axis=1)
    on_a = (np.abs(sides[:, 0]) <= 1e-6) & (sides[:, 1] >= -1e-6)
    on_b = (np.abs(sides[:, 1]) <= 1e-6) & (sides[:, 0] >= -1e-6)
    assert (on_a | on_b).all()
    sections = [MultiPoint(b.section(plane_origin=[0, 0, z], plane_normal=[0, 0, 1]).vertices[:, :2]).convex_hull
                for b in boxes]
    union = unary_union(sections)
    # convex corners lose a chip, the two reflex corners where the sections meet gain one: < w² each
    assert abs(cut.area - union.area) <= 4 * w**2
    assert sections[0].intersection(sections[1]).area > 5.0  # the doubly enclosed part is really cut through
    # the sign against an independent inside test, off ∂H, on points all over the boxes
    rng = np.random.default_rng(7)
    pts = rng.uniform(-4.5, 7.5, (6000, 3))
    d, _ = distance(pts)
    inside = np.stack([_inside_box(b, pts) for b in boxes], axis=1).min(axis=1)
    clear = np.abs(d) > 1e-6
    assert ((d[clear] < 0) == (inside[clear] < 0)).all()
    assert ((verify_layers.winding_numbers(solid, pts[clear]) > 0.5) == (d[clear] < 0)).all()


def test_a_pocket_of_missed_voxels_reads_no_jumps_of_g():
    """Missed voxels get guessed layers (1 + the least G around them); a jump of two between two such
    guesses is not a jump of the field, so no layer ends there. A box printed in two planar halves offset
    by 3 layers, with a 5-voxel pocket of missed voxels across the seam: every layer's boundary lies on
    ∂H or next to a jump of G as the verifier reads it (missed voxels count as 0). Cheburashka at 0.8 mm
    ended layer 60 inside such a pocket, 0.27 w from ∂H."""
    w = 1.0
    box = _box([14.0, 10.0, 12.0], [0.0, 0.0, 6.0])
    grid = voxelize(box, w)
    ijk = np.indices(grid.shape)
    mid = grid.shape[0] // 2
    growing = np.where(grid.occupied, ijk[2] + 1 + 3 * (ijk[0] >= mid), 0).astype(np.int32)
    centre = np.array(grid.shape) // 2
    growing[(np.abs(ijk - centre[:, None, None, None]).max(axis=0) <= 2)] = 0
    layers = extract_working_surfaces(growing, grid.origin, w, box, occupied=grid.occupied)
    jumps = np.pad(verify_layers.jump_voxels(growing, grid.occupied), 1)
    around = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3)
    inner_ends = 0
    for layer in layers:
        ends = layer.vertices[_boundary_vertices(layer)]
        off = np.abs(trimesh.proximity.signed_distance(box, ends)) > verify_layers.TOLERANCE * w
        base = np.rint((ends[off] - grid.origin) / w).astype(np.int64) + 1
        near_jump = np.zeros(len(base), bool)
        for d in around:
            q = base + d
            near_jump |= jumps[q[:, 0], q[:, 1], q[:, 2]]
        assert near_jump.all(), (layer.metadata["layer"], ends[off][~near_jump])
        inner_ends += int(off.sum())
    assert inner_ends > 0  # the seam's jump does end layers inside H: the test sees them


def _grid_aligned_solid(name: str) -> trimesh.Trimesh:
    """Solids whose flat faces lie on voxel faces at 1.0 and 1.5 mm: an inverted cone (top at z = 25)
    and an L of a post and a 22 mm cantilever slab (underside at z = 24, top at z = 30)."""
    if name == "inverted cone":
        cone = trimesh.creation.cone(15.0, 25.0)
        return cone.apply_transform(trimesh.transformations.rotation_matrix(np.pi, [1.0, 0.0, 0.0]))
    return _box([8.0, 20.0, 24.0], [-11.0, 0.0, 12.0]).union(_box([30.0, 20.0, 6.0], [0.0, 0.0, 27.0]))


@pytest.mark.parametrize("name, voxel", [("inverted cone", 1.0), ("L overhang", 1.5)])
def test_a_flat_face_on_a_voxel_face_belongs_to_one_layer(tmp_path, name, voxel):
    """Flat faces of H on voxel faces (z = k·w): a skin is the surface of the layer whose voxels it
    bounds. Crossings leaving another layer's voxel once stayed on that face, on ∂H, so the last layer of
    the cone (a few voxels) was extracted over the whole top, and a layer under the L's slab ran along
    its underside: off their own voxels and crossing their neighbours."""
    _grid_aligned_solid(name).export(tmp_path / "solid.stl")
    out = tmp_path / "out"
    assert main(["slice", str(tmp_path / "solid.stl"), "--voxel", str(voxel), "--stages", "layers",
                 "--out", str(out)]) == 0
    results = verify_layers.checks(out)
    failed = [c for c in results if not c.passed]
    assert not failed, failed
    assert {"consecutive layers do not cross", "each layer lies on its own voxels"} <= {c.name for c in results}


def test_a_lowered_top_layer_is_left_out_of_the_spacing_statistic(tmp_path):
    """A plate 2 mm thick at 1.5 mm voxels has two layers: the interface of its top layer lies above the
    plate, so that layer is extracted lower, 0.25 w over the first. The spacing statistic (a plausibility
    check of the field's layering, Fig. 3.18) is taken over the layers at their own level only; counted in,
    the lowered layer alone made the mean implausible and the slice fail."""
    import json

    plate = _box((50, 40, 2), (0, 0, 1))
    plate.export(tmp_path / "plate.stl")
    out = tmp_path / "plate"
    assert main(["slice", str(tmp_path / "plate.stl"), "--voxel", "1.5", "--stages", "layers", "--quiet",
                 "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["layers"]["count"] == 2 and report["layers"]["lowered"] == [2]
    spacing = {r.name: r for r in verify_layers.checks(out)}["layer spacing"]
    assert spacing.passed
    report["layers"]["lowered"] = []  # the lowered layer counted in: 0.25 w, below the plausible range
    (out / "report.json").write_text(json.dumps(report))
    spacing = {r.name: r for r in verify_layers.checks(out)}["layer spacing"]
    assert not spacing.passed and spacing.value.startswith("mean 0.25")


def test_a_layer_ending_inside_h_is_explained_only_by_a_jump_or_missed_voxels(kitten_slice, tmp_path):
    """A hole cut into the middle of a layer ends it inside H, away from every jump of G: the check fails.
    The same hole inside a pocket of missed voxels (G = 0 there, H̄ still occupied) passes: G gives no
    layer there, the surfaces cross it on guessed layers and may end in it (the pinion at 0.8 mm)."""
    import shutil

    out = tmp_path / "holed"
    shutil.copytree(kitten_slice, out)
    name = "boundary on ∂H or at a field jump"
    assert {r.name: r.passed for r in verify_layers.checks(out)}[name]
    files = sorted((out / "layers").glob("layer_*.ply"))
    with np.load(out / "field.npz") as f:
        field = dict(f)
    w, origin = float(field["voxel_size"]), np.asarray(field["origin"], float)
    solid = trimesh.load(out / "solid.stl")
    # a layer vertex deep in H with no jump of G within two voxels (coarse: the kitten at 2 mm has few), on the
    # layer that has the deepest one
    from scipy import ndimage

    calm = ~ndimage.binary_dilation(verify_layers.jump_voxels(field["growing"], field["occupied"]), iterations=2)
    best = (0.0, None, None)
    for k, path in enumerate(files):
        mesh = trimesh.load(path, process=False, force="mesh")
        if not len(mesh.faces):
            continue
        ijk = np.clip(np.rint((mesh.vertices - origin) / w).astype(int), 0, np.array(calm.shape) - 1)
        ok = calm[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
        if ok.any():
            depth = trimesh.proximity.signed_distance(solid, mesh.vertices[ok])
            if depth.max() > best[0]:
                best = (float(depth.max()), k, mesh.vertices[ok][np.argmax(depth)])
    depth, k, centre = best
    assert depth > 0.9 * w  # (the hole, 0.8 w across, stays clear of ∂H)
    mesh = trimesh.load(files[k], process=False)
    near = np.linalg.norm(mesh.triangles_center - centre, axis=1) < 0.8 * w
    mesh.update_faces(~near)
    mesh.export(files[k])
    check = {r.name: r for r in verify_layers.checks(out)}[name]
    assert not check.passed and check.value.endswith("else") and not check.value.endswith(" 0 else")
    # a pocket of missed voxels 3 w around the hole
    ijk = np.indices(field["growing"].shape).reshape(3, -1).T
    pocket = (np.abs(origin + w * ijk - centre).max(axis=1) < 3.0 * w).reshape(field["growing"].shape)
    field["growing"] = np.where(pocket & field["occupied"], 0, field["growing"]).astype(field["growing"].dtype)
    np.savez(out / "field.npz", **field)
    assert {r.name: r.passed for r in verify_layers.checks(out)}[name]


def test_a_layer_on_missed_voxels_lies_on_no_voxels_of_another_layer(kitten_slice, tmp_path):
    """Two layers' files swapped lie off their own voxels: the check fails. Once the voxels of both layers are
    missed (G = 0 in H̄), no layer of G is there to lie on: the surfaces cross such voxels on guessed layers
    (the elephant at 0.8 mm, whose trunk is missed: layer 58 lies wholly on missed voxels), and it passes."""
    import shutil

    out = tmp_path / "swapped"
    shutil.copytree(kitten_slice, out)
    name = "each layer lies on its own voxels"
    files = sorted((out / "layers").glob("layer_*.ply"))
    a, b = len(files) // 3, 2 * len(files) // 3
    data = files[a].read_bytes(), files[b].read_bytes()
    files[a].write_bytes(data[1])
    files[b].write_bytes(data[0])
    assert not {r.name: r.passed for r in verify_layers.checks(out)}[name]
    with np.load(out / "field.npz") as f:
        field = dict(f)
    gone = (field["growing"] == a + 1) | (field["growing"] == b + 1)
    field["growing"] = np.where(gone, 0, field["growing"]).astype(field["growing"].dtype)
    np.savez(out / "field.npz", **field)
    assert {r.name: r.passed for r in verify_layers.checks(out)}[name]


def test_closest_points_in_chunks_are_trimeshs(monkeypatch):
    """The verifier's closest points on ∂H, a few points per call (trimesh's candidate arrays grow with the points
    times the triangles near each: 4 GB on a coarse gear), are trimesh's in one call, row for row."""
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    pts = np.random.default_rng(3).normal(size=(53, 3)) * 8.0
    whole = trimesh.proximity.closest_point(mesh, pts)
    monkeypatch.setattr(verify_layers, "CLOSEST_CHUNK", 10)
    chunked = verify_layers.closest_on(mesh, pts)
    for x, y in zip(whole, chunked):
        assert np.array_equal(x, y)
