"""Jerk stage benchmark (thesis §4.3.2, Table 4.2, Figs. 4.3/4.4) on the first layers of a slice folder.

Runs the robot stage itself (:func:`curvslice.robot_stage.plan_robot`: graph search per layer, jerk filter,
time-scaling and Ruckig moves per block of layers) on the first ``--layers`` layers of ``SLICE/toolpaths.npz``,
then writes both trajectories of that one search next to each other, ``OUT/graph`` (as searched,
``--trajectory graph``) and ``OUT/jerk`` (the default), each with joints.csv, programs and the files
``curvslice verify`` reads, and prints: max |q̈| and |q⃛| and total squared jerk J (Eq. 4.2) of both with the
reductions (thesis: 83.6-95.8 % and 99.4 %) against the workcell's a_max / j_max, print time added by the
time-scaling, skipped waypoints with their reasons, FK error of every row, the verifier's failed robot
checks, and the seconds of the graph search and of the jerk stage (Table 4.2: 86 s + 30 s for 2,545).

Run: ``python -m benchmarks.bench_jerk /work/data/k08 --layers 10 --out /tmp/kitten10``; Table 4.2's
size: ``--waypoints 2545`` (the first whole layers reaching 2,545 waypoints, as ``curvslice bench``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import trimesh

from benchmarks.run import robot_subset
from curvslice.exporters.joints_csv import write_robot_outputs
from curvslice.kinematics import fk_reference, load_robot
from curvslice.robot_stage import plan_robot
from curvslice.verify import robot as verify_robot
from curvslice.workcell import load_workcell, waypoints_from_flange


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("slice", type=Path, help="a `curvslice slice` folder with toolpaths.npz, layers/, field.npz")
    ap.add_argument("--layers", type=int, default=10, help="plan layers FROM..LAYERS")
    ap.add_argument("--from-layer", type=int, default=1, help="first layer planned (the earlier ones are obstacles only)")
    ap.add_argument("--waypoints", type=int, help="instead: the first whole layers reaching this many waypoints")
    ap.add_argument("--robot", default="ur5")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    with np.load(a.slice / "toolpaths.npz") as f:
        if a.waypoints:
            a.layers = int(f["layer"][robot_subset(SimpleNamespace(layer=f["layer"]), a.waypoints)].max())
        keep = (f["layer"] >= a.from_layer) & (f["layer"] <= a.layers)
        tp = {k: f[k][keep] for k in f.files}
    layer_files = sorted((a.slice / "layers").glob("layer_*.ply"))
    layers = [trimesh.load(p, force="mesh") for p in layer_files]
    with np.load(a.slice / "field.npz") as f:
        platform = f["platform_vertices"]
    cell, robot = load_workcell(a.robot), load_robot(a.robot)
    start, cpu = time.perf_counter(), time.process_time()
    graph, final, report = plan_robot(cell, tp, layers, platform, trajectory="jerk")
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    search = sum(s["seconds"] for s in graph.layers)  # plan_layer's own clock, per layer
    jerk_s = report["seconds"]
    verdict = {}
    for kind, motion in (("graph", graph), ("jerk", final)):
        out = a.out / kind
        if out.exists():
            shutil.rmtree(out)
        (out / "layers").mkdir(parents=True)
        np.savez(out / "toolpaths.npz", **tp)
        for p in layer_files[: a.layers]:
            shutil.copy(p, out / "layers" / p.name)
        for name in ("field.npz", "solid.stl"):
            shutil.copy(a.slice / name, out / name)
        write_robot_outputs(out, cell, robot.family, tp, motion)
        pos, axis = waypoints_from_flange(cell, fk_reference(robot, motion.q))
        checks = verify_robot.checks(out)
        verdict[kind] = {"fk_position_error_mm": float(np.linalg.norm(pos - tp["positions"][motion.index], axis=1).max()),
                         "fk_axis_error_rad": float(np.abs(axis - motion.normals).max()),
                         "verify_failed": [c.name for c in checks if not c.passed],
                         "verify": {c.name: c.value for c in checks}}
    skipped = [r for s in graph.layers for r in s.get("skipped_rows", [])]
    summary = {k: v for k, v in report.items() if k != "layers"}
    summary.update(waypoints=int(len(tp["positions"])), rows=int(len(final.q)), layers=a.layers, wall_s=wall, stage_cpu_s=cpu,
                   graph_search_s=search, jerk_stage_s=jerk_s, load=os.getloadavg()[0], skipped_rows=skipped,
                   verdict=verdict, per_layer=report["layers"])
    (a.out / "bench_jerk.json").write_text(json.dumps(summary, indent=1, default=float))
    g, j = report["before"], report["after"]
    n = len(tp["positions"])
    lim = report["limits"]
    red_max = 100 * (1 - np.array(j["max_jerk"]) / np.array(g["max_jerk"]))
    print(f"{n} waypoints on layers {a.from_layer}-{a.layers}, {len(final.q)} rows realized, {len(skipped)} skipped; "
          f"graph {int(graph.segment.max()) + 1} segments, jerk {int(final.segment.max()) + 1} (jumps become Ruckig moves)")
    for r in skipped:
        print(f"  skipped row {r['row']} (layer {r['layer']}): {r['reason']}")
    print(f"max |jerk| per joint: graph {g['max_jerk']} -> jerk {j['max_jerk']} rad/s³ (j_max {lim['jerk']}; "
          f"-{red_max.min():.1f} to -{red_max.max():.1f} %, max over joints -{100 * (1 - max(j['max_jerk']) / max(g['max_jerk'])):.2f} %)")
    print(f"max |acc| per joint: graph {g['max_acceleration']} -> jerk {j['max_acceleration']} rad/s² (a_max {lim['acceleration']})")
    print(f"J (Eq. 4.2): graph {g['total_squared_jerk']:.4g} -> jerk {j['total_squared_jerk']:.4g} "
          f"(-{100 * (1 - j['total_squared_jerk'] / g['total_squared_jerk']):.3f} %)")
    print(f"print time {g['time_s']:.1f} s -> {j['time_s']:.1f} s ({100 * (j['time_s'] / g['time_s'] - 1):+.2f} %); time-scaling "
          f"added {report['time_scaling_added_s']} s ({report['time_scaling_added_pct']} % of the steps inside segments); "
          f"Ruckig moves {report['moves_s']} s")
    print(f"robot stage {wall:.2f} s wall ({cpu:.2f} s CPU, load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores): "
          f"graph search {search:.2f} s + jerk stage {jerk_s:.2f} s ({report['cpu_s']:.2f} s CPU; filter {report['seconds_filter']} s, "
          f"{report['collision_checks']} fcl checks, {report['rows_projected']} rows projected (Eq. 4.13), "
          f"{report['rows_reverted_for_collision']} put back); Table 4.2 (2,545 waypoints): 86 s + 30 s")
    v = verdict["jerk"]
    print(f"FK error: {v['fk_position_error_mm']:.2e} mm, {v['fk_axis_error_rad']:.2e} rad; tilt max {report['max_tilt_deg']} deg")
    print(f"verify failed: graph {verdict['graph']['verify_failed']}, jerk {v['verify_failed']}")


if __name__ == "__main__":
    main()
