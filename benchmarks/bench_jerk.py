"""Jerk stage benchmark (thesis §4.3.2, Table 4.2, Figs. 4.3/4.4) on the first layers of a slice folder.

Plans the first ``--layers`` layers of ``SLICE/toolpaths.npz`` with the graph search (§4.3.1, lazy
fcl, the part = union of the earlier layers), then writes both trajectories next to each other,
``OUT/graph`` (as searched) and ``OUT/jerk`` (jerk-optimized, limits by time-scaling, Ruckig moves),
each with joints.csv, programs and the files ``curvslice verify`` reads, and prints: max |q⃛| and
total squared jerk J (Eq. 4.2) of both with the reductions (thesis: 83.6-95.8 % and 99.4 %), rows over
the workcell's a_max / j_max, print time added by the time-scaling, FK error of every row, and the
jerk stage's time per 1,000 waypoints (thesis: 30 s for 2,545).

Run: ``python benchmarks/bench_jerk.py /work/data/kitten08 --layers 10 --out /tmp/kitten10``; Table 4.2's
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
from curvslice.collision import CollisionScene
from curvslice.exporters.joints_csv import write_robot_outputs
from curvslice.jerk import trajectory_stage
from curvslice.kinematics import fk_reference, load_robot
from curvslice.motion import plan_print
from curvslice.verify import robot as verify_robot
from curvslice.workcell import load_workcell, waypoints_from_flange


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("slice", type=Path, help="a `curvslice slice` folder with toolpaths.npz, layers/, field.npz")
    ap.add_argument("--layers", type=int, default=10, help="plan layers 1..LAYERS")
    ap.add_argument("--waypoints", type=int, help="instead: the first whole layers reaching this many waypoints")
    ap.add_argument("--robot", default="ur5")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    with np.load(a.slice / "toolpaths.npz") as f:
        if a.waypoints:
            a.layers = int(f["layer"][robot_subset(SimpleNamespace(layer=f["layer"]), a.waypoints)].max())
        keep = f["layer"] <= a.layers
        tp = {k: f[k][keep] for k in f.files}
    layers = [trimesh.load(p, force="mesh") for p in sorted((a.slice / "layers").glob("layer_*.ply"))]
    with np.load(a.slice / "field.npz") as f:
        platform = f["platform_vertices"]
    cell, robot = load_workcell(a.robot), load_robot(a.robot)
    scene = CollisionScene(robot, cell, platform)
    start = time.perf_counter()
    graph = plan_print(robot, cell, tp, lambda layer: scene.for_layer(layers, layer))
    search = time.perf_counter() - start
    reports = {}
    for kind in ("graph", "jerk"):
        start, cpu = time.perf_counter(), time.process_time()
        motion, rep = trajectory_stage(robot, cell, tp, graph, kind, lambda layer: scene.for_layer(layers, layer))
        rep["stage_s"], rep["stage_cpu_s"] = time.perf_counter() - start, time.process_time() - cpu
        out = a.out / kind
        if out.exists():
            shutil.rmtree(out)
        (out / "layers").mkdir(parents=True)
        np.savez(out / "toolpaths.npz", **tp)
        for p in sorted((a.slice / "layers").glob("layer_*.ply"))[: a.layers]:
            shutil.copy(p, out / "layers" / p.name)
        for name in ("field.npz", "solid.stl"):
            shutil.copy(a.slice / name, out / name)
        write_robot_outputs(out, cell, robot.family, tp, motion)
        pos, axis = waypoints_from_flange(cell, fk_reference(robot, motion.q))
        rep["fk_position_error_mm"] = float(np.linalg.norm(pos - tp["positions"][motion.index], axis=1).max())
        rep["fk_axis_error_rad"] = float(np.abs(axis - motion.normals).max())
        rep.pop("layers", None)
        rep["verify_failed"] = [c.name for c in verify_robot.checks(out) if not c.passed]
        (out / "jerk_report.json").write_text(json.dumps(rep, indent=1))
        reports[kind] = rep
    g, j = reports["graph"]["before"], reports["jerk"]["after"]
    n = len(graph.q)
    red_max = 100 * (1 - np.array(j["max_jerk"]) / np.array(g["max_jerk"]))
    print(f"{n} waypoints, {int(graph.segment.max()) + 1} segments; graph search {search:.1f} s")
    print(f"max |jerk| per joint: graph {g['max_jerk']} -> jerk {j['max_jerk']} rad/s³ "
          f"(-{red_max.min():.1f} to -{red_max.max():.1f} %)")
    print(f"max |acc| per joint: graph {g['max_acceleration']} -> jerk {j['max_acceleration']} rad/s²")
    print(f"J (Eq. 4.2): graph {g['total_squared_jerk']:.4g} -> jerk {j['total_squared_jerk']:.4g} "
          f"(-{100 * (1 - j['total_squared_jerk'] / g['total_squared_jerk']):.2f} %)")
    r = reports["jerk"]
    print(f"print time {g['time_s']:.1f} s -> {j['time_s']:.1f} s; time-scaling added {r['time_scaling_added_s']} s "
          f"({r['time_scaling_added_pct']} % of the printing steps); Ruckig moves {r['moves_s']} s")
    print(f"jerk stage {r['stage_s']:.2f} s wall, {r['stage_cpu_s']:.2f} s CPU = {1000 * r['stage_cpu_s'] / n:.2f} s CPU "
          f"per 1,000 waypoints (load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores) "
          f"(filter {r['seconds_filter']} s, {r['collision_checks']} fcl checks, {r['rows_reverted_for_collision']} rows put back)")
    print(f"Table 4.2 (WS1, 2,545 waypoints: init 86 s + optm 30 s): graph search {search:.2f} s + jerk stage "
          f"{r['stage_s']:.2f} s = {search + r['stage_s']:.2f} s for {n} waypoints")
    print(f"FK error: {r['fk_position_error_mm']:.2e} mm, {r['fk_axis_error_rad']:.2e} rad; tilt max {r['max_tilt_deg']} deg")
    print(f"verify failed: graph {reports['graph']['verify_failed']}, jerk {r['verify_failed']}")


if __name__ == "__main__":
    main()
