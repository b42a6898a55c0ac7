"""`curvslice sweep`: one folder per model × setting, a CSV row each, failures recorded not raised."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from curvslice.cli import main

TEE = Path(__file__).resolve().parents[1] / "models" / "tee.stl"


def test_sweep_writes_a_folder_and_a_row_per_run_and_records_failures(tmp_path):
    broken = tmp_path / "broken.stl"
    broken.write_text("solid nothing\nendsolid nothing\n")
    out = tmp_path / "runs"
    code = main(["sweep", str(TEE), str(broken), "--grid", "voxel=2,3", "--grid", "method=pg-sp-gcfa",
                 "--stages", "field", "--out", str(out)])
    assert code == 1  # the broken model's runs failed, and the sweep says so
    rows = list(csv.DictReader(open(out / "sweep.csv")))
    assert [(r["model"], float(r["voxel"]), r["method"]) for r in rows] == [
        ("tee", 2.0, "pg-sp-gcfa"), ("tee", 3.0, "pg-sp-gcfa"), ("broken", 2.0, "pg-sp-gcfa"), ("broken", 3.0, "pg-sp-gcfa")]
    for r in rows[:2]:
        assert r["status"] == "ok" and r["verify"] == "PASS" and not r["error"]
        with np.load(Path(r["folder"]) / "field.npz") as z:  # the row's counts are the folder's
            assert int(r["voxels"]) == int(z["occupied"].sum())
            assert float(z["voxel_size"]) == float(r["voxel"]) and str(z["method"]) == "pg-sp-gcfa"
        assert float(r["growing_s"]) > 0 and float(r["total_s"]) >= float(r["growing_s"])
    assert int(rows[0]["voxels"]) > int(rows[1]["voxels"])  # finer voxels, more of them
    for r in rows[2:]:
        assert r["status"] == "failed" and "broken.stl" in r["error"] and not Path(r["folder"]).exists()
