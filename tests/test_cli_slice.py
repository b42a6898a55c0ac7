"""`curvslice slice` / `verify` as a user runs them: outputs, bad input, atomic folders."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from curvslice.cli import main
from curvslice.errors import CurvsliceError
from curvslice.solid import load_solid, place, repair

MODELS = Path(__file__).resolve().parents[1] / "models"


def _run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "curvslice", *args], cwd=cwd, capture_output=True, text=True)


def test_slice_writes_the_contract_files_and_verifies(tmp_path):
    out = tmp_path / "tee"
    assert main(["slice", str(MODELS / "tee.stl"), "--voxel", "2", "--out", str(out), "--stages", "field", "--quiet", "--no-verify"]) == 0
    with np.load(out / "field.npz") as z:
        assert {"occupied", "peeling", "growing", "origin", "voxel_size", "method", "platform_vertices"} <= set(z.files)
        assert str(z["method"]) == "pg-sp-gcfa" and z["growing"].dtype == np.int32
        assert ((z["growing"] > 0) <= z["occupied"]).all()
    report = json.loads((out / "report.json").read_text())
    assert report["field"]["missed"] == 0 and report["field"]["layers"] == int(np.load(out / "field.npz")["growing"].max())
    assert {"load", "voxelize", "peeling", "growing"} <= set(report["timings_s"])
    assert report["parameters"]["voxel"] == 2.0
    solid = trimesh.load(out / "solid.stl")
    assert solid.bounds[0, 2] == pytest.approx(0.0, abs=1e-9) and solid.is_watertight
    assert main(["verify", str(out)]) == 0


def test_existing_output_needs_force_and_input_is_never_overwritten(tmp_path):
    out = tmp_path / "o"
    args = ["slice", str(MODELS / "tee.stl"), "--voxel", "3", "--out", str(out), "--stages", "field", "--quiet", "--no-verify"]
    assert main(args) == 0
    assert main(args) == 2
    assert main(args + ["--force"]) == 0
    model = tmp_path / "m" / "tee.stl"
    model.parent.mkdir()
    model.write_bytes((MODELS / "tee.stl").read_bytes())
    (model.parent / "report.json").write_text("{}")
    assert main(["slice", str(model), "--voxel", "3", "--out", str(model.parent), "--force", "--quiet"]) == 2
    assert model.read_bytes() == (MODELS / "tee.stl").read_bytes()


def _holed_sphere(tmp_path: Path, drop: int) -> Path:
    s = trimesh.creation.icosphere(subdivisions=3, radius=10)
    keep = np.ones(len(s.faces), bool)
    centre = s.triangles_center[:, 2].argmax()
    near = np.argsort(np.linalg.norm(s.triangles_center - s.triangles_center[centre], axis=1))[:drop]
    keep[near] = False
    path = tmp_path / f"holed{drop}.stl"
    trimesh.Trimesh(s.vertices, s.faces[keep]).export(path)
    return path


BAD_INPUTS = {
    "missing file": lambda d: d / "nope.stl",
    "not a mesh": lambda d: (d / "junk.stl").write_bytes(b"\x00garbage" * 100) and d / "junk.stl",
    "empty mesh": lambda d: (d / "empty.obj").write_text("# nothing\n") and d / "empty.obj",
    "mesh with a large hole": lambda d: _holed_sphere(d, 40),
    "wrong extension": lambda d: (d / "model.txt").write_text("solid") and d / "model.txt",
}


@pytest.mark.parametrize("case", BAD_INPUTS)
def test_bad_input_gives_one_clear_line_and_no_folder(tmp_path, case):
    path = BAD_INPUTS[case](tmp_path)
    r = _run_cli("slice", str(path), "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert r.stderr.startswith("curvslice slice: error:")
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.partial*"))


def test_voxel_size_needing_too_much_memory_is_refused(tmp_path):
    r = _run_cli("slice", str(MODELS / "tee.stl"), "--voxel", "0.005", "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert r.returncode == 2 and "GiB" in r.stderr and "--voxel" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()


def test_verify_fails_on_a_tampered_field(tmp_path):
    """Both sides: the untampered slice (all stages to tool-paths) passes every check, the same
    folder with one voxel of G moved to layer 2 fails."""
    out = tmp_path / "t"
    assert main(["slice", str(MODELS / "tee.stl"), "--voxel", "2", "--stages", "toolpaths", "--out", str(out),
                 "--quiet"]) == 0
    r = _run_cli("verify", str(out), cwd=tmp_path)
    assert r.returncode == 0 and "FAIL" not in r.stdout, r.stdout
    z = dict(np.load(out / "field.npz"))
    g = z["growing"]
    g[tuple(np.argwhere(g == g.max())[0])] = 2
    np.savez(out / "field.npz", **z)
    r = _run_cli("verify", str(out), cwd=tmp_path)
    assert r.returncode == 1 and "FAIL" in r.stdout


def test_a_thin_walled_box_is_printed_on_its_walls_and_a_bead_across_it_fails_verify(tmp_path):
    """An open-top box with 1.5 mm walls at 1 mm voxels: where a layer's wall is a band too narrow for
    two beads, one loop round the box prints it (the centre line of either contour ring alone paired its
    sides across the box: on layer 5 a bead ran 15 mm through the inside, 2.5 mm from the floor). Every
    verify check passes, the beads-inside-H one with them; the same tool-paths with one wall's pass moved
    onto the box's middle line fail it."""
    import manifold3d as mf

    def box(extents, centre):
        return mf.Manifold.cube(extents, center=True).translate(centre)

    solid = (box([24, 18, 14], [0, 0, 7]) - box([21, 15, 14], [0, 0, 8.5])).to_mesh()
    path = tmp_path / "box.stl"
    trimesh.Trimesh(np.asarray(solid.vert_properties)[:, :3], np.asarray(solid.tri_verts)).export(path)
    out = tmp_path / "box"
    assert main(["slice", str(path), "--voxel", "1", "--stages", "toolpaths", "--out", str(out), "--quiet"]) == 0
    line = next(x for x in _run_cli("verify", str(out), cwd=tmp_path).stdout.splitlines() if "printed segments inside H" in x)
    assert "PASS" in line and " 0 beads" in line, line
    z = dict(np.load(out / "toolpaths.npz"))
    wall = (z["layer"] == z["layer"].max() // 2) & (np.abs(z["positions"][:, 1]) > 7.4)
    assert wall.sum() > 5  # a layer's samples on the two long walls
    z["positions"][wall, 1] = 0.0  # moved onto the box's middle line, over its empty inside
    np.savez(out / "toolpaths.npz", **z)
    r = _run_cli("verify", str(out), cwd=tmp_path)
    line = next(x for x in r.stdout.splitlines() if "printed segments inside H" in x)
    assert r.returncode == 1 and "FAIL" in line and " 0 beads" not in line, r.stdout


def test_small_holes_are_filled_and_inverted_meshes_flipped():
    s = trimesh.creation.icosphere(subdivisions=3, radius=10)
    holed = trimesh.Trimesh(s.vertices, s.faces[1:])
    fixed, notes = repair(holed)
    assert fixed.is_watertight and fixed.volume == pytest.approx(s.volume, rel=1e-3)
    inverted = trimesh.Trimesh(s.vertices, s.faces[:, ::-1])
    fixed, notes = repair(inverted)
    assert fixed.volume > 0 and any("invert" in n for n in notes)


def test_up_axis_and_size_placement():
    box = trimesh.creation.box([2.0, 4.0, 8.0])
    placed, scale = place(box, up="y", size=40.0)
    assert scale == pytest.approx(5.0)
    # the model's y extent (4 mm, x5 = 20 mm) now points up; the others stay horizontal
    assert placed.extents[2] == pytest.approx(20.0)
    assert sorted(placed.extents[:2]) == pytest.approx([10.0, 40.0])
    assert placed.bounds[0, 2] == pytest.approx(0.0)
    assert np.allclose((placed.bounds[0, :2] + placed.bounds[1, :2]) / 2, 0.0)


def test_unit_confusion_is_caught(tmp_path):
    tiny = trimesh.creation.box([0.05, 0.04, 0.06])
    tiny.export(tmp_path / "metres.stl")
    with pytest.raises(CurvsliceError, match="metres"):
        load_solid(tmp_path / "metres.stl")
    solid, rep = load_solid(tmp_path / "metres.stl", scale=1000.0)
    assert solid.extents.max() == pytest.approx(60.0)


def test_touching_bodies_lose_their_internal_wall(tmp_path):
    """Two boxes sharing a face with the same triangles (an assembly export): the shared wall's two copies
    have opposite winding and cancel, leaving one closed solid of the union's volume."""
    a = trimesh.creation.box((10, 10, 10)).apply_translation((5, 0, 5))
    b = trimesh.Trimesh(a.vertices * [-1, 1, 1] + [20, 0, 0], a.faces[:, ::-1], process=False)  # mirrored at x = 10
    joined = trimesh.Trimesh(np.vstack([a.vertices, b.vertices]), np.vstack([a.faces, b.faces + len(a.vertices)]),
                             process=False)
    fixed, notes = repair(joined)
    assert fixed.is_watertight and fixed.volume == pytest.approx(2000.0)
    assert any("internal wall" in n for n in notes)
    fin = trimesh.Trimesh(joined.vertices, np.vstack([joined.faces, [[0, 1, 2]]]), process=False)
    fin.faces = fin.faces[np.r_[0:len(a.faces), len(a.faces) + 2:len(fin.faces)]]  # an open, non-manifold mess
    with pytest.raises(CurvsliceError, match="open boundary edges.*shared by more than two"):
        repair(fin)


@pytest.mark.parametrize("form", [["--up", "-y"], ["--up=-y"]])
def test_a_negative_up_axis_is_taken_with_or_without_the_equals_sign(tmp_path, form):
    """``--up -y`` failed in argparse ("expected one argument": a value starting with a dash reads as an
    option); both forms now place the part upside down about y: its old -y side on the platform."""
    model = tmp_path / "wedge.stl"
    trimesh.creation.box(extents=(10, 20, 6)).export(model)
    out = tmp_path / "o"
    assert main(["slice", str(model), *form, "--voxel", "2", "--stages", "field", "--quiet", "--no-verify",
                 "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["parameters"]["up"] == "-y"
    assert np.allclose(trimesh.load(out / "solid.stl").extents, (10, 6, 20))  # y (20 mm) now vertical
