"""Extended G-code (thesis appendix): write + read round trip, absolute E, header, travels."""

from __future__ import annotations

import numpy as np
import pytest

from curvslice.exporters.gcode6 import read_gcode6, read_gcode6_header, write_gcode6


def _random_paths(seed: int = 3, n: int = 600):
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-80, 80, (n, 3))
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    path_id = np.sort(rng.integers(0, 25, n))
    layer = 1 + path_id // 5
    extrusion = rng.uniform(0.0, 0.2, n)
    extrusion[np.r_[True, path_id[1:] != path_id[:-1]]] = 0.0
    feed = rng.choice([600.0, 900.0, 1234.5], n)
    return positions, normals, extrusion, feed, path_id, layer


def test_round_trip_identical_to_1e3(tmp_path):
    positions, normals, extrusion, feed, path_id, layer = _random_paths()
    out = tmp_path / "t.gcode"
    write_gcode6(out, positions, normals, extrusion, feed, path_id, layer, header={"path_width": 0.8})
    back = read_gcode6(out)
    assert np.abs(back["positions"] - positions).max() <= 1e-3
    assert np.abs(back["normals"] - normals).max() <= 1e-5
    assert np.abs(back["extrusion"] - extrusion).max() <= 1e-5
    assert np.allclose(back["feed"], feed)
    assert np.array_equal(back["path_id"], path_id)
    assert np.array_equal(back["layer"], layer)
    assert read_gcode6_header(out)["path_width"] == "0.8"


def test_absolute_e_and_travels(tmp_path):
    positions, normals, extrusion, feed, path_id, layer = _random_paths(seed=5, n=200)
    out = tmp_path / "t.gcode"
    write_gcode6(out, positions, normals, extrusion, feed, path_id, layer)
    lines = out.read_text().splitlines()
    e_values = [float(w[1:]) for ln in lines if ln.startswith("G1") for w in ln.split() if w.startswith("E")]
    assert np.all(np.diff(e_values) >= -1e-9)  # absolute E never decreases
    assert abs(e_values[-1] - extrusion.sum()) < 1e-5
    travels = [ln for ln in lines if ln.startswith("G0")]
    assert len(travels) == len(np.unique(path_id))
    assert all(" E" not in ln for ln in travels)


def test_reads_plain_reprap_gcode(tmp_path):
    """The appendix's conventional example: no orientation words means +Z, E from G92 base."""
    out = tmp_path / "plain.gcode"
    out.write_text("G92 E0\nG28\nG0 F600 X4.391 Y-8.398 Z1.500\nG1 X3.650 Y-9.611 Z1.500 E1.026\n")
    back = read_gcode6(out)
    assert np.allclose(back["positions"], [[4.391, -8.398, 1.5], [3.65, -9.611, 1.5]])
    assert np.allclose(back["normals"], [[0, 0, 1], [0, 0, 1]])
    assert np.allclose(back["extrusion"], [0.0, 1.026])
    assert np.allclose(back["feed"], [600, 600])


def test_rejects_extrusion_on_travel(tmp_path):
    positions, normals, extrusion, feed, path_id, layer = _random_paths(n=50)
    extrusion[0] = 0.1
    with pytest.raises(ValueError):
        write_gcode6(tmp_path / "bad.gcode", positions, normals, extrusion, feed, path_id, layer)
