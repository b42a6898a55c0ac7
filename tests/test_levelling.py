"""Bed levelling: the seed 004 vector, properties that catch its row-shift and rounding bugs,
a scipy reference, tilt, CSV and the RAPID probing routine."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from curvslice import cli
from curvslice.cell.cells import load_cell, robot_path
from curvslice.cell.gcode import parse_gcode
from curvslice.cell.levelling import (
    HeightMap,
    heightmap_from_points,
    level_path,
    read_probe_csv,
    write_probe_csv,
)
from curvslice.errors import CurvsliceError
from curvslice.exporters.rapid import write_probe_routine

#: Seed 004 Appendix 10: the 25 probed bed heights, 50 mm apart.
SEED_004_PROBES = np.array([
    (0, 0, 2.57608), (50, 0, 2.86989), (100, 0, 2.94418), (150, 0, 2.85357), (200, 0, 2.56837),
    (0, 50, 2.55952), (50, 50, 2.82228), (100, 50, 2.9139), (150, 50, 2.80468), (200, 50, 2.50553),
    (0, 100, 2.52471), (50, 100, 2.82434), (100, 100, 2.89199), (150, 100, 2.81364), (200, 100, 2.54148),
    (0, 150, 2.53342), (50, 150, 2.79708), (100, 150, 2.88318), (150, 150, 2.81295), (200, 150, 2.61035),
    (0, 200, 2.55512), (50, 200, 2.798938), (100, 200, 2.82164), (150, 200, 2.75293), (200, 200, 2.54133),
])


def random_map(nx: int, ny: int, seed: int) -> HeightMap:
    rng = np.random.default_rng(seed)
    xs = np.sort(rng.uniform(-40, 160, nx))
    ys = np.sort(rng.uniform(10, 90, ny))
    return HeightMap(xs, ys, rng.uniform(-1, 1, (ny, nx)))


def seed_style_lookup(hmap: HeightMap, x, y) -> np.ndarray:
    """Seed 004's method: a table of heights at integer coordinates from the first probe, read
    back with Python's round() of ``coordinate - inset`` (half-even at every .5)."""
    table = hmap.height(*np.meshgrid(np.arange(hmap.xs[0], hmap.xs[-1] + 1), np.arange(hmap.ys[0], hmap.ys[-1] + 1)))
    return np.array([table[round(b - hmap.ys[0])][round(a - hmap.xs[0])] for a, b in zip(x, y)])


def test_seed_004_bilinear_vector():
    hmap = heightmap_from_points(np.array([(10, 4, 100), (20, 4, 200), (10, 6, 150), (20, 6, 300)], float))
    assert float(hmap.height(12, 5.5)) == pytest.approx(165.0, abs=1e-12)


def test_exact_at_every_probe_catches_row_shifts():
    for hmap in (random_map(5, 5, 0), random_map(7, 3, 1), heightmap_from_points(SEED_004_PROBES)):
        X, Y = np.meshgrid(hmap.xs, hmap.ys)
        assert np.array_equal(hmap.height(X, Y), hmap.z)
    seed = heightmap_from_points(SEED_004_PROBES)
    assert float(seed.height(50, 150)) == 2.79708 and float(seed.height(200, 0)) == 2.56837


def test_bilinear_functions_reproduced_everywhere_catches_rounding():
    """h = a + bx + cy + dxy is bilinear on every cell, so it must come back exactly — also at the
    half-millimetre points where round-half-even lookups jump to a neighbour."""
    rng = np.random.default_rng(3)
    xs, ys = np.array([0, 50, 100, 150, 200.0]), np.array([0, 50, 100, 150, 200.0])
    a, b, c, d = 2.6, 0.004, -0.003, 1e-5
    X, Y = np.meshgrid(xs, ys)
    hmap = HeightMap(xs, ys, a + b * X + c * Y + d * X * Y)
    x = np.concatenate([rng.uniform(0, 200, 500), np.arange(0.5, 200, 7.0)])
    y = np.concatenate([rng.uniform(0, 200, 500), np.arange(0.5, 200, 7.0)[::-1]])
    want = a + b * x + c * y + d * x * y
    assert np.abs(hmap.height(x, y) - want).max() < 1e-12
    # the seed's integer table + round() misses by up to half a millimetre of slope: these tests catch it
    assert np.abs(seed_style_lookup(hmap, x, y) - want).max() > 1e-3


def test_matches_scipy_reference_on_non_uniform_grids():
    rng = np.random.default_rng(5)
    for nx, ny in [(2, 2), (5, 3), (4, 9)]:
        hmap = random_map(nx, ny, nx * 10 + ny)
        ref = RegularGridInterpolator((hmap.ys, hmap.xs), hmap.z, method="linear")
        x = rng.uniform(hmap.xs[0], hmap.xs[-1], 2000)
        y = rng.uniform(hmap.ys[0], hmap.ys[-1], 2000)
        assert np.abs(hmap.height(x, y) - ref(np.c_[y, x])).max() < 1e-12
        # an x-only bed varies with x only (no transposed axes)
        xonly = HeightMap(hmap.xs, hmap.ys, np.tile(hmap.xs * 0.01, (ny, 1)))
        assert np.allclose(xonly.height(x, y), x * 0.01)


def test_outside_policy():
    hmap = random_map(4, 4, 2)
    edge = hmap.height(hmap.xs[-1], hmap.ys[0])
    assert hmap.height(hmap.xs[-1] + 30, hmap.ys[0] - 5) == pytest.approx(edge)
    with pytest.raises(CurvsliceError, match="outside the probed area"):
        hmap.height(hmap.xs[-1] + 1, hmap.ys[0], outside="error")


def test_normals_are_the_gradient():
    hmap = heightmap_from_points(SEED_004_PROBES)
    rng = np.random.default_rng(7)
    x, y = rng.uniform(1, 199, 300), rng.uniform(1, 199, 300)
    x, y = x[(x % 50 > 0.01) & (y % 50 > 0.01)], y[(x % 50 > 0.01) & (y % 50 > 0.01)]
    h = 1e-6
    gx = (hmap.height(x + h, y) - hmap.height(x - h, y)) / (2 * h)
    gy = (hmap.height(x, y + h) - hmap.height(x, y - h)) / (2 * h)
    want = np.c_[-gx, -gy, np.ones_like(gx)]
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    assert np.abs(hmap.normal(x, y) - want).max() < 1e-7


def test_csv_round_trip_and_errors(tmp_path):
    hmap = random_map(5, 4, 9)
    write_probe_csv(tmp_path / "a.csv", hmap)
    lines = (tmp_path / "a.csv").read_text().splitlines()
    rng = np.random.default_rng(0)
    body = [lines[i] for i in rng.permutation(np.arange(1, len(lines)))]
    (tmp_path / "b.csv").write_text("# probed 2024-04-16\n" + lines[0] + "\n" + "\n".join(body) + "\n")
    back = read_probe_csv(tmp_path / "b.csv")
    assert np.array_equal(back.xs, hmap.xs) and np.array_equal(back.ys, hmap.ys) and np.array_equal(back.z, hmap.z)
    (tmp_path / "c.csv").write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(CurvsliceError, match="is missing"):
        read_probe_csv(tmp_path / "c.csv")
    (tmp_path / "d.csv").write_text("\n".join(lines + [lines[3]]) + "\n")
    with pytest.raises(CurvsliceError, match="more than once"):
        read_probe_csv(tmp_path / "d.csv")


def test_level_path_z_and_tilt():
    """On a tilted plane bed the corrected nozzle keeps its height above the bed and, with tilt,
    its axis along the bed normal; quaternions stay normalised."""
    xs = ys = np.array([0.0, 100.0, 200.0])
    X, Y = np.meshgrid(xs, ys)
    plane = HeightMap(xs, ys, 1.0 + 0.02 * X - 0.01 * Y)
    cell = load_cell("huygens-irb120")
    robot, _ = robot_path(parse_gcode("M83\nG1 X10 Y20 Z0.2 F600\nG1 X150 Y120 E1\nG1 X60 Y190 E1\n"), cell)
    flat = level_path(robot, plane, reference=1.0)
    assert np.allclose(flat.positions[:, 2] - robot.positions[:, 2],
                       0.02 * robot.positions[:, 0] - 0.01 * robot.positions[:, 1])
    assert np.array_equal(flat.quaternions, robot.quaternions)
    tilted = level_path(robot, plane, tilt=True)
    assert np.allclose(np.linalg.norm(tilted.quaternions, axis=1), 1.0)
    normal = np.array([-0.02, 0.01, 1.0]) / np.linalg.norm([-0.02, 0.01, 1.0])
    w, x, y, z = tilted.quaternions.T  # tool z axis (third column of R) points into the bed: -normal
    tool_z = np.c_[2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)]
    assert np.allclose(tool_z, -normal, atol=1e-12)


def test_probe_routine(tmp_path):
    xs, ys = np.linspace(17.5, 217.5, 5), np.linspace(17.5, 167.5, 4)
    offset = (24.88, -39.05, 2.4)
    seed_quat = (0.0, 0.701057385, -0.701057385, 0.0)  # seed 004 Appendix 9: not normalised
    count = write_probe_routine(tmp_path / "BedProbe.mod", xs, ys, probe_offset=offset, orientation=seed_quat,
                                signal="D652_10_DI10", tool="Hemera", wobj="PrintBed")
    text = (tmp_path / "BedProbe.mod").read_text()
    assert count == 20 and text.count("SearchL \\Stop, D652_10_DI10") == 20
    targets = re.findall(r"CONST robtarget c(\d+) := \[\[([^\]]*)\],\[([^\]]*)\]", text)
    xyz = np.array([[float(v) for v in t[1].split(",")] for t in targets])
    quats = np.array([[float(v) for v in t[2].split(",")] for t in targets])
    assert np.allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-9)
    probe_xy = xyz[:, :2] + offset[:2]  # where the probe tip touches
    assert {(round(a, 3), round(b, 3)) for a, b in probe_xy} == {(a, b) for a in xs for b in ys}
    steps = np.linalg.norm(np.diff(probe_xy, axis=0), axis=1)
    assert steps.max() <= 50.0 + 1e-9  # serpentine: never a long jump back
    searched = [int(k) for k in re.findall(r"SearchL \\Stop, \w+, touched, Offs\(c(\d+),0,0,-5.0\)", text)]
    assert searched == list(range(1, 21))
    assert text.count("Write probelog, NumToStr") == 20 and "Close probelog;" in text


def test_level_cli_and_convert_level(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(cli, "COMMANDS", ("convert", "level"))
    csv = tmp_path / "probe.csv"
    write_probe_csv(csv, heightmap_from_points(SEED_004_PROBES))
    assert cli.main(["level", "report", str(csv)]) == 0
    assert "peak-to-peak 0.439 mm" in capsys.readouterr().out
    args = ["level", "routine", "--xs", "17.5", "217.5", "5", "--ys", "17.5", "217.5", "5", "--out", str(tmp_path),
            "--cell", "huygens-irb120", "--probe-offset", "24.88", "-39.05", "2.4", "--signal", "D652_10_DI10"]
    assert cli.main(args) == 0 and (tmp_path / "BedProbe.mod").is_file()
    src = tmp_path / "line.gcode"
    src.write_text("M83\nG1 X20 Y20 Z0.2 F600\nG1 X180 Y180 E5\n")
    # the extended G-code keeps the input's name, so it goes to another folder (never over the input)
    assert cli.main(["convert", str(src), "--to", "gcode6", "--out", str(tmp_path / "out"), "--level", str(csv),
                     "--level-reference", "2.5"]) == 0
    g6 = parse_gcode((tmp_path / "out" / "line.gcode").read_text())
    hmap = read_probe_csv(csv)
    assert np.allclose(g6.positions[:, 2], 0.2 + hmap.height(g6.positions[:, 0], g6.positions[:, 1]) - 2.5, atol=1e-4)
