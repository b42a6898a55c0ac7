"""RoboFDM decomposition benchmark: rows beside the thesis's Table 2.1, and nozzle placement.

Table 2.1 (:data:`benchmarks.paper.TABLE_2_1`): bunny 10,000 facets decomposed in 171 s, armadillo
17,142 in 269 s, hanging-ball 5,984 in 156 s; fabrication 152, 263, 85 min. Here the shape analysis
runs on a simplified copy (about the thesis's facet count) and the parts are cut from the full
mesh, so the row gives both counts; the fabrication time is the printed tool-paths' length at the
workcell's speeds (``--print``: every part sliced and planned, minutes of work).

``python benchmarks/bench_decompose.py [MODEL ...] [--print] [--placement]`` prints one row per model
(wall and CPU seconds by phase, parts, risky area per part with its share on the model's underside,
Constraint I/II violations) with the load average, the Table 2.1 lines, and with ``--placement`` the
UR3/UR5 nozzle placement (1 M configurations). :func:`decomposition_case` and
:func:`table_2_1_lines` are what a suite report calls (a dict per model, Markdown lines).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.paper import TABLE_2_1
from curvslice.decompose import decompose, write_decomposition
from curvslice.decompose.placement import place_nozzle
from curvslice.kinematics import load_robot
from curvslice.solid import load_solid
from curvslice.workcell import load_workcell

MODELS = Path(__file__).resolve().parents[2] / "shared" / "models"


def fabrication_minutes(folder: Path, workcell: str = "ur3") -> float:
    """Printing time (min) of a printed decomposition folder's ``toolpaths.npz``: every step at the
    G-code feed inside a path and the workcell's travel speed between paths
    (:func:`curvslice.motion.segment_speeds`); the robot's re-orientation between parts left out."""
    from curvslice.motion import segment_speeds

    with np.load(Path(folder) / "toolpaths.npz") as z:
        positions, path, feed = z["positions"], z["path"], z["feed"]
    step = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    return float((step / segment_speeds(path, feed, load_workcell(workcell))).sum() / 60.0)


def decomposition_case(path: Path, print_parts: bool = False, voxel: float = 1.0) -> dict:
    """One Table 2.1 row: facets, decomposition wall and CPU seconds (by phase), parts, risky area per
    part (and on the underside), constraint violations, volume error, load; with ``print_parts`` the
    planar layers and tool-paths of every part and the fabrication minutes."""
    from curvslice.decompose.printing import print_decomposition

    solid, _ = load_solid(path)
    load = os.getloadavg()[0]
    cpu, wall = time.process_time(), time.perf_counter()
    dec = decompose(solid)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    risky = [p.risky_area for p in dec.parts]
    row = {"model": path.stem, "facets": len(solid.faces), "analysis_faces": dec.analysis_faces,
           "wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "loadavg": round(load, 2),
           "phases_s": {k: round(v, 2) for k, v in dec.timings.items()}, "parts": len(dec.parts),
           "risky_mm2": [round(a, 2) for a in risky], "underside_mm2": [round(p.risky_underside, 2) for p in dec.parts],
           "support_free": sum(a <= 1.0 for a in risky),
           "support_free_beyond_underside": sum(a - p.risky_underside <= 1.0 for a, p in zip(risky, dec.parts)),
           "constraint_one": dec.constraint_one_violations(), "constraint_two": dec.constraint_two_violations(),
           # parts with a sampled nozzle position where no turn of the UR3 extruder clears the earlier parts
           "extruder_blocked_parts": sum(b > 0 for b, _ in dec.extruder_blocked),
           "volume_error": abs(sum(p.mesh.volume for p in dec.parts) - solid.volume) / solid.volume}
    if print_parts:
        with tempfile.TemporaryDirectory() as tmp:
            write_decomposition(dec, Path(tmp), str(path), solid)
            start = time.perf_counter()
            sections = print_decomposition(Path(tmp), voxel, meshes=[p.mesh for p in dec.parts])
            row.update(print_s=round(time.perf_counter() - start, 1), layers=sections["layers"]["count"],
                       samples=sections["toolpaths"]["samples"], fabrication_min=round(fabrication_minutes(Path(tmp)), 1))
    return row


def table_2_1_lines(rows: list[dict]) -> list[str]:
    """Markdown: our rows beside Table 2.1 (ratio = ours / thesis; the thesis's machine is not stated)."""
    lines = ["## Beside the thesis, Table 2.1 (RoboFDM decomposition)", "",
             "Thesis: facets of the decomposed model, decomposition and fabrication time (machine not stated). Ours: "
             "the full mesh's faces (shape analysis on the simplified copy's), wall and CPU seconds with the load "
             "average, parts, parts support-free (risky area ≤ 1 mm²; in brackets: beyond the model's underside), "
             "fabrication = the printed tool-paths at the UR3 cell's speeds.", "",
             "| model | figure | thesis | ours | ratio |", "|---|---|---|---|---|"]
    for r in rows:
        ref = TABLE_2_1.get(r["model"], {})
        rat = (lambda ours, key: f"{ours / ref[key]:.2f}" if key in ref and ours is not None else "–")
        m = r["model"]
        facets = f"{ref['facets']:,}" if ref else "–"
        lines += [f"| {m} | facets | {facets} | {r['facets']:,} ({r['analysis_faces']:,} analysed) | – |",
                  f"| {m} | decomposition s | {ref.get('decomposition', '–')} | {r['wall_s']:.1f} wall, {r['cpu_s']:.1f} CPU "
                  f"(load {r['loadavg']:.1f}) | {rat(r['wall_s'], 'decomposition')} |",
                  f"| {m} | parts (support-free) | – | {r['parts']} ({r['support_free']}; "
                  f"{r['support_free_beyond_underside']}) | – |",
                  f"| {m} | Constraint I / II violations | – | {len(r['constraint_one'])} / {len(r['constraint_two'])} | – |",
                  f"| {m} | parts the extruder cannot reach | – | {r.get('extruder_blocked_parts', '–')} | – |"]
        if "fabrication_min" in r:
            lines.append(f"| {m} | fabrication min | {ref.get('fabrication_min', '–')} | {r['fabrication_min']:.0f} "
                         f"({r['samples']:,} samples, {r['layers']} layers) | {rat(r['fabrication_min'], 'fabrication_min')} |")
    return lines + [""]


def placement_rows(samples: int) -> None:
    for name, min_radius in (("ur3", 0.0), ("ur3", 200.0), ("ur5", 0.0), ("ur5", 300.0)):
        start = time.perf_counter()
        _, reach = place_nozzle(load_robot(name), load_workcell(name), samples=samples, min_radius=min_radius)
        centre, count = reach.best
        print(f"placement {name} (min radius {min_radius:g} mm): {samples:,} samples, {reach.frames:,} frames kept, "
              f"nozzle at {np.round(centre, 1).tolist()} mm with {count:,} frames in the 100 mm box "
              f"({time.perf_counter() - start:.1f} s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("models", nargs="*", type=Path, default=[MODELS / "bunny.stl"])
    parser.add_argument("--print", action="store_true", dest="print_parts",
                        help="also slice and plan every part (fabrication time)")
    parser.add_argument("--placement", action="store_true", help="also time the UR3/UR5 nozzle placement")
    parser.add_argument("--samples", type=int, default=1_000_000)
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    rows = []
    for path in args.models:
        r = decomposition_case(path, args.print_parts)
        rows.append(r)
        print(f"{r['model']}: {r['facets']:,} faces (analysis copy {r['analysis_faces']:,}); decomposition "
              f"{r['wall_s']:.1f} s wall, {r['cpu_s']:.1f} s CPU at load {r['loadavg']:.2f}")
        print("  phases (s): " + ", ".join(f"{k} {v:.2f}" for k, v in r["phases_s"].items()))
        print(f"  {r['parts']} parts; risky area per part (mm²): " + ", ".join(f"{a:.1f}" for a in r["risky_mm2"])
              + "; of it on the underside: " + ", ".join(f"{a:.1f}" for a in r["underside_mm2"]))
        print(f"  support-free (≤ 1 mm²): {r['support_free']}/{r['parts']}, beyond the underside: "
              f"{r['support_free_beyond_underside']}/{r['parts']}; Constraint I violations: {r['constraint_one']}, "
              f"Constraint II violations: {r['constraint_two']}, volume error {r['volume_error']:.2e}; "
              f"parts the extruder cannot reach: {r['extruder_blocked_parts']}")
    print("\n".join(table_2_1_lines(rows)))
    if args.placement:
        placement_rows(args.samples)


if __name__ == "__main__":
    main()
