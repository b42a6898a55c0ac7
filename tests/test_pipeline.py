"""The pipeline (issue 14): settings in one place, the library API, and resume that reuses exactly."""

from __future__ import annotations

import dataclasses
import filecmp
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import curvslice
from curvslice.cli import build_parser
from curvslice.cli.slice import settings_from_args
from curvslice.errors import CurvsliceError
from curvslice.pipeline import STAGE_NAMES, Settings, settings_of, stage_keys

ROOT = Path(__file__).resolve().parent.parent
TEE = ROOT / "models" / "tee.stl"


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "curvslice", *args], capture_output=True, text=True)


def _report(folder: Path) -> dict:
    return json.loads((folder / "report.json").read_text())


def _arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as f:
        return {k: f[k] for k in f.files}


def test_cli_defaults_are_the_settings_defaults() -> None:
    """No option given: the CLI's settings equal Settings() (the only place a default lives)."""
    args = build_parser("slice").parse_args(["slice", "x.stl"])
    assert settings_from_args(args, Settings()) == Settings()
    args = build_parser("slice").parse_args(["slice", "x.stl", "--max-tilt", "30", "--no-gap-passes", "--voxel", "2"])
    s = settings_from_args(args, Settings())
    assert s.max_tilt == pytest.approx(np.radians(30)) and s.gap_passes is False and s.voxel == 2.0


def test_stage_keys_change_from_the_first_changed_stage_on() -> None:
    base = stage_keys(TEE, Settings(voxel=2.0))
    assert stage_keys(TEE, Settings(voxel=2.0)) == base
    tp = stage_keys(TEE, Settings(voxel=2.0, path_width=2.0))
    assert [tp[s] == base[s] for s in STAGE_NAMES] == [True, True, False, False]
    seam = stage_keys(TEE, Settings(voxel=2.0, start_rule="seam"))  # and a folder of the other rule is not resumed
    assert [seam[s] == base[s] for s in STAGE_NAMES] == [True, True, False, False]
    vox = stage_keys(TEE, Settings(voxel=2.5))
    assert not any(vox[s] == base[s] for s in STAGE_NAMES)
    with pytest.raises(CurvsliceError, match="unknown setting"):
        Settings().replace(voxels=1.0)


def test_library_api_in_three_lines() -> None:
    s = curvslice.slice(TEE, curvslice.Settings(voxel=2.0), until="toolpaths")
    assert s.field.report["missed"] == 0 and len(s.layers) == s.field.report["layers"] > 0
    assert len(s.toolpaths.positions) == len(s.toolpaths.bead) > 0
    assert "robot" not in s.results


def test_resume_reuses_unchanged_stages_and_matches_a_fresh_run(tmp_path: Path) -> None:
    """Slice to tool-paths, resume with a robot: field, layers and tool-paths are reused (copied, not
    recomputed) and every file equals a fresh full run's, joints.csv included."""
    first, resumed, fresh = tmp_path / "first", tmp_path / "resumed", tmp_path / "fresh"
    assert _cli("slice", str(TEE), "--voxel", "2", "--stages", "toolpaths", "--quiet", "--out", str(first)).returncode == 0
    r = _cli("slice", "--resume", str(first), "--robot", "ur5", "--quiet", "--out", str(resumed))
    assert r.returncode == 0, r.stderr
    rep = _report(resumed)
    assert rep["reused"] == ["field", "layers", "toolpaths"] and rep["stages"][-1] == "robot"
    assert set(rep["timings_s"]) == {"robot", "robot_graph", "robot_trajectory", "total"}
    assert _cli("slice", str(TEE), "--voxel", "2", "--robot", "ur5", "--quiet", "--out", str(fresh)).returncode == 0
    for name in ("field.npz", "toolpaths.npz"):
        a, b = _arrays(fresh / name), _arrays(resumed / name)
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    for name in ("joints.csv", "toolpaths.gcode", "curvslice_001.script", "layers/layer_0005.ply"):
        assert filecmp.cmp(fresh / name, resumed / name, shallow=False), name
    assert settings_of(resumed) == settings_of(fresh)
    # resuming into the same folder replaces it only with --force
    r = _cli("slice", "--resume", str(first), "--path-width", "2.2", "--quiet")
    assert r.returncode == 2 and "--force" in r.stderr
    r = _cli("slice", "--resume", str(first), "--voxel", "3", "--quiet", "--force", "--no-verify")
    assert r.returncode == 0, r.stderr
    rep = _report(first)
    assert rep["reused"] == [] and rep["parameters"]["voxel"] == 3.0
    assert dataclasses.asdict(settings_of(first))["voxel"] == 3.0


def test_the_robot_stage_key_follows_the_workcell_content(tmp_path: Path) -> None:
    """Resuming after the workcell file was edited recomputes the robot stage (its key holds the
    workcell's content, not only the file's name); the slicing stages keep theirs."""
    from curvslice.workcell import load_workcell, workcell_to_dict

    path = tmp_path / "cell.json"
    spec = workcell_to_dict(load_workcell("ur5"))
    path.write_text(json.dumps(spec))
    before = stage_keys(TEE, curvslice.Settings(voxel=2.0, robot=str(path)))
    path.write_text(json.dumps({**spec, "axis_smoothing_mm": 1.0}))
    after = stage_keys(TEE, curvslice.Settings(voxel=2.0, robot=str(path)))
    assert before["robot"] != after["robot"]
    assert all(before[k] == after[k] for k in ("field", "layers", "toolpaths"))


@pytest.mark.parametrize("option, value", [("--voxel", "inf"), ("--size", "inf"), ("--memory-limit", "nan"),
                                           ("--path-width", "0"), ("--rotations", "0"), ("--eps", "-1"),
                                           ("--voxel", "1e6"), ("--layer-height", "1e6"), ("--max-tilt", "95"),
                                           ("--robot", "no_such_cell.json")])
def test_bad_settings_are_one_line_before_any_work(tmp_path: Path, option: str, value: str) -> None:
    r = _cli("slice", str(TEE), option, value, "--out", str(tmp_path / "o"))
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "o").exists() and not list(tmp_path.iterdir())


def test_settings_validate_in_the_library_too() -> None:
    for bad in (dict(voxel=float("nan")), dict(path_width=0.1, voxel=1.0), dict(rotations=8, max_rotations=4),
                dict(delta_f=0), dict(method="greedy")):
        with pytest.raises(CurvsliceError, match="setting"):
            Settings(**bad)


def test_a_failing_result_is_a_non_zero_exit(tmp_path: Path) -> None:
    """A cube floating 10 mm above another cannot be reached support-free: most of its voxels are missed,
    and `slice` says which check failed instead of exiting 0 (issue 15)."""
    import trimesh

    body = trimesh.util.concatenate([trimesh.creation.box((12, 12, 6)).apply_translation((0, 0, 3)),
                                     trimesh.creation.box((8, 8, 6)).apply_translation((0, 0, 19))])
    model = tmp_path / "floating.stl"
    body.export(model)
    r = _cli("slice", str(model), "--voxel", "1.5", "--stages", "field", "--quiet", "--out", str(tmp_path / "f"))
    assert r.returncode == 1 and "missed voxels" in r.stderr, r.stderr
    assert (tmp_path / "f" / "field.npz").exists()  # the folder is kept for inspection


def test_the_default_run_with_a_preview_verifies_clean(tmp_path: Path) -> None:
    """The README's main command on the tee: all stages (the robot one skipped without --robot), a preview,
    and the automatic verify passes — the skipped stage promises no files and the PNG is a PNG."""
    out = tmp_path / "tee"
    r = _cli("slice", str(TEE), "--voxel", "2", "--preview", "--quiet", "--out", str(out))
    assert r.returncode == 0, r.stderr
    rep = _report(out)
    assert rep["stages"] == ["field", "layers", "toolpaths"] and rep["robot"].startswith("skipped")
    assert "preview.png" in rep["files"]
