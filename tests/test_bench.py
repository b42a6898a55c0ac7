"""The benchmark suite: its measuring (repetitions, budget, memory), its arithmetic (sweep exponents,
ratios to the thesis) and a real ``curvslice bench --quick`` run whose outputs are cross-checked."""

from __future__ import annotations

import json
import re
import time

import numpy as np
import pytest
from matplotlib.image import imread

from benchmarks.paper import AUTHORS_CPP, TABLE_3_1
from benchmarks.run import DERIVED, STAGE_LABELS, Recorder, StageTimeout, _fmt, markdown, robot_subset, sweep_exponent
from curvslice.cli import main


def test_recorder_repeats_within_budget_and_measures_memory():
    rec = Recorder(repeat=3, budget=10.0, quiet=True)
    calls = []
    assert rec.run("a", lambda: calls.append(time.sleep(0.02)) or len(calls)) == 3
    s = rec.stages["a"].summary()
    assert s["reps"] == 3 and s["min_s"] >= 0.02 and s["min_s"] <= s["median_s"] <= s["max_s"]
    rec = Recorder(repeat=5, budget=0.03, quiet=True)
    rec.run("slow", lambda: time.sleep(0.05))
    assert rec.stages["slow"].summary()["reps"] == 1  # over budget after one run
    rec = Recorder(repeat=1, quiet=True)
    rec.run("alloc", lambda: np.ones(40_000_000).sum())  # 320 MB, freed at once
    peak = rec.stages["alloc"].summary()["peak_above_start_mb"]
    if peak is None:
        pytest.skip("no /proc/self/clear_refs here")
    assert 250 < peak < 1000


def test_recorder_stops_a_stage_at_the_time_limit():
    rec = Recorder(repeat=3, timeout=0.2, quiet=True)
    t0 = time.perf_counter()
    with pytest.raises(StageTimeout):
        rec.run("stuck", lambda: time.sleep(30))
    assert time.perf_counter() - t0 < 5
    s = rec.stages["stuck"].summary()
    assert s["reps"] == 0 and s["median_s"] is None and s["timeout_s"] == 0.2
    assert rec.run("next", lambda: 7) == 7  # the alarm is off again


def test_sweep_exponent_recovers_a_power_law():
    sweep = [{"counts": {"voxels": v}, "stages": {"x": {"median_s": 0.003 * v**1.5}}} for v in (1e3, 4e3, 2e4)]
    assert sweep_exponent(sweep, "x") == pytest.approx(1.5)
    assert sweep_exponent(sweep[:1], "x") is None


def test_robot_subset_takes_whole_first_layers():
    class TP:
        layer = np.repeat([1, 2, 3, 4], [10, 30, 5, 50])

    assert len(robot_subset(TP, 35)) == 40  # layers 1-2: the first to reach 35 waypoints
    assert len(robot_subset(TP, 10)) == 10
    assert len(robot_subset(TP, 10_000)) == 95


def _fake_case(model: str, voxel: float, scale: float) -> dict:
    """A case whose every time is ``scale`` × the thesis's (or the authors') figure."""
    ref, cpp = TABLE_3_1[model], AUTHORS_CPP[(model, 1.0, "pg-sp-gcfa")]
    t = {"peeling": ref["peeling"] * scale, "growing_pg-sp-gcfa": (ref["total"] - ref["peeling"]) * scale,
         "surfaces": ref["surfaces"] * scale, "toolpaths": ref["toolpaths"] * scale,
         "trimming": cpp["trimming"] * scale}
    stages = {k: {"times_s": [v], "reps": 1, "median_s": v, "min_s": v, "max_s": v, "peak_rss_mb": 100.0,
                  "peak_above_start_mb": 1.0} for k, v in t.items()}
    counts = {"voxels": ref["voxels"], "pg-sp-gcfa": {"layers": 90, "missed": 0, "shadow_tests": 1},
              "surfaces": {"layers": 90, "empty": 0, "triangles": 1}}
    return {"model": model, "voxel_mm": voxel, "counts": counts, "stages": stages}


def test_markdown_puts_the_papers_figures_beside_ours_with_ratios():
    machine = {"cpu": "x", "nproc": 2, "memory_gb": 1, "python": "3", "numpy": "2", "scipy": "1", "trimesh": "4",
               "platform": "p", "loadavg_start": [0.1, 0, 0], "loadavg_end": [0.1, 0, 0]}
    result = {"suite": "full", "machine": machine, "wall_s": 1.0, "standard": [_fake_case("bunny", 1.0, 2.0)], "sweep": [],
              "settings": {"repeat": 1, "budget_s": 1, "methods": ["pg-sp-gcfa"], "robot": None, "robot_waypoints": 1}}
    md = markdown(result)
    row = next(line for line in md.splitlines() if "| decomposition total s |" in line)
    assert row.split("|")[3].strip() == "204" and row.split("|")[5].strip() == "2.00"  # 203.90 s in Table 3.1
    assert re.search(r"\| working surfaces s \| 889 \| 1,777 \| 2\.00 \|", md)
    cpp = next(line for line in md.splitlines() if line.startswith("| bunny @1 mm, pg-sp-gcfa"))
    assert "363 / 726 (2.00)" in cpp  # trimming: the authors' 362.8 s
    assert "shared during the run" not in md


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    assert main(["bench", "--quick", "--repeat", "1", "--out", str(out), "--quiet"]) == 0
    return out, json.loads((out / "results.json").read_text())


def test_quick_bench_times_every_stage(quick_run):
    out, result = quick_run
    assert [c["model"] for c in result["standard"]] == ["tee", "arch"]
    for case in result["standard"]:
        threads = case["threads"]  # (the one-thread row is timed when the suite's stages run on several)
        assert set(case["stages"]) == set(STAGE_LABELS) - ({"toolpaths_one_thread"} if threads == 1 else set())
        for st in case["stages"].values():
            assert st["reps"] >= 1 and 0 < st["median_s"] < 120
        s = {k: v["median_s"] for k, v in case["stages"].items()}
        # parts the library reports inside a stage (summed task times) never exceed its wall time on each thread
        assert s["dual_contouring"] + s["trimming"] <= s["surfaces"] * threads * 1.01
        assert s["spirals"] + s["orientation"] <= s["toolpaths"] * threads * 1.01
        n = case["counts"]
        assert n["pg-sp-gcfa"]["missed"] == 0  # the repository models are printable without misses
        assert n["surfaces"]["layers"] >= n["pg-sp-gcfa"]["layers"] - 1
        assert n["robot"]["waypoints"] >= 150 and n["robot"]["rows"] <= n["robot"]["waypoints"]
    sweep = result["sweep"]
    sizes = [c["voxel_mm"] for c in sweep]
    voxels = [c["counts"]["voxels"] for c in sweep]
    assert sizes == sorted(sizes, reverse=True) and voxels == sorted(voxels) and len(set(voxels)) == len(voxels)


def test_quick_bench_writes_markdown_and_plot(quick_run):
    out, result = quick_run
    md = (out / "RESULTS.md").read_text()
    for case in result["standard"]:
        assert f"{case['model']} @{case['voxel_mm']:g} mm" in md
    for key, label in STAGE_LABELS.items():
        if key == "toolpaths_one_thread" and result["settings"]["threads"] == 1:
            continue
        assert f"| {label} |" in md, label
        if key not in DERIVED:
            assert sum(line.startswith(f"| {label} |") for line in md.splitlines()) >= 2  # times + memory
    assert "Table 3.1" in md and "Table 4.2" in md and "Size sweep" in md and "Not yet implemented" in md
    # the 1 vs N row: both timings of each case and their ratio (the arrays were checked equal by the run)
    for case in result["standard"]:
        one, two = case["stages"]["toolpaths"]["median_s"], case["stages"]["toolpaths_workers"]["median_s"]
        assert case["workers"] == 2 and f"| {_fmt(one)} | {_fmt(two)} | {one / two:.2f}× |" in md
    img = imread(out / "results.png")[..., :3]
    assert img.shape[0] > 400 and img.shape[1] > 1000
    assert (img.std(axis=2) > 0.1).mean() > 0.01  # coloured bars and lines, not a blank canvas


def test_bench_refuses_unknown_models_in_one_line(capsys, tmp_path):
    assert main(["bench", "--quick", "--models", "bunny", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "choose from tee, arch" in err[0]


def test_verify_table_locates_missed_voxels(tmp_path):
    """benchmarks/bench_verify.missed_voxels on a hand-made field: a 2-voxel pocket inside the block and
    one missed voxel in its bottom row are two pieces, the second on ∂H̄ and on the platform."""
    from benchmarks.bench_verify import missed_voxels

    occupied = np.zeros((8, 8, 8), bool)
    occupied[1:7, 1:7, 0:6] = True
    growing = np.where(occupied, 1 + np.arange(8)[None, None, :], 0)
    growing[3, 3, 2:4] = 0  # enclosed pocket between layers 2 and 5
    growing[1, 4, 0] = 0  # bottom row, on the side of the block
    disc = np.array([[x, y, z] for x in (-20.0, 20.0) for y in (-20.0, 20.0) for z in (-10.0, 0.0)])
    np.savez(tmp_path / "field.npz", occupied=occupied, growing=growing, origin=np.array([0.0, 0.0, 0.5]), voxel_size=1.0,
             platform_vertices=disc)
    found = missed_voxels(tmp_path)
    assert found["missed"] == 3 and found["voxels"] == 216 and found["layers"] == 6
    pocket, corner = found["pieces"]
    # the pocket's lower voxel could first rest on layer 2 (z = 1.5 mm), whose front C(layers ≤ 2 ∪ T) is
    # the slab up to z = 1.5: it lies 1 w above it (depth -1 w: accessible); the upper one rests on layer
    # 3 beside it, 1 w above that front too
    assert {k: pocket[k] for k in ("size", "z_mm", "on_surface", "on_platform", "layers_around")} == {
        "size": 2, "z_mm": [2.5, 3.5], "on_surface": 0, "on_platform": False, "layers_around": [2, 5]}
    assert pocket["first_support"] == 2 and pocket["unsupported"] == 0 and pocket["depth_w"] == [-1.0, -1.0]
    assert corner["size"] == 1 and corner["on_surface"] == 1 and corner["on_platform"] and corner["layers_around"] == [1, 2]
    assert corner["first_support"] == 1


def test_verify_section_is_spliced_into_results_md(tmp_path):
    from benchmarks.bench_verify import SECTION, Case, cases, markdown, splice

    run = {"model": "kitten", "voxel_mm": 0.8, "title": Case("kitten", 0.8).title, "slice_s": 1.0, "verify_s": 2.0,
           "cross_check_s": 0.5, "passed": False,
           "failed": [{"check": "toolpaths/overlap", "value": "max 6.1% (layer 18)", "detail": "", "layers": [8, 18]}],
           "coverage": {"percent": 96.0, "layer": 4, "failing": []},
           "overlap": {"percent": 6.1, "layer": 18, "failing": [8, 18]},
           "field": {"voxels": 100, "layers": 9, "missed": 1, "pieces": [
               {"size": 1, "z_mm": [0.4, 0.4], "on_surface": 1, "on_platform": True, "layers_around": [1, 1]}]},
           "inside": {"vertices": 10, "disagree": 0, "layers": [], "max_w": 0.0, "winding_alone": 0, "winding_alone_layers": []}}
    md = markdown([run], {"command": "curvslice bench --verify-only", "commit": "abc", "date": "d", "load": "1"})
    row = next(line for line in md.splitlines() if line.startswith("| kitten @0.8 mm |"))
    assert "| 1 (0) **above C++** |" in row and "| 0 / 2 |" in row and row.endswith("**FAIL** |")
    assert "- kitten @0.8 mm: toolpaths/overlap max 6.1% (layer 18) — layers 8, 18" in md
    target = tmp_path / "RESULTS.md"
    target.write_text("# r\n\n## A\n\na\n\n## Not yet implemented\n\n- x\n")
    splice(target, md)
    once = target.read_text()
    assert once.index("## A") < once.index(SECTION) < once.index("## Not yet implemented")
    splice(target, md.replace("commit abc", "commit xyz"))  # a refresh replaces the section, nothing else
    again = target.read_text()
    assert again.count(SECTION) == 1 and "commit xyz" in again and "commit abc" not in again
    assert again.replace("commit xyz", "commit abc") == once
    assert [c.title for c in cases(("kitten",))] == ["kitten @0.8 mm", "kitten @1 mm", "kitten @1.6 mm", "kitten @2 mm",
                                                     "kitten @0.8 mm, path 0.6 w", "kitten @0.8 mm, path 1.5 w"]


def test_corpus_section_counts_passes_per_voxel_and_sits_beside_the_verify_table(tmp_path):
    from benchmarks.bench_corpus import SECTION, markdown
    from benchmarks.bench_verify import SECTION as VERIFY, splice

    runs = [{"solid": "cup", "voxel": 1.0, "failed": ["overlap: max 5.5% (layer 13)"], "seconds": 1.0},
            {"solid": "arch", "voxel": 1.0, "failed": [], "seconds": 1.0},
            {"solid": "arch", "voxel": 0.8, "failed": [], "seconds": 1.0}]
    md = markdown(runs, {"command": "python -m benchmarks.bench_corpus", "commit": "abc", "date": "d", "load": "1",
                         "load_end": "1", "jobs": "1"})
    rows = [line for line in md.splitlines() if line.startswith("| 1 mm") or line.startswith("| 0.8 mm")]
    assert rows == ["| 1 mm | 1 of 2 | cup: overlap: max 5.5% (layer 13) |", "| 0.8 mm | 1 of 1 | – |"]
    target = tmp_path / "RESULTS.md"
    target.write_text(f"# r\n\n{VERIFY}\n\nv\n\n## Not yet implemented\n\n- x\n")
    splice(target, md, SECTION)
    splice(target, md.replace("commit abc", "commit xyz"), SECTION)
    text = target.read_text()
    assert text.count(SECTION) == 1 and "commit xyz" in text and f"{VERIFY}\n\nv\n" in text
    assert text.index(VERIFY) < text.index(SECTION) < text.index("## Not yet implemented")
