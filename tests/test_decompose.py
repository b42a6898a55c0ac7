"""RoboFDM decomposition (thesis ch. 2) and nozzle placement (§2.3.1)."""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import pytest

from curvslice.decompose import decompose
from curvslice.decompose.constraints import constraint_one, faces_up, sections_intersect
from curvslice.decompose.parts import Plane, cross_section, to_trimesh
from curvslice.decompose.placement import box_counts, brute_force_counts, platform_frames
from curvslice.decompose.risky import risky_area, risky_faces


def y_solid() -> m3.Manifold:
    """A Y: a 12 mm-radius stem on the platform with two 4 mm arms leaning 50° off vertical, rooted
    14 mm apart on its top (the arms' undersides hang along +z).

    Known weakness: the coarse segmentation depends on the triangulation; the same solid united
    as stem + foot first ends with both arms in one part (40 mm² left risky).
    """
    stem = m3.Manifold.cylinder(44, 12, 12, 48)
    arm = m3.Manifold.cylinder(40, 4, 4, 32)
    foot = m3.Manifold.cylinder(4, 12, 12, 48)  # the same radius: only the triangulation changes
    return (foot + stem + arm.rotate((0, 50, 0)).translate((7, 0, 40))
            + arm.rotate((0, -50, 0)).translate((-7, 0, 40))).refine_to_length(2.0)


def test_risky_area_of_a_box_matches_eq_2_1():
    box = to_trimesh(m3.Manifold.cube((20, 10, 5)))
    up = np.array([0.0, 0.0, 1.0])
    assert risky_area(box, Plane(up, 0.0), np.radians(45)) == pytest.approx(0.0)  # bottom is the base
    assert risky_area(box, Plane(up, -1.0), np.radians(45)) == pytest.approx(200.0)  # bottom hangs
    # tilted 40° about y the bottom hangs (n·d = -cos 40° < -sin 45°); at 50° it is self-supported
    # but the 10 x 5 mm side facing -x hangs (n·d = -sin 50°)
    for tilt, expected in ((40, 200.0), (50, 50.0)):
        d = np.array([np.sin(np.radians(tilt)), 0.0, np.cos(np.radians(tilt))])
        faces = risky_faces(box, Plane(d, -100.0), np.radians(45))
        assert box.area_faces[faces].sum() == pytest.approx(expected)


def test_y_solid_decomposes_into_a_standing_stem_and_two_arms():
    solid = y_solid()
    mesh = to_trimesh(solid)
    up = np.array([0.0, 0.0, 1.0])
    assert risky_area(mesh, Plane(up, 0.0), np.radians(45)) > 100.0  # not printable along +z
    dec = decompose(mesh)
    parts = dec.parts
    assert len(parts) == 3
    # the parts partition the model, keep Constraints I and II, and are all support-free
    assert sum(p.mesh.volume for p in parts) == pytest.approx(solid.volume(), rel=1e-3)
    assert not dec.constraint_one_violations() and not dec.constraint_two_violations()
    assert max(p.risky_area for p in parts) < 1.0
    # the root is the stem standing on its flat bottom; each arm tip is in its own later part
    assert np.degrees(np.arccos(dec.root_direction @ up)) < 5.0
    assert parts[0].mesh.bounds[0][2] == pytest.approx(0.0, abs=1e-3)
    assert parts[0].mesh.bounds[1][2] < 50.0
    tips = [np.array([s * 34.0, 0.0, 64.0]) for s in (-1, 1)]
    owner = [min(range(3), key=lambda i: parts[i].mesh.nearest.on_surface([t])[1][0]) for t in tips]
    assert sorted(owner) == [1, 2]
    # each arm is printed from a plane leaning towards its own side
    for i, side in zip(owner, (-1, 1)):
        assert side * parts[i].base.normal[0] > 0.5


def test_constraint_one_detects_crossing_base_sections():
    """Fig. 2.6: two base planes through one block whose sections cross on the planes' common line."""
    block = m3.Manifold.cube((20, 20, 20))
    a = Plane(np.array([1.0, 0.0, 0.0]), 10.0)
    b = Plane(np.array([0.0, 0.0, 1.0]), 10.0)
    ra, rb = cross_section(block, a), cross_section(block, b)
    assert ra.area == pytest.approx(400.0, rel=1e-3)
    assert sections_intersect(a, ra, b, rb)
    assert constraint_one([a, b], [ra, rb]) == [(0, 1)]
    # an L (slab along x, wall along z): the slab's end section at x = 12 and the wall's top
    # section at z = 14 are both crossed by the planes' common line, but neither where the other is
    ell = m3.Manifold.cube((20, 20, 8)) + m3.Manifold.cube((8, 20, 20))
    pa, pb = Plane(a.normal, 12.0), Plane(b.normal, 14.0)
    assert not sections_intersect(pa, cross_section(ell, pa), pb, cross_section(ell, pb))
    pa = Plane(a.normal, 4.0)  # through the wall instead: the two sections now cross
    assert sections_intersect(pa, cross_section(ell, pa), pb, cross_section(ell, pb))
    # parallel, distinct planes never meet; the same plane overlaps itself
    assert not sections_intersect(b, cross_section(block, b), Plane(b.normal, 15.0), cross_section(block, Plane(b.normal, 15.0)))
    assert sections_intersect(b, cross_section(block, b), b, cross_section(block, b))
    assert faces_up(b.normal, np.array([0.0, 0.0, 1.0])) and not faces_up(-b.normal, np.array([0.0, 0.0, 1.0]))


@pytest.mark.parametrize("robot_name", ["ur3", "ur5"])
def test_grid_search_optimum_equals_brute_force(robot_name):
    from curvslice.kinematics import load_robot
    from curvslice.workcell import load_workcell

    cell = load_workcell(robot_name)
    pts = platform_frames(load_robot(robot_name), cell, 10_000, seed=1)
    assert len(pts) > 3_000  # about half the frames face up
    reach = box_counts(pts, box=200.0, cell=100.0)
    idx = np.indices(reach.counts.shape).reshape(3, -1).T
    centres = reach.origin + reach.cell * idx
    brute = brute_force_counts(pts, centres, 200.0)
    np.testing.assert_array_equal(brute, reach.counts.ravel())
    centre, count = reach.best
    assert count == brute.max()
    np.testing.assert_allclose(centre, centres[np.argmax(brute)])


def test_verify_flags_crossing_base_sections(tmp_path):
    """A hand-made folder whose two base faces cross (Fig. 2.6) fails `curvslice verify`'s Constraint I."""
    import json

    from curvslice.verify.decompose import checks

    boxes = [((0, 0, 0), (10, 20, 10)), ((10, 0, 0), (10, 20, 20)), ((0, 0, 10), (20, 20, 10))]
    planes = [((0, 0, 1), 0.0), ((1, 0, 0), 10.0), ((0, 0, 1), 10.0)]
    parts = []
    for k, ((x, y, z), size) in enumerate(boxes):
        to_trimesh(m3.Manifold.cube(size).translate((x, y, z))).export(tmp_path / f"part_{k:02d}.stl")
        parts.append({"file": f"part_{k:02d}.stl", "base_plane": {"normal": list(planes[k][0]), "offset_mm": planes[k][1]},
                      "risky_area_mm2": 0.0})
    (tmp_path / "parts.json").write_text(json.dumps({"alpha_max_deg": 45.0, "root_direction": [0, 0, 1], "parts": parts}))
    result = {c.name: c for c in checks(tmp_path)}
    assert not result["Constraint I (base sections apart)"].passed
    assert result["Constraint I (base sections apart)"].value == "1 pairs"
    assert result["Constraint II (base planes face up)"].passed is False  # x = 10 is vertical: n·d_root = 0


def test_cli_decompose_then_verify(tmp_path):
    """`curvslice decompose` writes the folder contract and `curvslice verify` re-checks it."""
    import json

    from curvslice.cli import main

    model = tmp_path / "y.stl"
    to_trimesh(y_solid()).export(model)
    out = tmp_path / "y_parts"
    assert main(["decompose", str(model), "--out", str(out)]) == 0
    spec = json.loads((out / "parts.json").read_text())
    assert [p["sequence"] for p in spec["parts"]] == list(range(len(spec["parts"])))
    assert all((out / p["file"]).exists() for p in spec["parts"])
    assert spec["parts"][0]["parent"] is None and all(p["parent"] < p["sequence"] for p in spec["parts"][1:])
    for p in spec["parts"]:  # T_P^E is a rigid transform whose z axis is the build direction in E
        T = np.asarray(p["T_P_E"])
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    assert (out / "parts.png").exists() and (out / "report.json").exists()
    assert main(["verify", str(out)]) == 0


def test_cli_workcell_place_writes_a_loadable_workcell(tmp_path):
    from curvslice.cli import main
    from curvslice.workcell import load_workcell

    out = tmp_path / "ur3.json"
    assert main(["workcell", "place", "--robot", "ur3", "--samples", "20000", "--box", "100", "--grid", "20",
                 "--out", str(out)]) == 0
    cell = load_workcell(out)
    assert cell.robot == "ur3" and out.with_suffix(".png").exists()
    report = __import__("json").loads(out.with_suffix(".report.json").read_text())
    np.testing.assert_allclose(cell.nozzle[:3, 3], report["nozzle_mm"], atol=1e-6)
    assert report["frames_in_box"] > 0


def test_first_layer_above_any_base_plane_is_not_risky():
    """An upside-down frustum (a cone widening upwards 60° off vertical) printed along +z hangs all
    round, except within the first layer above its base: from the platform and from a cut alike."""
    from curvslice.decompose.risky import FIRST_LAYER_MM

    r0, height = 5.0, 6.0
    cone = m3.Manifold.cylinder(height, r0, r0 + height * np.tan(np.radians(60)), 128).refine_to_length(0.25)
    mesh = to_trimesh(cone)
    up = np.array([0.0, 0.0, 1.0])

    def flank(z0: float, z1: float) -> float:  # lateral area of the frustum between two heights
        r = lambda z: r0 + z * np.tan(np.radians(60))  # noqa: E731
        return np.pi * (r(z0) + r(z1)) * (z1 - z0) / np.cos(np.radians(60))

    for offset in (0.0, -2.0):  # standing on the platform; the same frustum cut 2 mm lower is a child's base
        base = Plane(up, offset)
        expected = flank(max(FIRST_LAYER_MM + offset, 0.0), height)
        bottom = np.pi * r0**2 if offset < -FIRST_LAYER_MM else 0.0  # a base 2 mm under the bottom face: it hangs
        assert risky_area(mesh, base, np.radians(45)) == pytest.approx(expected + bottom, rel=0.01)


def _two_part_folder(folder):
    """A 16 x 16 x 12 block cut by a plane tilted 30° about y: the root below stands on the platform
    (+z), the top is printed along the plane's normal; written as a `curvslice decompose` folder."""
    import json

    from curvslice.decompose.parts import part_pose, plane_frame, split

    block = m3.Manifold.cube((16, 16, 12)).translate((-8, -8, 0))
    n = np.array([np.sin(np.radians(30)), 0.0, np.cos(np.radians(30))])
    cut = Plane(n, float(n @ np.array([0.0, 0.0, 6.0])))
    below, above = split(block, cut)
    meshes = [to_trimesh(below), to_trimesh(above[0])]
    bases = [Plane(np.array([0.0, 0.0, 1.0]), 0.0), cut]
    centres = [np.zeros(3), (cut.frame() @ np.r_[np.asarray(cross_section(above[0], cut).centroid.coords[0]), 0, 1])[:3]]
    root_frame = plane_frame(bases[0].normal, centres[0])
    parts = []
    for k, (m, b, c) in enumerate(zip(meshes, bases, centres)):
        m.export(folder / f"part_{k:02d}.stl")
        parts.append({"file": f"part_{k:02d}.stl", "sequence": k, "parent": None if k == 0 else 0,
                      "base_plane": {"normal": b.normal.tolist(), "offset_mm": b.offset},
                      "build_direction": b.normal.tolist(), "base_centre_mm": c.tolist(), "risky_area_mm2": 0.0,
                      "T_P_E": part_pose(b, c, root_frame).tolist()})
    to_trimesh(block).export(folder / "solid.stl")
    (folder / "parts.json").write_text(json.dumps({"alpha_max_deg": 45.0, "first_layer_mm": 0.5,
                                                   "root_direction": [0, 0, 1], "parts": parts}))
    (folder / "report.json").write_text(json.dumps({"stage": "decompose"}))
    return meshes, n


def test_printed_parts_are_planar_along_their_directions_and_verify_catches_a_tilted_nozzle(tmp_path):
    """`print_decomposition`: every layer a plane of its part's frame inside the part, the nozzle along
    the part's direction, layers and samples in sequence order, one G-code for both parts; verify
    re-checks it from the files, and fails when one part's nozzle axis is tilted."""
    import json

    from curvslice.decompose.printing import print_decomposition
    from curvslice.verify import verify_outdir

    meshes, n = _two_part_folder(tmp_path)
    sections = print_decomposition(tmp_path, voxel=2.0, meshes=meshes)
    with np.load(tmp_path / "toolpaths.npz") as z:
        tp = {k: z[k] for k in z.files}
    assert sections["toolpaths"]["samples"] == len(tp["positions"]) > 0
    assert np.all(np.diff(tp["part"]) >= 0) and set(tp["part"].tolist()) == {0, 1}
    np.testing.assert_allclose(tp["normals"][tp["part"] == 0], np.tile([0, 0, 1.0], ((tp["part"] == 0).sum(), 1)), atol=1e-9)
    np.testing.assert_allclose(tp["normals"][tp["part"] == 1] @ n, 1.0, atol=1e-9)
    # the platform frame E is the root's: the top part's samples sit on planes above the cut, every layer height
    # (2 mm) but the last, lowered into the part where the part ends (the working-surface stage's fallback)
    levels = np.unique(np.round(tp["positions"][tp["part"] == 1] @ n - 6.0 * n[2], 6))
    np.testing.assert_allclose(levels[:-1], 2.0 * np.arange(1, len(levels)), atol=1e-6)
    assert levels[-2] < levels[-1] < (meshes[1].vertices @ n).max() - 6.0 * n[2]
    result = {c.name: c for c in verify_outdir(tmp_path)}
    for name in ("planar layers", "layers inside their parts", "nozzle along each part's direction",
                 "union equals model", "gcode matches npz", "orientation validity"):
        assert result[name].passed, (name, result[name].value, result[name].detail)
    tp["normals"][tp["part"] == 1] = np.array([0.0, 0.0, 1.0])  # the top part printed along the root's z
    np.savez_compressed(tmp_path / "toolpaths.npz", **tp)
    result = {c.name: c for c in verify_outdir(tmp_path)}
    assert not result["nozzle along each part's direction"].passed
    assert json.loads((tmp_path / "report.json").read_text())["stages"] == ["layers", "toolpaths"]


def test_a_thin_top_oblique_to_the_voxel_grid_is_contoured_again_on_a_finer_grid():
    """A fin 12 mm broad at the platform narrowing to 0.5 mm at 9 mm, turned 45° to the voxel grid: at a
    2 mm voxel its top sections are narrower than two voxels, and the voxel contour trimmed by the solid
    keeps only the stars of the grid vertices inside them (the bunny's part 6 top: 6.7 of 13.5 mm²).
    `print_part` contours such a part on a grid half the voxel, keeping the layer height; every layer's
    area then matches manifold3d's exact slice of the part, and the tool-path stage covers each."""
    import shapely
    import trimesh

    from curvslice.decompose.printing import SECTION_KEPT, planar_layers, print_part, section_kept
    from curvslice.toolpaths import ToolpathSettings
    from curvslice.verify.toolpaths import layer_cover

    fin = trimesh.creation.extrude_polygon(shapely.geometry.Polygon([(-6, 0), (6, 0), (0.25, 9), (-0.25, 9)]), 16)
    fin.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    fin.apply_translation([0, 8, 0])
    fin.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 4, [0, 0, 1]))
    assert section_kept(fin, [m for m in planar_layers(fin, 2.0, 2.0) if len(m.faces)]) < SECTION_KEPT
    pp = print_part(fin, np.eye(4), 0, 2.0, 2.0, ToolpathSettings(path_width=2.5))
    assert pp.contour_mm == 1.0
    solid = m3.Manifold(m3.Mesh(vert_properties=np.asarray(fin.vertices, np.float32), tri_verts=np.asarray(fin.faces, np.uint32)))
    tp = pp.toolpaths
    for k, layer in enumerate(pp.layers, start=1):
        z = float(layer.vertices[:, 2].mean())
        assert z == pytest.approx(2.0 * k, abs=1e-6) or k == len(pp.layers)  # the layer height is kept
        assert layer.area == pytest.approx(solid.slice(z).area(), rel=0.05)
        at = tp.layer == k
        assert layer_cover(layer, tp.positions[at], tp.path[at], 2.5, bead=tp.bead[at])[0] >= 0.95


def test_platform_clearance_of_a_cylinder_and_a_cone_extruder():
    """A cylinder of radius r from a to b above the tip dips r·sinθ - a·cosθ below it at tilt θ; a cone
    with its apex on the tip never dips before θ reaches 90° - its half-angle."""
    from dataclasses import replace

    from curvslice.decompose.constraints import platform_clearance
    from curvslice.workcell import Body, load_workcell, pose_matrix

    cell = load_workcell("ur3")
    r, a, b = 6.0, 2.0, 12.0
    cylinder = replace(cell, extruder=(Body("body", "cylinder", (r, b - a), pose_matrix([0, 0, (a + b) / 2], [0, 0, 0])),))
    for deg in (0, 10, 30, 60, 85):
        t = np.radians(deg)
        exact = max(0.0, r * np.sin(t) - a * np.cos(t))
        assert exact - 1e-9 <= platform_clearance(cylinder, t) <= exact + 0.01 * r  # the rim is circumscribed
    half = np.degrees(np.arctan(4.0 / 5.0))  # radius 4 at 5 mm: apex at the tip (cone apex at +length/2, turned over)
    cone = replace(cell, extruder=(Body("nozzle", "cone", (4.0, 5.0), pose_matrix([0, 0, 2.5], [180, 0, 0])),))
    assert platform_clearance(cone, np.radians(90 - half - 1)) == 0.0
    assert platform_clearance(cone, np.radians(90 - half + 10)) > 0.5


def test_robot_stage_on_one_part_of_a_printed_sequence(tmp_path):
    """`plan_robot(..., parts=[1])`: the top part of the two-part block planned for the UR3 with the root's
    layers as obstacles; joints.csv indexes the folder's toolpaths.npz (only part 1's rows), and the
    verifier's robot checks pass but for the root's samples, counted as not realized."""
    import json

    from curvslice.decompose.printing import plan_robot, print_decomposition
    from curvslice.verify import verify_outdir

    meshes, _ = _two_part_folder(tmp_path)
    print_decomposition(tmp_path, voxel=4.0, meshes=meshes)
    report = plan_robot(tmp_path, "ur3", parts=[1])
    with np.load(tmp_path / "toolpaths.npz") as z:
        part = z["part"]
    from curvslice.exporters.joints_csv import read_joints_csv

    index = read_joints_csv(tmp_path / "joints.csv")["index"]
    assert report["parts_planned"] == [1] and report["waypoints"] == int((part == 1).sum())
    assert len(index) and np.all(part[index] == 1) and report["rows"] == len(index)
    assert json.loads((tmp_path / "report.json").read_text())["stages"] == ["layers", "toolpaths", "robot"]
    result = {c.name: c for c in verify_outdir(tmp_path) if c.stage == "robot"}
    realized = result.pop("waypoints realized")
    assert not realized.passed and realized.value == f"{len(np.unique(index))}/{len(part)}"
    assert all(c.passed for c in result.values()), {n: (c.value, c.detail) for n, c in result.items() if not c.passed}


def test_extruder_hits_a_point_over_the_tip_but_not_beside_or_below_it():
    """A cylinder extruder of radius 6 mm from 2 to 12 mm over the tip: a point 5 mm over the tip is
    inside at every turn, one 5 mm below or 10 mm aside is not; tilted 60° towards +x, the body
    reaches over a point 8 mm aside and 5 mm up (9.4 mm along the axis, 0.3 mm from it)."""
    from dataclasses import replace

    from curvslice.decompose.constraints import extruder_hits
    from curvslice.workcell import Body, load_workcell, pose_matrix

    cell = replace(load_workcell("ur3"), extruder=(Body("body", "cylinder", (6.0, 10.0), pose_matrix([0, 0, 7], [0, 0, 0])),))
    tip = np.zeros((1, 3))
    up = np.array([0.0, 0.0, 1.0])
    pts = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, -5.0], [10.0, 0.0, 3.0]])
    assert extruder_hits(cell, tip, up, pts[:1]).all()
    assert not extruder_hits(cell, tip, up, pts[1:]).any()
    tilted = np.array([np.sin(np.radians(60)), 0.0, np.cos(np.radians(60))])
    assert not extruder_hits(cell, tip, up, np.array([[8.0, 0.0, 5.0]])).any()
    assert extruder_hits(cell, tip, tilted, np.array([[8.0, 0.0, 5.0]])).all()


def test_printing_order_prints_the_part_leaning_over_its_sibling_first():
    """A slab with a 40 mm post (part 1) and, on a pedestal 10 mm from it, a low block printed 35°
    towards the post (part 2): breadth-first order prints the post first and the UR3 extruder's body
    then hits it while printing the block; the extruder-aware order prints the block first and
    neither is blocked."""
    import trimesh

    from curvslice.decompose.constraints import extruder_hits
    from curvslice.decompose.sequence import breadth_first_order, extruder_aware_order
    from curvslice.workcell import load_workcell

    box = lambda lo, hi: trimesh.creation.box(bounds=[lo, hi])  # noqa: E731
    root = trimesh.util.concatenate([box([-10, -10, 0], [50, 10, 5]), box([0, -5, 5], [10, 5, 15])])
    meshes = {0: root, 1: box([20, -5, 5], [30, 5, 45]), 2: box([0, -5, 15], [10, 5, 18])}
    meshes = {k: m.subdivide_to_size(4.0) for k, m in meshes.items()}
    tilt = np.radians(35)
    dirs = {0: np.array([0.0, 0, 1]), 1: np.array([0.0, 0, 1]), 2: np.array([np.sin(tilt), 0, np.cos(tilt)])}
    parent = {0: None, 1: 0, 2: 0}
    assert breadth_first_order(0, parent) == [0, 1, 2]
    cell = load_workcell("ur3")
    order, blocked = extruder_aware_order(0, parent, meshes, dirs, cell)
    assert order == [0, 2, 1]
    assert all(b == 0 for b, _ in blocked.values()), blocked
    assert extruder_hits(cell, meshes[2].vertices, dirs[2], meshes[1].vertices).all(axis=1).any()  # BFS order


def test_fabrication_minutes_of_a_square_and_a_jump(tmp_path):
    """Table 2.1's fabrication time from toolpaths.npz: a 10 mm square at the G-code feed (600 mm/min)
    is 4 s, a 50 mm jump to the next path at the UR3 cell's travel speed 50 mm/s is 1 s more."""
    from benchmarks.bench_decompose import fabrication_minutes
    from curvslice.workcell import load_workcell

    square = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0], [0, 0, 0]], float)
    positions = np.vstack([square, square[-1] + [0, 50, 0]])
    np.savez(tmp_path / "toolpaths.npz", positions=positions, path=np.array([0, 0, 0, 0, 0, 1]),
             feed=np.full(6, 600.0))
    cell = load_workcell("ur3")
    assert cell.travel_speed == 50.0  # the figure the expectation uses
    assert fabrication_minutes(tmp_path) == pytest.approx((40 / 10 + 50 / 50) / 60)


def test_fine_decomposition_avoids_a_cut_the_extruder_cannot_print():
    """A slab printed first with a 60 mm wall at x = 40, and standing on it a post with a flare and an
    arm leaning 55° towards the wall (108 mm² risky along +z). Without the extruder the Eq. 2.2 search
    cuts the arm off along a plane leaning 27° towards the wall, and the UR3 extruder printing that part
    meets the wall at every turn at many of its vertices; with it, the search takes another plane that
    leaves every part support-free and every vertex of the new part a clear turn."""
    from curvslice.decompose.constraints import extruder_hits
    from curvslice.decompose.fine_tuning import Piece, Settings, fine_decomposition, part_risk
    from curvslice.workcell import load_workcell

    up = np.array([0.0, 0.0, 1.0])
    root = (m3.Manifold.cube((90, 30, 6)).translate((-45, -15, 0))
            + m3.Manifold.cube((6, 30, 60)).translate((40, -15, 0))).refine_to_length(2.0)
    flare = 8 * np.tan(np.radians(40))  # a 40° flare: self-supported printed upright, not when tilted over 5°
    post = (m3.Manifold.cylinder(8, 6, 6, 32).translate((-15, 0, 6))
            + m3.Manifold.cylinder(8, 6, 6 + flare, 32).translate((-15, 0, 14))
            + m3.Manifold.cylinder(4, 6 + flare, 6 + flare, 32).translate((-15, 0, 22)))
    arm = m3.Manifold.cylinder(25, 4, 4, 32).rotate((0, 55, 0)).translate((-7, 0, 23))
    g = (post + arm).refine_to_length(2.0)
    cell = load_workcell("ur3")
    results = {}
    for workcell in (None, "ur3"):
        s = Settings(workcell=workcell)
        pieces = {0: Piece(root, Plane(up, 0.0), None, cross_section(root, Plane(up, 0.0), 0.5)),
                  1: Piece(g, Plane(up, 6.0), 0, cross_section(g, Plane(up, 6.0)))}
        assert part_risk(pieces[1], s.alpha_max) > 100.0
        cuts = fine_decomposition(pieces, [], up, root.volume() + g.volume(), s)
        assert len(cuts) == 1 and set(pieces) == {0, 1, 2} and pieces[2].parent == 1
        assert max(part_risk(p, s.alpha_max) for p in pieces.values()) < 1.0
        new = to_trimesh(pieces[2].solid)
        earlier = np.vstack([to_trimesh(pieces[i].solid).vertices for i in (0, 1)])
        results[workcell] = int(extruder_hits(cell, new.vertices, pieces[2].base.normal, earlier).all(axis=1).sum())
    assert results[None] > 50  # the cut the thesis's search takes leaves a part the extruder cannot print
    assert results["ur3"] == 0


def test_verify_counts_a_ceiling_within_one_layer_over_the_platform_as_printed_on_it(tmp_path):
    """A 20 x 20 x 10 block with a 10 x 10 pocket 1.5 mm deep under it: the pocket's ceiling faces straight
    down 1.5 mm over the platform (100 mm²). Printed in 2 mm layers it lies in the first layer, on the
    platform; in 1 mm layers it hangs, and verify passes when parts.json reports that remainder and
    fails when the part claims less (the acceptance: "risky area 0 ... or the remainder reported")."""
    import json

    from curvslice.decompose.parts import part_pose, plane_frame
    from curvslice.verify.decompose import checks

    block = m3.Manifold.cube((20, 20, 10)).translate((-10, -10, 0)) - m3.Manifold.cube((10, 10, 2.5)).translate((-5, -5, -1))
    mesh = to_trimesh(block)
    mesh.export(tmp_path / "part_00.stl")
    mesh.export(tmp_path / "solid.stl")
    up = Plane(np.array([0.0, 0.0, 1.0]), 0.0)
    for layer, risky, claim in ((2.0, 0.0, 0.0), (1.0, 100.0, 100.0), (1.0, 100.0, 0.0), (1.0, 100.0, 60.0)):
        part = {"file": "part_00.stl", "sequence": 0, "parent": None,
                "base_plane": {"normal": up.normal.tolist(), "offset_mm": 0.0}, "build_direction": up.normal.tolist(),
                "base_centre_mm": [0.0, 0.0, 0.0], "risky_area_mm2": claim, "risky_underside_mm2": claim,
                "T_P_E": part_pose(up, np.zeros(3), plane_frame(up.normal, np.zeros(3))).tolist()}
        (tmp_path / "parts.json").write_text(json.dumps({"alpha_max_deg": 45.0, "first_layer_mm": 0.5, "underside_mm": 5.0,
                                                         "platform_layer_mm": layer, "root_direction": [0, 0, 1],
                                                         "parts": [part]}))
        by_name = {c.name: c for c in checks(tmp_path)}
        assert by_name["risky area per part"].passed == (claim == risky)  # recomputed from the mesh
        free = by_name["every part support-free or remainder reported"]
        assert free.passed == (claim == risky)  # a remainder passes when reported, fails when understated
        assert ("part 0: 100.0" in free.value) == (risky > 0)  # the remainder is listed per part
