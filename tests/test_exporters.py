"""Robot-program writers read back by their readers, plus independent checks of the written text."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from curvslice.errors import CurvsliceError
from curvslice.exporters.rapid import read_rapid_joints, write_rapid_joints
from curvslice.exporters.urscript import read_urscript_joints, write_urscript_joints


def joint_trajectory(n: int, seed: int = 0):
    """A random timed joint trajectory with segments (some long, some of one row) and extruder toggles."""
    rng = np.random.default_rng(seed)
    q = np.cumsum(rng.normal(scale=0.01, size=(n, 6)), axis=0) + rng.uniform(-np.pi, np.pi, 6)
    t = 12.5 + np.cumsum(rng.uniform(0.002, 0.2, n))
    seg = np.cumsum(rng.random(n) < 0.03) + 7
    ext = rng.random(n) < 0.8
    ext[np.flatnonzero(np.diff(seg, prepend=seg[0] - 1))] = False  # disconnections are joint moves without extrusion
    return q, t, seg, ext


@pytest.mark.parametrize("max_lines", [20000, 400, 9])
def test_urscript_joints_round_trip_and_split(tmp_path, max_lines):
    q, t, seg, ext = joint_trajectory(3000)
    paths = write_urscript_joints(tmp_path, q, t, segment=seg, extruding=ext, max_lines=max_lines, name="demo")
    sizes = [len(p.read_text().splitlines()) for p in paths]
    assert max(sizes) <= max_lines
    # a row needs at most 3 lines (segment comment, output, move) + 4 lines per file: the split is not wasteful
    assert len(paths) <= math.ceil(len(q) * 3 / (max_lines - 7))
    back = read_urscript_joints(paths)
    assert np.abs(back["q"] - q).max() <= 5e-10
    assert np.abs(back["t"] - t).max() <= 2e-9
    assert np.array_equal(back["segment"], seg)
    assert np.array_equal(back["extruding"], ext)


def test_urscript_joints_motion_semantics(tmp_path):
    """Independent parse: segment starts are movej, the rest servoj, each lasting its time step."""
    q, t, seg, ext = joint_trajectory(500, seed=3)
    paths = write_urscript_joints(tmp_path, q, t, segment=seg, extruding=ext)
    moves = [
        line for p in paths for line in p.read_text().splitlines() if re.match(r"\s*(movej|servoj)\(", line)
    ]
    assert len(moves) == len(q)
    starts = np.flatnonzero(np.diff(seg)) + 1
    kinds = np.array([m.split("(")[0].strip() for m in moves])
    assert set(np.flatnonzero(kinds == "movej")) == {0, *starts}
    durations = np.array([float(re.search(r"\bt=([0-9.]+)", m)[1]) for m in moves[1:]])
    assert np.allclose(durations, np.diff(t), atol=1.5e-9)
    text = "".join(p.read_text() for p in paths)
    assert text.count("def ") == text.count("\nend") == len(paths)
    assert text.rstrip().endswith("set_standard_digital_out(0, False)\nend")


@pytest.mark.parametrize("max_targets", [7000, 250])
def test_rapid_joints_round_trip_and_modules(tmp_path, max_targets):
    q, t, seg, ext = joint_trajectory(1200, seed=1)
    paths = write_rapid_joints(tmp_path, q, t, segment=seg, extruding=ext, max_targets=max_targets, name="demo")
    main, parts = paths[0], paths[1:]
    assert len(parts) == math.ceil(len(q) / max_targets)
    for p in parts:
        assert len(re.findall(r"CONST jointtarget", p.read_text())) <= max_targets
    loads = re.findall(r'Load \\Dynamic, "HOME:/(\w+)\.mod"', main.read_text())
    assert loads == [p.stem for p in parts]
    assert main.read_text().count("UnLoad") == len(parts)
    back = read_rapid_joints(list(reversed(paths)))  # order comes from the main module
    assert np.abs(back["q"] - q).max() <= np.radians(5e-7)
    assert np.abs(back["t"] - t).max() <= 2e-9
    assert np.array_equal(back["segment"], seg)
    assert np.array_equal(back["extruding"], ext)


def test_rapid_joints_stops_only_where_needed(tmp_path):
    """``fine`` only at switches, disconnections, module ends and after the approach (seed 004 §2.4.4)."""
    q, t, seg, ext = joint_trajectory(900, seed=2)
    paths = write_rapid_joints(tmp_path, q, t, segment=seg, extruding=ext, max_targets=400)
    zones = [
        m[1] for p in paths[1:] for m in re.finditer(r"MoveAbsJ \w+, [^,]+, (\w+),", p.read_text())
    ]
    fine = np.array(zones) == "fine"
    expected = np.zeros(len(q), bool)
    expected[:-1] = (np.diff(ext.astype(int)) != 0) | (np.diff(seg) != 0)
    expected[[0, 399, 799, len(q) - 1]] = True
    assert np.array_equal(fine, expected)
    assert fine.mean() < 0.5  # not a stop at every point


def test_joint_writers_defaults_and_stale_parts(tmp_path):
    q, t, _, _ = joint_trajectory(50)
    for write, read, kw in [
        (write_urscript_joints, read_urscript_joints, {"max_lines": 12}),
        (write_rapid_joints, read_rapid_joints, {"max_targets": 5}),
    ]:
        many = write(tmp_path, q, t, **kw)
        few = write(tmp_path, q[:10], t[:10], **kw)
        assert len(few) < len(many)
        on_disk = sorted(p.name for p in tmp_path.iterdir())
        assert on_disk == sorted({p.name for p in few} | ({"curvslice_main.mod"} if "max_targets" in kw else set()))
        back = read(few)
        assert not back["extruding"].any() and not back["segment"].any()
        for p in tmp_path.iterdir():
            p.unlink()


@pytest.mark.parametrize("write", [write_urscript_joints, write_rapid_joints])
def test_joint_writers_reject_bad_input(tmp_path, write):
    q, t, _, _ = joint_trajectory(10)
    with pytest.raises(CurvsliceError, match="increase"):
        write(tmp_path, q, t[::-1])
    with pytest.raises(CurvsliceError, match="shape"):
        write(tmp_path, q[:, :5], t)
    q_nan = q.copy()
    q_nan[3, 2] = np.nan
    with pytest.raises(CurvsliceError, match="NaN"):
        write(tmp_path, q_nan, t)


# ---------------------------------------------------------------- Cartesian programs (convert)

from curvslice import cli  # noqa: E402
from curvslice.cell.cells import Cell, RapidIO, gcode6_samples, load_cell, robot_path, tool_normals  # noqa: E402
from curvslice.cell.gcode import parse_gcode  # noqa: E402
from curvslice.exporters.arduino import read_accelstepper_sketch, write_accelstepper_sketch  # noqa: E402
from curvslice.exporters.gcode6 import read_gcode6, write_gcode6  # noqa: E402
from curvslice.exporters.rapid import read_rapid, write_rapid  # noqa: E402
from curvslice.exporters.urscript import read_urscript, write_urscript  # noqa: E402
from curvslice.exporters.vplus import read_vplus, signal_count, speed_inventory, write_vplus  # noqa: E402
from test_gcode import prusa_style  # noqa: E402

SEED_003_VPLUS = """.PROGRAM example();
    SPEED 10.0 MMPS ALWAYS
    WAIT STATE(2) == 2
    SIGNAL 1
    MOVE TRANS(600.0,150.0,-60.0,0,180,0)
    WAIT STATE(2) == 2
    SIGNAL -1
.END
"""

SEED_003_SKETCH = """#include <AccelStepper.h>
#define D1_SIGNAL_PIN 16
#define E0_STEP_PIN 26
#define E0_DIR_PIN 28
#define E0_ENABLE_PIN 24
AccelStepper E0(AccelStepper::DRIVER, E0_STEP_PIN, E0_DIR_PIN);
void setup()
{
Serial.begin(9600);
pinMode(D1_SIGNAL_PIN, INPUT); // Speed Pin
pinMode(E0_STEP_PIN, OUTPUT);
pinMode(E0_DIR_PIN, OUTPUT);
pinMode(E0_ENABLE_PIN, OUTPUT);
digitalWrite(E0_ENABLE_PIN, LOW);
E0.setMaxSpeed(1000);
}
void loop()
{
int IN0 = digitalRead(D1_SIGNAL_PIN);
if (IN0 == LOW) {
// motor does not move
}
else if (IN0 == HIGH) { // Extruder 0, Speed 1
E0.setSpeed(8.51653543307);
E0.runSpeed();
}
}"""


def squash(text: str) -> str:
    """Whitespace-insensitive form of a listing: one space between tokens, no blank lines."""
    return "\n".join(" ".join(line.split()) for line in text.splitlines() if line.strip())


def run_cli(argv: list[str], monkeypatch) -> int:
    monkeypatch.setattr(cli, "COMMANDS", ("convert",))  # the other commands may not exist yet
    return cli.main(argv)


def test_seed_003_vplus_and_sketch(tmp_path):
    cell = load_cell("heuser-adept-python")
    robot, warnings = robot_path(parse_gcode("G1 X600 Y150 Z-60 E0.1 F600.000\n"), cell)
    assert not warnings
    patterns = speed_inventory(robot)
    assert patterns == [(0, 10.0)]
    write_vplus(tmp_path / "example.v2", robot, patterns, cell.vplus, program="example")
    assert (tmp_path / "example.v2").read_text() == SEED_003_VPLUS
    write_accelstepper_sketch(tmp_path / "example.ino", patterns, signal_count(1, cell.vplus), cell.syringe)
    assert squash((tmp_path / "example.ino").read_text()) == squash(SEED_003_SKETCH)
    assert read_accelstepper_sketch(tmp_path / "example.ino") == {1: (0, 8.51653543307)}


def test_vplus_speed_inventory_round_trip(tmp_path):
    """Two extruders and several speeds: patterns are binary codes, decoded back by the sketch."""
    text = prusa_style(layers=2) + "T1\nG1 X120 Y120 F900\nG1 X125 E0.2\nG1 X130 E0.2 F1500\n"
    cell = load_cell("heuser-adept-python")
    robot, _ = robot_path(parse_gcode(text), cell)
    patterns = speed_inventory(robot)
    assert len(patterns) == len(set(patterns)) >= 4 and {t for t, _ in patterns} == {0, 1}
    bits = signal_count(len(patterns), cell.vplus)
    assert 2 ** (bits - 1) <= len(patterns) < 2**bits
    write_vplus(tmp_path / "p.v2", robot, patterns, cell.vplus)
    write_accelstepper_sketch(tmp_path / "p.ino", patterns, bits, cell.syringe)
    back = read_vplus(tmp_path / "p.v2")
    table = read_accelstepper_sketch(tmp_path / "p.ino")
    assert np.abs(back["positions"] - robot.positions).max() <= 5e-4
    assert np.allclose(back["speed"], robot.speed, atol=5e-4)
    assert np.array_equal(back["pattern"] > 0, robot.extruding)
    # every extruding move's pattern decodes to its own extruder and the flow-model stepper speed
    mm_per_step = 0.000125 * 25.4
    for code, tool, speed in zip(back["pattern"], robot.tool, robot.speed):
        if code:
            assert table[code][0] == tool
            assert table[code][1] == pytest.approx(round(speed, 3) * 0.052**2 / mm_per_step, rel=1e-9)
    assert [e.code for e in back["events"]] == [e.code for e in robot.events]
    tight = Cell(vplus=cell.vplus.__class__(signals=(1, 2), max_signals=2))
    with pytest.raises(CurvsliceError, match="controller signals"):
        signal_count(len(patterns), tight.vplus)


def slicer_robot(cell: Cell, layers: int = 3):
    return robot_path(parse_gcode(prusa_style(layers=layers), home=cell.home), cell)


def test_rapid_10000_moves_two_modules(tmp_path):
    rng = np.random.default_rng(4)
    xy = np.round(rng.uniform(10, 200, (10000, 2)), 3)
    text = "M83\nG1 F1800\n" + "".join(f"G1 X{x:.3f} Y{y:.3f} E0.05\n" for x, y in xy)
    cell = load_cell("huygens-irb120")
    robot, _ = robot_path(parse_gcode(text), cell)
    paths = write_rapid(tmp_path, robot, cell.rapid, name="big")
    assert [p.name for p in paths] == ["big_main.mod", "big_mod1.mod", "big_mod2.mod"]
    assert [p.read_text().count("CONST robtarget") for p in paths[1:]] == [7000, 3000]
    back = read_rapid(paths, cell.rapid)
    assert np.array_equal(back["positions"][:, :2], xy)
    assert np.allclose(back["quaternions"], robot.quaternions, atol=1e-7)
    assert np.allclose(back["speed"], 30.0) and np.array_equal(back["speed_word"], np.full(10000, 30))
    zones = re.findall(r"MoveL p\d+, sd\d+, (\w+),", paths[1].read_text() + paths[2].read_text())
    assert zones.count("fine") == 2  # one per module end: no stop at every point


def test_rapid_speed_bits_and_overflow(tmp_path):
    """The 8th bit survives (seed 004 dropped it); a word that does not fit is an error with its line."""
    text = "M83\nG1 X0 Y0 Z1 F600\nG1 X10 E1 F7680\nG1 X20 E1 F600\nG1 E-0.8\nG1 X30\nG1 E0.8\nG1 X40 E1 F15300\n"
    program = parse_gcode(text)
    eight = RapidIO(speed_outputs=tuple(f"DO{i}" for i in range(8)), retract_output="DO9", extruder_output=None)
    robot, _ = robot_path(program, Cell(rapid=eight, max_speed=1000))
    back = read_rapid(write_rapid(tmp_path, robot, eight), eight)
    assert back["speed_word"].tolist() == [0, 128, 10, 0, 0, 10, 255]  # the prime (E+0.8) extrudes
    assert back["retracted"].tolist() == [False, False, False, True, True, False, False]
    assert back["extruding"].tolist() == robot.extruding.tolist()
    seven = RapidIO(speed_outputs=tuple(f"DO{i}" for i in range(7)))
    with pytest.raises(CurvsliceError, match=r"line 3: 128 mm/s .*\(max 127\)"):
        write_rapid(tmp_path, robot, seven)


def test_rapid_quaternions_normalised_and_tilted(tmp_path):
    text = "G1 X0 Y0 Z5 F600 nX0 nY0 nZ1\nG1 X5 nX0.3 nY0 nZ0.954 E1\nG1 X9 nX-0.2 nY0.5 nZ0.8 E2\n"
    cell = load_cell("huygens-irb120")
    robot, _ = robot_path(parse_gcode(text), cell)
    back = read_rapid(write_rapid(tmp_path, robot, cell.rapid), cell.rapid)
    assert np.allclose(np.linalg.norm(back["quaternions"], axis=1), 1.0, atol=1e-6)
    want = parse_gcode(text).normals
    assert np.allclose(tool_normals(back["quaternions"], cell.orientation), want, atol=1e-6)
    assert np.allclose(back["quaternions"][0], cell.orientation, atol=1e-7)


def same_events(found, robot) -> bool:
    return [(e.index, e.code, e.params, e.text) for e in found] == [
        (e.index, e.code, e.params, e.text) for e in robot.events
    ]


def test_slicer_gcode_converts_to_every_target_without_loss(tmp_path):
    cell = dataclasses.replace(load_cell("huygens-irb120"), max_speed=200.0)  # the sample travels at 180 mm/s
    robot, warnings = slicer_robot(cell)
    assert not warnings
    n = len(robot)
    # RAPID
    rapid = read_rapid(write_rapid(tmp_path / "rapid", robot, cell.rapid), cell.rapid)
    assert np.abs(rapid["positions"] - robot.positions).max() <= 5e-4
    assert np.allclose(rapid["speed"], robot.speed, atol=5e-4)
    assert np.allclose(rapid["extrusion"], robot.extrusion, atol=5e-7)
    assert np.array_equal(rapid["extruding"], robot.extruding)
    assert np.array_equal(rapid["retracted"], robot.retracted)
    assert np.array_equal(rapid["home"], robot.home)
    assert same_events(rapid["events"], robot)
    # URScript
    ur = read_urscript(write_urscript(tmp_path / "ur", robot, cell.urscript, max_lines=60), cell.urscript)
    assert np.abs(ur["positions"] - robot.positions).max() <= 5e-4
    assert np.allclose(np.abs((ur["quaternions"] * robot.quaternions).sum(axis=1)), 1.0, atol=1e-9)
    assert np.allclose(ur["speed"], robot.speed, atol=5e-4)
    assert np.allclose(ur["extrusion"], robot.extrusion, atol=5e-7)
    assert np.array_equal(ur["extruding"], robot.extruding) and np.array_equal(ur["home"], robot.home)
    assert same_events(ur["events"], robot)
    # V+
    patterns = speed_inventory(robot)
    write_vplus(tmp_path / "p.v2", robot, patterns, cell.vplus)
    vp = read_vplus(tmp_path / "p.v2")
    assert len(vp["positions"]) == n and np.abs(vp["positions"] - robot.positions).max() <= 5e-4
    assert np.allclose(np.abs((vp["quaternions"] * robot.quaternions).sum(axis=1)), 1.0, atol=1e-9)
    assert np.array_equal(vp["pattern"] > 0, robot.extruding)
    assert same_events(vp["events"], robot)
    # extended G-code: every move is a sample, filament totals kept, retractions included
    samples = gcode6_samples(robot, cell.orientation)
    write_gcode6(tmp_path / "p.gcode", **samples)
    g6 = read_gcode6(tmp_path / "p.gcode")
    assert len(g6["positions"]) == n
    assert np.abs(g6["positions"] - robot.positions).max() <= 5e-5
    assert np.allclose(g6["extrusion"], robot.extrusion, atol=2e-6)
    assert np.allclose(g6["normals"], [0, 0, 1])


def test_convert_cli_targets_and_errors(tmp_path, monkeypatch, capsys):
    src = tmp_path / "part.gcode"
    src.write_text(prusa_style(layers=2))
    out = tmp_path / "out"
    argv = ["convert", str(src), "--cell", "huygens-irb120", "--out", str(out)]
    assert run_cli(argv + ["--to", "rapid", "--to", "urscript", "--to", "vplus", "--to", "gcode6"], monkeypatch) == 0
    assert "180 mm/s exceeds the cell's max_speed 150 mm/s" in capsys.readouterr().err
    names = sorted(p.name for p in out.rglob("*") if p.is_file())
    assert names == ["part.gcode", "part.ino", "part.v2", "part_001.script", "part_main.mod", "part_mod1.mod"]
    # an unknown command fails with its line number, as one line and exit code 2
    bad = tmp_path / "bad.gcode"
    lines = prusa_style(layers=1).splitlines()
    lines.insert(29, "G5 I1 J1 X3 Y3")
    bad.write_text("\n".join(lines))
    assert run_cli(["convert", str(bad), "--to", "rapid", "--out", str(out)], monkeypatch) == 2
    err = capsys.readouterr().err.strip()
    assert "line 30: unknown command G5" in err and len(err.splitlines()) == 1
    # a move outside the workspace is refused with its line, or reported with --warn-workspace
    far = tmp_path / "far.gcode"
    far.write_text("M83\nG1 X10 Y10 Z1 F600\nG1 X250 Y10 E1\nG1 X10 Y10 E1\n")
    assert run_cli(["convert", str(far), "--to", "rapid", "--cell", "huygens-irb120", "--out", str(out)], monkeypatch) == 2
    assert "line 3: move to (250.000, 10.000, 1.000) mm is outside the workspace" in capsys.readouterr().err
    args = ["convert", str(far), "--to", "rapid", "--cell", "huygens-irb120", "--out", str(out), "--warn-workspace"]
    assert run_cli(args, monkeypatch) == 0
    assert "far.gcode, line 3: move to (250.000" in capsys.readouterr().err


def test_extended_gcode_through_convert_keeps_normals(tmp_path):
    """Extended G-code (thesis appendix) in, extended G-code out: positions, tilted normals and
    filament survive the trip through tool quaternions."""
    rng = np.random.default_rng(8)
    n = 300
    normals = rng.normal(size=(n, 3)) * [0.4, 0.4, 0.0] + [0, 0, 1]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    path_id = np.repeat(np.arange(6), 50)
    extrusion = np.where(np.diff(path_id, prepend=-1) != 0, 0.0, rng.uniform(0.01, 0.1, n))
    src = dict(positions=rng.uniform(-50, 50, (n, 3)), normals=normals, extrusion=extrusion,
               feed=np.full(n, 1200.0), path_id=path_id, layer=np.repeat(np.arange(1, 4), 100))
    write_gcode6(tmp_path / "in.gcode", **src)
    cell = load_cell("generic")
    robot, _ = robot_path(parse_gcode((tmp_path / "in.gcode").read_text()), cell)
    out = gcode6_samples(robot, cell.orientation)
    assert np.abs(out["positions"] - src["positions"]).max() <= 5e-5
    assert np.abs(out["normals"] - normals).max() <= 1e-6
    assert np.allclose(out["extrusion"], extrusion, atol=2e-6)
    assert np.array_equal(np.unique(out["path_id"], return_index=True)[1], np.arange(0, n, 50))
    assert np.array_equal(out["layer"], src["layer"])
