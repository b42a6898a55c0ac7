"""Workcell files and the frames of Eq. 2.3 / Eq. 4.3, and the robot-stage artefacts end to end
(planned, written, then re-checked by ``curvslice.verify.robot`` from the files alone)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from curvslice.collision import CollisionScene
from curvslice.errors import CurvsliceError
from curvslice.exporters.joints_csv import read_joints_csv, write_robot_outputs
from curvslice.kinematics import ROBOT_NAMES, load_robot
from curvslice.jerk import trajectory_stage
from curvslice.motion import plan_print
from curvslice.verify import robot as verify_robot
from curvslice.workcell import (
    deposition_frames,
    flange_poses,
    load_workcell,
    rotation_samples,
    save_workcell,
    waypoints_from_flange,
    workcell_from_dict,
    workcell_to_dict,
)


@pytest.mark.parametrize("name", ROBOT_NAMES)
def test_shipped_workcells_round_trip(name, tmp_path):
    cell = load_workcell(name)
    assert cell.robot == name and cell.rotations == 30 and cell.max_joint_speed == 1.0
    save_workcell(cell, tmp_path / "w.json")
    again = load_workcell(tmp_path / "w.json")
    assert np.allclose(again.nozzle, cell.nozzle) and np.allclose(again.platform_mount, cell.platform_mount)
    assert workcell_to_dict(again) == workcell_to_dict(cell)
    assert [b.name for b in again.extruder + again.obstacles] == [b.name for b in cell.extruder + cell.obstacles]


def test_flange_poses_satisfy_eq_2_3():
    cell = load_workcell("ur5")
    rng = np.random.default_rng(0)
    c = rng.normal(size=(20, 3)) * 20
    t = rng.normal(size=(20, 3))
    t[:, 2] = np.abs(t[:, 2]) + 0.1
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    p = 7
    T_EB = flange_poses(cell, c, t, p)
    T_OP = deposition_frames(c, t, rotation_samples(p))
    lhs = T_EB @ cell.platform_mount @ T_OP  # T_E^B T_P^E T_O^P
    assert np.abs(lhs - cell.nozzle).max() < 1e-9
    pos, axis = waypoints_from_flange(cell, T_EB)
    assert np.abs(pos - c[:, None]).max() < 1e-9 and np.abs(axis - t[:, None]).max() < 1e-12
    # the p frames differ only by the rotation θ about t (Eq. 4.3): same z, x turned by 2π/p
    x = T_OP[..., :3, 0]
    cos = np.einsum("npi,npi->np", x[:, 1:], x[:, :-1])
    assert np.allclose(cos, np.cos(2 * np.pi / p))


@pytest.mark.parametrize(
    "patch, message",
    [
        ({"robot": "kuka"}, "robot"),
        ({"nozzle": None}, "nozzle"),
        ({"rotations": 0}, "rotations"),
        ({"extruder": [{"name": "x", "type": "sphere"}]}, "type"),
        ({"joint_limits_deg": {"lower": [0] * 6, "upper": [0] * 6}}, "lower"),
        ({"max_axis_deviation_deg": 95}, "max_axis_deviation_deg"),
        ({"axis_deviation_step_deg": 0}, "axis_deviation_step"),
    ],
)
def test_bad_workcells_are_user_errors(patch, message):
    spec = workcell_to_dict(load_workcell("ur5"))
    spec.update(patch)
    if patch.get("nozzle", 1) is None:
        del spec["nozzle"]
    with pytest.raises(CurvsliceError, match=message):
        workcell_from_dict(spec)


def test_shipped_nozzle_cone_has_its_apex_at_the_tip():
    import fcl

    from curvslice.collision import CollisionScene

    cell = load_workcell("ur5")
    scene = CollisionScene(load_robot("ur5"), cell)
    cone = next(s for s in scene.static if s.name == "nozzle")

    def touches(p_nozzle):
        p = cell.nozzle @ np.r_[p_nozzle, 1.0]
        probe = fcl.CollisionObject(fcl.Sphere(0.01), fcl.Transform(np.eye(3), p[:3]))
        return fcl.collide(cone.obj, probe, fcl.CollisionRequest(), fcl.CollisionResult()) > 0

    assert not touches([0, 0, 0.2])  # the deposition point itself stays free
    assert touches([0, 0, 1.0]) and touches([3.5, 0, 5.2])
    assert not touches([3.5, 0, 2.0])  # outside the cone near the tip


def test_unreadable_workcell_file(tmp_path):
    bad = tmp_path / "cell.json"
    bad.write_text("{not json")
    with pytest.raises(CurvsliceError, match="JSON"):
        load_workcell(bad)
    with pytest.raises(CurvsliceError, match="neither"):
        load_workcell(tmp_path / "missing.json")


def _synthetic_slice(outdir, m_per_layer=80):
    """Two dome 'layers' of oriented waypoints (three paths) and their surfaces."""
    rows = []
    for layer, radius in ((1, 30.0), (2, 32.0)):
        s = np.linspace(0, 1, m_per_layer)
        pol = np.radians(45) * (1 - s)
        az = 2 * np.pi * 2 * s
        t = np.stack([np.sin(pol) * np.cos(az), np.sin(pol) * np.sin(az), np.cos(pol)], 1)
        path = np.where(s < 0.5, 2 * layer - 1, 2 * layer)
        rows.append((radius * t, t, np.full(m_per_layer, layer), path))
    pos = np.vstack([r[0] for r in rows])
    nor = np.vstack([r[1] for r in rows])
    layer = np.concatenate([r[2] for r in rows]).astype(np.int32)
    path = np.concatenate([r[3] for r in rows]).astype(np.int32)
    first = np.r_[True, path[1:] != path[:-1]]
    ext = np.where(first, 0.0, 0.05)
    tp = dict(positions=pos, normals=nor, layer=layer, path=path, extrusion=ext,
              thickness=np.full(len(pos), 0.8), feed=np.full(len(pos), 600.0))
    np.savez(outdir / "toolpaths.npz", **tp)
    (outdir / "layers").mkdir()
    for k, radius in enumerate((28.0, 30.0), start=1):
        cap = trimesh.creation.icosphere(2, radius)
        cap.update_faces(cap.triangles_center[:, 2] > 5)
        cap.remove_unreferenced_vertices()
        cap.export(outdir / "layers" / f"layer_{k:04d}.ply")
    return tp


@pytest.mark.parametrize("name", ["ur5", "irb120"])
def test_robot_stage_files_pass_the_verifier(name, tmp_path):
    tp = _synthetic_slice(tmp_path)
    cell = load_workcell(name)
    robot = load_robot(name)
    scene = CollisionScene(robot, cell)
    layers = [trimesh.load(p) for p in sorted((tmp_path / "layers").glob("*.ply"))]
    motion = plan_print(robot, cell, tp, lambda layer: scene.for_layer(layers, layer))
    motion, _ = trajectory_stage(robot, cell, tp, motion, "jerk", lambda layer: scene.for_layer(layers, layer))
    write_robot_outputs(tmp_path, cell, robot.family, tp, motion)
    results = verify_robot.checks(tmp_path)
    failed = [c for c in results if not c.passed]
    assert not failed, failed
    names = {c.name for c in results}
    assert ("URScript program matches joints.csv" in names) == (name == "ur5")
    assert ("RAPID program matches joints.csv" in names) == (name == "irb120")
    rows = read_joints_csv(tmp_path / "joints.csv")
    assert np.array_equal(rows["index"], np.arange(len(tp["positions"])))
    assert json.loads((tmp_path / "workcell.json").read_text())["robot"] == name


def test_verifier_catches_a_wrong_joint_row(tmp_path):
    tp = _synthetic_slice(tmp_path, 30)
    cell, robot = load_workcell("ur5"), load_robot("ur5")
    motion = plan_print(robot, cell, tp)
    motion.q[10, 0] += 0.01  # one row no longer reaches its waypoint, and jumps
    write_robot_outputs(tmp_path, cell, robot.family, tp, motion)
    failed = {c.name for c in verify_robot.checks(tmp_path) if not c.passed}
    assert "FK reproduces waypoint position" in failed


def test_cli_rejects_an_unknown_robot_while_parsing(tmp_path, capsys):
    from curvslice.cli import main

    assert main(["slice", str(tmp_path / "part.stl"), "--robot", "kuka"]) == 2
    err = capsys.readouterr().err
    assert "--robot" in err and "kuka" in err and "Traceback" not in err


def test_slice_cli_robot_stage_verifies(tmp_path):
    """`curvslice slice tee.stl --robot ur5 --stages robot` on a coarse grid, re-checked by verify."""
    from pathlib import Path

    from curvslice.cli import main

    model = Path(__file__).resolve().parents[1] / "models" / "tee.stl"
    out = tmp_path / "tee"
    assert main(["slice", str(model), "--voxel", "3", "--out", str(out), "--stages", "robot", "--robot", "ur5", "--no-verify",
                 "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())["robot"]
    assert report["rows"] + report["skipped"] == report["waypoints"] > 0
    assert report["ik_solutions_per_waypoint_min"] > 0 and report["max_joint_step_rad"] > 0
    results = {c.name: c for c in verify_robot.checks(out)}
    for name in ("FK reproduces waypoint position", "FK reproduces nozzle axis", "joint limits",
                 "joint speed within segments", "no collision at any row", "URScript program matches joints.csv"):
        assert results[name].passed, results[name]


def test_deviated_axes_are_recorded_and_bounded_in_the_files(tmp_path):
    """Near the platform: 30° waypoints print as planned, 55° ones only tilted back (the heater block
    would dip under z = 0), one at 80° cannot be printed within the 20° bound. joints.csv carries the
    realized axes; the verifier re-checks them against FK and the bound, and still fails the
    unrealizable waypoint."""
    tilt = np.r_[np.full(12, 30.0), np.full(3, 55.0), 80.0, np.full(8, 30.0)]
    a = np.radians(tilt)
    n = len(a)
    pos = np.stack([np.linspace(-6, 6, n), np.zeros(n), np.where(tilt > 30, 1.0, 3.0)], 1)
    nor = np.stack([np.sin(a), np.zeros(n), np.cos(a)], 1)
    ext = np.r_[0.0, np.full(n - 1, 0.05)]
    tp = dict(positions=pos, normals=nor, layer=np.ones(n, np.int32), path=np.ones(n, np.int32), extrusion=ext,
              thickness=np.full(n, 0.8), feed=np.full(n, 600.0))
    np.savez(tmp_path / "toolpaths.npz", **tp)
    cell, robot = replace(load_workcell("ur5"), axis_smoothing=0.0), load_robot("ur5")  # collision tilts alone
    scene = CollisionScene(robot, cell)
    motion = plan_print(robot, cell, tp, lambda layer: scene.collisions)
    write_robot_outputs(tmp_path, cell, robot.family, tp, motion)
    rows = read_joints_csv(tmp_path / "joints.csv")
    assert 15 not in rows["index"]  # the 80° waypoint is unrealizable
    moved = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", rows["normals"], nor[rows["index"]]), -1, 1)))
    assert set(rows["index"][moved > 1e-6]) == {12, 13, 14}
    assert moved.max() <= 20 + 1e-9
    assert np.allclose(np.degrees(motion.deviation), moved, atol=1e-6)
    results = {c.name: c for c in verify_robot.checks(tmp_path)}
    for name in ("axis deviation within bound", "FK reproduces nozzle axis", "FK reproduces waypoint position",
                 "no collision at any row", "joint speed within segments"):
        assert results[name].passed, results[name]
    assert not results["waypoints realized"].passed  # not listed in a report
    listed = {"robot": {"layers": [{"skipped_rows": [{"row": 15, "reason": "all poses collide"}]}]}}
    (tmp_path / "report.json").write_text(json.dumps(listed))
    realized = {c.name: c for c in verify_robot.checks(tmp_path)}["waypoints realized"]
    assert realized.passed and realized.detail.startswith("1 listed in report.json with a reason, 1 confirmed")
    spec = json.loads((tmp_path / "workcell.json").read_text())
    spec["max_axis_deviation_deg"] = float(moved.max()) / 2  # a tighter bound than realized: caught
    (tmp_path / "workcell.json").write_text(json.dumps(spec))
    assert not {c.name: c for c in verify_robot.checks(tmp_path)}["axis deviation within bound"].passed


def test_the_verifier_carries_the_layers_exactly_as_the_planner_did(tmp_path):
    """The PLY files round vertices to float32 (µm on a part of 100 mm), which flips a grazing contact; the
    robot checks read the exact saved arrays (layers.npz), the planner's own geometry."""
    from curvslice.verify.robot import _layer_meshes
    from curvslice.working_surfaces import write_layers

    layer = trimesh.creation.icosphere(subdivisions=2, radius=37.123456789)
    layer.vertices += [51.987654321, -43.21, 12.345]
    write_layers(tmp_path, [layer])
    ply = trimesh.load(tmp_path / "layers" / "layer_0001.ply", force="mesh")
    assert np.abs(ply.vertices - layer.vertices).max() > 1e-7  # the PLY is not exact ...
    carried = _layer_meshes(tmp_path)
    assert len(carried) == 1 and np.array_equal(carried[0].vertices, layer.vertices)  # ... the verifier's layers are
    assert np.array_equal(carried[0].faces, layer.faces)
