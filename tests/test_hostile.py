"""Hostile-input corpus for convert, level, drape, view, verify and the writers (issue 15).

Every case is generated here (small files in tmp_path). A refused case must exit non-zero with one
line on stderr, no traceback, no output file and its inputs unchanged; an accepted case is checked
by reading its result back. ``CASES`` lists the refusals by category.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
from pathlib import Path

import ezdxf
import numpy as np
import pytest

from curvslice import cli
from curvslice.cell.gcode import parse_gcode
from curvslice.errors import CurvsliceError
from curvslice.exporters.gcode6 import read_gcode6, write_gcode6
from curvslice.exporters.joints_csv import write_joints_csv
from curvslice.outdir import atomic_files, output_lock
from curvslice.viz import open_viewer

MODELS = Path(__file__).resolve().parents[1] / "models"
GCODE = "G21\nG90\nM82\nG92 E0\nG1 Z0.2 F3000\nG1 X10 Y10 E1 F1200\nG1 X20 Y10 E2\n"


def checksummed(line: str) -> str:
    """``line*cs`` with the RepRap checksum (XOR of the bytes before ``*``)."""
    cs = 0
    for byte in line.encode():
        cs ^= byte
    return f"{line}*{cs}"


def dxf(path: Path, radius: float = 10.0) -> Path:
    doc = ezdxf.new()
    doc.modelspace().add_circle((0, 0), radius)
    doc.saveas(path)
    return path


def workcell(folder: Path, **changes) -> Path:
    """The shipped UR5 workcell with ``changes``, as a JSON file (NaN written as JSON's NaN)."""
    from curvslice.workcell import load_workcell, workcell_to_dict

    spec = {**workcell_to_dict(load_workcell("ur5")), **changes}
    return write(folder / "wc.json", json.dumps(spec))


def write(path: Path, content: str | bytes) -> Path:
    (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    return path


def run(argv: list[str], capsys) -> tuple[int, str, str]:
    """Exit code, stderr and stdout of ``curvslice ARGV`` (argparse errors exit through SystemExit)."""
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.err, captured.out


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# Each case: (category, id, function(tmp) -> argv, text the error line must contain).
CASES = [
    # ---- options: non-finite, out of range, wrong type, paths in names
    ("option", "convert-offset-nan", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--offset", "nan", "0", "0"], "--offset"),
    ("option", "convert-offset-inf", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--offset", "0", "inf", "0"], "mm"),
    ("option", "convert-offset-400-digits", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--offset", "1" * 400, "0", "0"], "--offset"),
    ("option", "convert-level-reference-nan", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--level-reference", "nan"], "mm"),
    ("option", "convert-name-escapes-out", lambda d: ["convert", d / "ok.gcode", "--to", "gcode6", "--out", d / "o", "--name", "../../x"], "--name"),
    ("option", "convert-name-empty", lambda d: ["convert", d / "ok.gcode", "--to", "gcode6", "--name", ""], "--name"),
    ("option", "convert-unknown-target", lambda d: ["convert", d / "ok.gcode", "--to", "kuka"], "--to"),
    ("option", "drape-step-nan", lambda d: ["drape", d / "c.dxf", "--surface", "brooks", "--step", "nan"], "--step"),
    ("option", "drape-step-zero", lambda d: ["drape", d / "c.dxf", "--surface", "brooks", "--step", "0"], "> 0"),
    ("option", "drape-print-speed-negative", lambda d: ["drape", d / "c.dxf", "--surface", "brooks", "--print-speed", "-5"], "mm/s"),
    ("option", "drape-travel-speed-nan", lambda d: ["drape", d / "c.dxf", "--surface", "brooks", "--travel-speed", "nan"], "mm/s"),
    ("option", "drape-fill-spacing-zero", lambda d: ["drape", d / "c.dxf", "--surface", "brooks", "--fill-spacing", "0"], "--fill-spacing"),
    ("option", "drape-diameter-inf", lambda d: ["drape", d / "c.dxf", "--surface", "brooks", "--diameter", "inf"], "--diameter"),
    ("option", "drape-fill-angle-text", lambda d: ["drape", d / "c.dxf", "--surface", "brooks", "--fill-angle", "ten"], "not a number"),
    ("option", "drape-surface-poly-nan", lambda d: ["drape", d / "c.dxf", "--surface", "poly:nan,1", "--out", d / "o"], "finite"),
    ("option", "drape-surface-poly-text", lambda d: ["drape", d / "c.dxf", "--surface", "poly:a,b", "--out", d / "o"], "coefficients"),
    ("option", "level-xs-inf", lambda d: ["level", "routine", "--xs", "0", "inf", "3", "--ys", "0", "10", "3", "--out", d / "o"], "--xs"),
    ("option", "level-count-fraction", lambda d: ["level", "routine", "--xs", "0", "10", "2.5", "--ys", "0", "10", "3", "--out", d / "o"], "COUNT"),
    ("option", "level-probe-offset-nan", lambda d: ["level", "routine", "--xs", "0", "10", "3", "--ys", "0", "10", "3", "--probe-offset", "nan", "0", "0"], "--probe-offset"),
    ("option", "level-signal-not-identifier", lambda d: ["level", "routine", "--xs", "0", "10", "3", "--ys", "0", "10", "3", "--signal", "a b"], "--signal"),
    ("option", "view-glyph-stride-zero", lambda d: ["view", d, "--glyph-stride", "0"], "--glyph-stride"),
    ("option", "view-zmq-url-not-tcp", lambda d: ["view", d, "--zmq-url", "localhost"], "--zmq-url"),
    # ---- files: missing, binary, malformed, hostile numbers, bad JSON keys
    ("file", "gcode-missing", lambda d: ["convert", d / "nope.gcode", "--to", "rapid"], "not an existing file"),
    ("file", "gcode-binary", lambda d: ["convert", write(d / "b.gcode", b"G1 X1\0\xff\xfe"), "--to", "rapid", "--out", d / "o"], "binary"),
    ("file", "gcode-400-digits", lambda d: ["convert", write(d / "n.gcode", f"G1 X1{'0' * 400} Y1 F100\n"), "--to", "rapid", "--out", d / "o"], "out of range"),
    ("file", "gcode-2e9-mm", lambda d: ["convert", write(d / "n.gcode", "G1 X2000000000 F100\n"), "--to", "rapid", "--out", d / "o"], "out of range"),
    ("file", "gcode-wrong-checksum", lambda d: ["convert", write(d / "c.gcode", "N1 G1 X5 Y5 F600*1\n"), "--to", "rapid", "--out", d / "o"], "checksum"),
    ("file", "gcode-unknown-command", lambda d: ["convert", write(d / "u.gcode", "G1 X1 F100\nG2 X5 Y5 I1 J1\n"), "--to", "rapid", "--out", d / "o"], "G2"),
    ("file", "gcode-negative-feed", lambda d: ["convert", write(d / "f.gcode", "G1 X1 F-300\n"), "--to", "rapid", "--out", d / "o"], "feed"),
    ("file", "gcode-no-moves", lambda d: ["convert", write(d / "e.gcode", "; nothing\nM104 S200\n"), "--to", "rapid", "--out", d / "o"], "no moves"),
    ("file", "probe-csv-binary", lambda d: ["level", "report", write(d / "p.csv", b"\x00\x01\x02x,y,z")], "binary"),
    ("file", "probe-csv-nan", lambda d: ["level", "report", write(d / "p.csv", "x,y,z\n0,0,0\n1,0,nan\n0,1,0\n1,1,0\n")], "finite"),
    ("file", "probe-csv-holes", lambda d: ["level", "report", write(d / "p.csv", "0,0,0\n1,0,0\n0,1,0\n")], "missing"),
    ("file", "cell-nan-speed", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--out", d / "o", "--cell", write(d / "c.json", '{"max_speed": NaN}')], "max_speed"),
    ("file", "cell-string-speed", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--out", d / "o", "--cell", write(d / "c.json", '{"max_speed": "fast"}')], "max_speed"),
    ("file", "cell-short-offset", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--out", d / "o", "--cell", write(d / "c.json", '{"offset": [1, 2]}')], "offset"),
    ("file", "cell-nested-negative", lambda d: ["convert", d / "ok.gcode", "--to", "urscript", "--out", d / "o", "--cell", write(d / "c.json", '{"urscript": {"acceleration": -1}}')], "urscript.acceleration"),
    ("file", "cell-bool-for-number", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--out", d / "o", "--cell", write(d / "c.json", '{"rapid": {"max_targets": true}}')], "rapid.max_targets"),
    ("file", "cell-unknown-key", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--out", d / "o", "--cell", write(d / "c.json", '{"speed": 5}')], "unknown key"),
    ("file", "cell-not-json", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--out", d / "o", "--cell", write(d / "c.json", "{max_speed: 5")], "not valid JSON"),
    ("file", "cell-array", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--out", d / "o", "--cell", write(d / "c.json", "[1, 2]")], "JSON object"),
    ("file", "workcell-nan-speed", lambda d: ["slice", MODELS / "tee.stl", "--out", d / "s", "--robot", workcell(d, max_joint_speed_rad_s=float("nan"))], "max_joint_speed_rad_s"),
    ("file", "workcell-text-speed", lambda d: ["slice", MODELS / "tee.stl", "--out", d / "s", "--robot", workcell(d, linear_speed_mm_s="fast")], "linear_speed_mm_s"),
    ("file", "workcell-fractional-rotations", lambda d: ["slice", MODELS / "tee.stl", "--out", d / "s", "--robot", workcell(d, rotations=2.5)], "rotations"),
    ("file", "workcell-nozzle-nan", lambda d: ["slice", MODELS / "tee.stl", "--out", d / "s", "--robot", workcell(d, nozzle={"xyz_mm": [0, 0, float("nan")], "rpy_deg": [0, 0, 0]})], "xyz_mm"),
    ("file", "view-incomplete-field", lambda d: ["view", d, "--zmq-url", "tcp://127.0.0.1:1"], "damaged"),
    ("file", "view-corrupt-field", lambda d: ["view", write(d / "field.npz", b"PK\x03\x04broken").parent, "--zmq-url", "tcp://127.0.0.1:1"], "damaged"),
    ("file", "dxf-garbage", lambda d: ["drape", write(d / "g.dxf", "not a dxf"), "--surface", "brooks", "--out", d / "o"], "DXF"),
    # ---- resources: the guard names the number
    ("resource", "drape-step-1e-6", lambda d: ["drape", d / "c.dxf", "--surface", "brooks", "--out", d / "o", "--step", "1e-6"], "needed"),
    ("resource", "drape-circle-radius-1e9", lambda d: ["drape", dxf(d / "huge.dxf", 1e9), "--surface", "brooks", "--out", d / "o"], "needed"),
    ("resource", "level-1e5-by-1e5", lambda d: ["level", "routine", "--xs", "0", "100", "1e5", "--ys", "0", "100", "1e5", "--out", d / "o"], "needed"),
    ("resource", "level-grid-product", lambda d: ["level", "routine", "--xs", "0", "100", "200", "--ys", "0", "100", "200", "--out", d / "o"], "4e+04 needed"),
    # ---- outputs: never over an input, never outside --out, never into a file
    ("output", "convert-over-own-input", lambda d: ["convert", d / "ok.gcode", "--to", "gcode6", "--out", d], "overwrite the input"),
    ("output", "convert-out-is-a-file", lambda d: ["convert", d / "ok.gcode", "--to", "rapid", "--out", d / "ok.gcode"], "is a file"),
    ("output", "view-html-over-field", lambda d: ["view", d, "--html", d / "field.npz"], ".html"),
    ("output", "view-html-is-a-folder", lambda d: ["view", d, "--html", d], ".html"),
    ("output", "view-html-inside-the-folder", lambda d: ["view", d, "--html", d / "scene.html"], "inside the slice folder"),
]


@pytest.mark.parametrize("category,case,argv,expected", CASES, ids=[c[1] for c in CASES])
def test_refused_with_one_line_and_nothing_written(tmp_path, capsys, category, case, argv, expected):
    write(tmp_path / "ok.gcode", GCODE)
    dxf(tmp_path / "c.dxf")
    np.savez(tmp_path / "field.npz", occupied=np.zeros((1, 1, 1), bool))
    args = argv(tmp_path)
    before = snapshot(tmp_path)
    code, err, _ = run(args, capsys)
    assert code != 0, f"{case} was accepted"
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert expected in lines[0], lines[0]
    assert snapshot(tmp_path) == before, "a refused command changed or added files"


def test_corpus_covers_every_category():
    counts = {c: sum(1 for k, *_ in CASES if k == c) for c in ("option", "file", "resource", "output")}
    assert min(counts.values()) >= 4, counts


# ------------------------------------------------------------------ accepted, with the result checked


def test_bom_paren_semicolon_and_valid_checksum_are_read(tmp_path, capsys):
    text = "\ufeffG21 (units; mm)\n" + checksummed("N1 G1 X5 Y6 Z0.2 F600") + " ; ok\nG1 X7 Y6 E1 (a;b)\n"
    src = write(tmp_path / "in.gcode", text.encode("utf-8"))
    assert run(["convert", src, "--to", "gcode6", "--out", tmp_path / "o"], capsys)[0] == 0
    back = read_gcode6(tmp_path / "o" / "in.gcode")
    assert np.allclose(back["positions"], [[5, 6, 0.2], [7, 6, 0.2]])
    assert src.read_bytes() == text.encode("utf-8")


def test_probe_grid_with_jitter_is_one_lattice(tmp_path, capsys):
    rng = np.random.default_rng(1)
    xs, ys = np.meshgrid([0.0, 50.0, 100.0], [0.0, 40.0])
    z = 0.01 * xs + 0.02 * ys
    pts = np.column_stack([xs.ravel(), ys.ravel(), z.ravel()])
    pts[:, :2] += rng.uniform(-1e-4, 1e-4, (len(pts), 2))
    csv = write(tmp_path / "p.csv", "x,y,z\n" + "\n".join(",".join(f"{v:.6f}" for v in p) for p in pts) + "\n")
    code, err, _ = run(["level", "report", csv], capsys)
    assert code == 0, err
    from curvslice.cell.levelling import read_probe_csv

    hmap = read_probe_csv(csv)
    assert hmap.z.shape == (2, 3) and np.allclose(hmap.height(np.array([25.0]), np.array([20.0])), 0.25 + 0.4, atol=1e-3)


def test_huge_dxf_scaled_by_diameter_is_draped_within_it(tmp_path, capsys):
    src = dxf(tmp_path / "huge.dxf", 1e9)
    assert run(["drape", src, "--surface", "brooks", "--out", tmp_path / "o", "--diameter", "40"], capsys)[0] == 0
    with np.load(tmp_path / "o" / "drape.npz") as z:
        r = np.hypot(z["points"][:, 0], z["points"][:, 1])
        assert np.isfinite(z["points"]).all() and r.max() <= 20 + 1e-6 and r.max() > 19.9


def test_infinite_workspace_in_a_cell_file_is_accepted(tmp_path, capsys):
    cell = write(tmp_path / "c.json", '{"workspace_max": [Infinity, 1000, 1000]}')
    src = write(tmp_path / "ok.gcode", GCODE)
    assert run(["convert", src, "--to", "urscript", "--out", tmp_path / "o", "--cell", cell], capsys)[0] == 0
    assert (tmp_path / "o" / "ok_001.script").is_file()


# ------------------------------------------------------------------ writers refuse non-finite values


def test_every_writer_refuses_non_finite_values(tmp_path):
    from curvslice.cell.cells import Syringe, load_cell, robot_path
    from curvslice.exporters.arduino import write_accelstepper_sketch
    from curvslice.exporters.rapid import write_probe_routine, write_rapid, write_rapid_joints
    from curvslice.exporters.urscript import write_urscript, write_urscript_joints
    from curvslice.exporters.vplus import write_vplus

    cell = load_cell("generic")
    robot, _ = robot_path(parse_gcode(GCODE), cell)
    robot.positions[1, 2] = np.nan
    q, t = np.zeros((3, 6)), np.arange(3.0)
    q[2, 4] = np.inf
    n = np.zeros((3, 3))
    writers = {
        "rapid": lambda: write_rapid(tmp_path, robot, cell.rapid, name="p"),
        "urscript": lambda: write_urscript(tmp_path, robot, cell.urscript, name="p"),
        "vplus": lambda: write_vplus(tmp_path / "p.v2", robot, [(0, 10.0)], cell.vplus, program="p"),
        "gcode6": lambda: write_gcode6(tmp_path / "p.gcode", robot.positions, n, np.zeros(3), np.ones(3), np.zeros(3), np.zeros(3)),
        "joints-csv": lambda: write_joints_csv(tmp_path / "j.csv", layer=np.zeros(3), path_id=np.zeros(3), index=np.arange(3),
                                               t=t, positions=n, normals=n, q=q, segment=np.zeros(3), extruding=np.zeros(3)),
        "rapid-joints": lambda: write_rapid_joints(tmp_path, q, t),
        "urscript-joints": lambda: write_urscript_joints(tmp_path, q, t),
        "arduino": lambda: write_accelstepper_sketch(tmp_path / "s.ino", [(0, float("nan"))], 1, Syringe()),
        "probe-routine": lambda: write_probe_routine(tmp_path / "b.mod", np.array([0.0, np.inf]), np.array([0.0, 1.0])),
    }
    for name, writer in writers.items():
        with pytest.raises(CurvsliceError, match="non-finite|NaN"):
            writer()
    assert not list(tmp_path.iterdir()), "a writer left a file after refusing"
    robot.positions[1, 2] = 0.0
    robot.speed[0] = -5.0
    with pytest.raises(CurvsliceError, match="not positive"):
        write_rapid(tmp_path, robot, cell.rapid, name="p")


# ------------------------------------------------------------------ atomic outputs, signals, locks


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_signal_mid_write_leaves_nothing_and_exits_128_plus_signal(tmp_path, capsys, monkeypatch, signum):
    from curvslice.cli import convert

    real = convert.write_targets

    def interrupted(robot, cell, targets, out, name, source):
        written = real(robot, cell, targets, out, name, source)
        assert written and all(p.is_file() for p in written)  # the set is half done when the signal comes
        os.kill(os.getpid(), signum)
        raise AssertionError("the signal did not interrupt")

    monkeypatch.setattr(convert, "write_targets", interrupted)
    src = write(tmp_path / "ok.gcode", GCODE)
    (tmp_path / "o").mkdir()
    # a job started in the background (nohup, some CI runners) inherits SIGINT ignored, and Python then keeps it so;
    # the Ctrl-C of a terminal reaches Python's own handler, which is what this checks
    previous = signal.signal(signal.SIGINT, signal.default_int_handler) if signum == signal.SIGINT else None
    try:
        code, err, _ = run(["convert", src, "--to", "rapid", "--to", "urscript", "--out", tmp_path / "o"], capsys)
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    assert code == 128 + signum and "interrupted" in err
    assert not list((tmp_path / "o").iterdir())


def test_an_error_mid_write_leaves_the_earlier_set_untouched(tmp_path, capsys, monkeypatch):
    src = write(tmp_path / "ok.gcode", GCODE)
    assert run(["convert", src, "--to", "rapid", "--out", tmp_path / "o"], capsys)[0] == 0
    before = snapshot(tmp_path / "o")
    from curvslice.cli import convert

    def broken(*args, **kwargs):
        raise CurvsliceError("disk full (simulated)")

    monkeypatch.setattr(convert, "write_urscript", broken)
    assert run(["convert", src, "--to", "rapid", "--to", "urscript", "--out", tmp_path / "o"], capsys)[0] == 2
    assert snapshot(tmp_path / "o") == before


def test_a_second_run_on_a_locked_out_fails_at_once(tmp_path, capsys):
    src = write(tmp_path / "ok.gcode", GCODE)
    out = tmp_path / "o"
    with atomic_files(out) as tmp:  # a first run still writing
        (tmp / "first.txt").write_text("1")
        code, err, _ = run(["convert", src, "--to", "rapid", "--out", out], capsys)
        assert code == 2 and "another curvslice run" in err
    assert sorted(p.name for p in out.iterdir()) == ["first.txt"]
    with output_lock(tmp_path / ".x.lock", tmp_path / "x"):
        with pytest.raises(CurvsliceError, match="another curvslice run"):
            with output_lock(tmp_path / ".x.lock", tmp_path / "x"):
                pass
    assert not (tmp_path / ".x.lock").exists()


def test_two_slice_folders_on_one_out_cannot_both_win(tmp_path):
    from curvslice.outdir import atomic_folder

    with atomic_folder(tmp_path / "o") as first:
        (first / "report.json").write_text("{}")
        with pytest.raises(CurvsliceError, match="another curvslice run"):
            with atomic_folder(tmp_path / "o"):
                pass
    assert (tmp_path / "o" / "report.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]  # no lock or partial left behind


def test_stale_split_files_go_with_a_new_shorter_program(tmp_path, capsys):
    src = write(tmp_path / "ok.gcode", GCODE)
    out = tmp_path / "o"
    out.mkdir()
    (out / "ok_mod7.mod").write_text("old part")
    (out / "keep.txt").write_text("not ours")
    assert run(["convert", src, "--to", "rapid", "--out", out], capsys)[0] == 0
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt", "ok_main.mod", "ok_mod1.mod"]


def test_joining_a_silent_meshcat_port_times_out():
    with pytest.raises(CurvsliceError, match="no meshcat server answered"):
        open_viewer("tcp://127.0.0.1:1", timeout=0.5)


# ------------------------------------------------------------------ verify cannot be fooled, never raises


@pytest.fixture(scope="module")
def robot_slice(tmp_path_factory):
    out = tmp_path_factory.mktemp("hostile") / "tee"
    assert cli.main(["slice", str(MODELS / "tee.stl"), "--voxel", "3", "--out", str(out), "--stages", "robot", "--no-verify",
                     "--robot", "ur5", "--quiet"]) == 0
    return out


def _tamper(folder: Path, how: str) -> None:
    if how.startswith("rm "):
        for p in folder.glob(how[3:]):
            p.unlink()
    elif how == "flip nZ":  # on one deposition move in the middle of the G-code
        path = folder / "toolpaths.gcode"
        lines = path.read_text().split("\n")
        moves = [i for i, line in enumerate(lines) if line.startswith("G1 ") and re.search(r" nZ(0\.[1-9]|1)", line)]
        i = moves[len(moves) // 2]
        lines[i] = re.sub(r"nZ(-?)", lambda m: "nZ" + ("" if m[1] else "-"), lines[i])
        path.write_text("\n".join(lines))
    elif how == "shift a voxel's layer":  # one voxel of the last layer moved one layer down
        z = dict(np.load(folder / "field.npz"))
        g = z["growing"]
        g[tuple(np.argwhere(g == g.max())[0])] -= 1
        np.savez_compressed(folder / "field.npz", **z)
    elif how.startswith("truncate "):
        p = folder / how[9:]
        p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 3])
    else:
        name, text = how.split("=", 1)
        (folder / name).write_text(text)


TAMPERS = [
    ("rm toolpaths.npz", "toolpaths files"),
    ("flip nZ", "toolpaths.gcode orientations = npz"),
    ("shift a voxel's layer", "field.npz layer sizes = report.json"),
    ("rm toolpaths.gcode", "toolpaths files"),
    ("rm field.npz", "field files"),
    ("rm layers/layer_0002.ply", "layers files"),
    ("rm joints.csv", "robot files"),
    ("rm workcell.json", "robot files"),
    ("rm *.script", "robot programs"),
    ("truncate field.npz", "field files"),
    ("truncate toolpaths.npz", "toolpaths files"),
    ("truncate joints.csv", "robot files"),
    ("layers/layer_0003.ply=not a ply", "layers files"),
    ("workcell.json={", "robot files"),
    ("report.json={", "report.json"),
    ("report.json=[]", "report.json"),
    ('report.json={"stages": ["field", "warp"]}', "report.json"),
]


@pytest.mark.parametrize("how,failed", TAMPERS, ids=[t[0] for t in TAMPERS])
def test_verify_fails_a_tampered_folder_naming_the_file(robot_slice, tmp_path, capsys, how, failed):
    folder = tmp_path / "t"
    shutil.copytree(robot_slice, folder)
    _tamper(folder, how)
    code, err, out = run(["verify", folder, "--json"], capsys)
    assert code == 1 and "Traceback" not in err, err
    bad = {c["name"] for c in json.loads(out) if not c["passed"] and c["stage"] == "artefacts"}
    assert failed in bad, out


def test_verify_json_on_a_robot_folder_lists_every_artefact_as_present(robot_slice, capsys):
    code, err, out = run(["verify", robot_slice, "--json"], capsys)
    checks = json.loads(out)
    artefacts = {c["name"]: c["passed"] for c in checks if c["stage"] == "artefacts"}
    assert artefacts == {"report.json": True, "field files": True, "layers files": True, "toolpaths files": True,
                         "toolpaths.gcode orientations = npz": True, "robot files": True, "robot programs": True,
                         "field.npz layer sizes = report.json": True, "files listed in report.json": True}
    assert code == (0 if all(c["passed"] for c in checks) else 1) and "Traceback" not in err
