"""RoboFDM decomposition benchmark: rows beside the thesis's Table 2.1, and nozzle placement.

Table 2.1 (C++, the thesis's machine): bunny 10,000 facets decomposed in 171 s, armadillo 17,142
in 269 s, hanging-ball 5,984 in 156 s. Here the shape analysis runs on a simplified copy (about
the thesis's facet count) and the parts are cut from the full mesh, so the row gives both counts.

``python benchmarks/bench_decompose.py [MODEL ...] [--placement]`` prints one row per model (wall
and CPU seconds by phase, parts, risky area per part, Constraint I/II violations) with the load
average, and with ``--placement`` the UR3/UR5 nozzle placement (1 M configurations).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from curvslice.decompose import decompose
from curvslice.decompose.placement import place_nozzle
from curvslice.kinematics import load_robot
from curvslice.solid import load_solid
from curvslice.workcell import load_workcell

THESIS_TABLE_2_1 = {"bunny": (10_000, 171.0), "armadillo": (17_142, 269.0), "hanging-ball": (5_984, 156.0)}
MODELS = Path(__file__).resolve().parents[2] / "shared" / "models"


def decomposition_row(path: Path) -> None:
    solid, _ = load_solid(path)
    cpu, wall = time.process_time(), time.perf_counter()
    dec = decompose(solid)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    ref = THESIS_TABLE_2_1.get(path.stem)
    risky = [p.risky_area for p in dec.parts]
    print(f"{path.stem}: {len(solid.faces):,} faces (analysis copy {dec.analysis_faces:,}); "
          f"decomposition {wall:.1f} s wall, {cpu:.1f} s CPU"
          + (f" (thesis: {ref[0]:,} facets, {ref[1]:.0f} s)" if ref else ""))
    print("  phases (s): " + ", ".join(f"{k} {v:.2f}" for k, v in dec.timings.items()))
    print(f"  {len(dec.parts)} parts; risky area per part (mm²): " + ", ".join(f"{a:.1f}" for a in risky)
          + f"; support-free (≤ 1 mm²): {sum(a <= 1.0 for a in risky)}/{len(risky)}")
    print(f"  Constraint I violations: {dec.constraint_one_violations()}, "
          f"Constraint II violations: {dec.constraint_two_violations()}, "
          f"volume error {abs(sum(p.mesh.volume for p in dec.parts) - solid.volume) / solid.volume:.2e}")


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
    parser.add_argument("--placement", action="store_true", help="also time the UR3/UR5 nozzle placement")
    parser.add_argument("--samples", type=int, default=1_000_000)
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    for path in args.models:
        decomposition_row(path)
    if args.placement:
        placement_rows(args.samples)


if __name__ == "__main__":
    main()
