"""Robot-program writers read back by their readers, plus independent checks of the written text."""

from __future__ import annotations

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
