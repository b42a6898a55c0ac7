"""Tool-path stage benchmark: heat-method solve time per 10k vertices, and the whole tool-path
stage (connected Fermat spirals + orientations + extrusion) on real layers.

The thesis's reference (Table 3.1): bunny tool-paths 51.09 s (C++, exact FWP-MMP geodesics).
Run ``python benchmarks/bench_toolpaths.py SLICE_DIR [SLICE_DIR ...]`` on slice folders made to
the layers stage at least (e.g. ``curvslice slice bunny.stl --voxel 1.0 --stages layers``); the
pipeline resumes each (field and layers reused), re-plans the tool-paths into it and the verifier's
table is printed. Without folders it only times the geodesic solve.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.spatial import Delaunay

from curvslice.geodesic import boundary_distance
from curvslice.pipeline import read_report, run, settings_of
from curvslice.verify import format_table
from curvslice.verify.toolpaths import checks

THESIS_BUNNY_S = 51.09


def geodesic_rate(sizes: tuple[int, ...] = (10_000, 40_000)) -> None:
    """Seconds of one boundary-distance solve on a jittered disc of n vertices, per 10k vertices."""
    rng = np.random.default_rng(0)
    for n in sizes:
        h = np.sqrt(np.pi * 30.0**2 / n * 2 / np.sqrt(3))
        angle = np.linspace(0, 2 * np.pi, int(2 * np.pi * 30 / h), endpoint=False)
        inner = rng.uniform(-30, 30, (int(n * 1.3), 2))
        inner = inner[np.linalg.norm(inner, axis=1) < 30 - h]
        pts = np.vstack([30 * np.c_[np.cos(angle), np.sin(angle)], inner])[:n]
        faces = Delaunay(pts).simplices
        v = np.c_[pts, 0.02 * (pts**2).sum(axis=1)]  # a shallow bowl
        start = time.perf_counter()
        boundary_distance(v, faces)
        dt = time.perf_counter() - start
        print(f"geodesic: {len(v):,} vertices in {dt:.3f} s = {dt / len(v) * 1e4:.3f} s per 10k vertices")


def run_folder(folder: Path, width: float | None) -> None:
    settings = settings_of(folder)
    if width is not None:
        settings = settings.replace(path_width=width)
    result = run(read_report(folder)["model"], settings, until="toolpaths", resume=folder, out=folder, force=True,
                 redo="toolpaths")
    tp = result.toolpaths
    width = result.results["toolpaths"].settings.path_width
    dt = result.report["timings_s"]["toolpaths"]
    pieces = [row["pieces"] for row in tp.layers]
    gaps = [row.get("gap_passes", 0) for row in tp.layers]
    print(f"{folder.name}: {len(result.layers)} layers, width {width:.3f} mm: tool-paths {dt:.1f} s "
          f"(thesis bunny {THESIS_BUNNY_S} s; spirals {tp.seconds['spirals']:.1f} s, "
          f"orientation {tp.seconds['orientation']:.1f} s), {len(tp.positions):,} samples, "
          f"pieces/layer mean {np.mean(pieces):.2f} max {max(pieces)}, gap passes {sum(gaps)}, "
          f"jumps {sum(max(p - 1, 0) for p in pieces)}, travel {sum(r['travel_mm'] for r in tp.layers):.0f} mm")
    print(format_table(checks(folder)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="*", type=Path, help="slice folders (made to the layers stage at least)")
    parser.add_argument("--width", type=float, help="path width, mm (default: voxel size / 0.8, §3.6)")
    args = parser.parse_args()
    geodesic_rate()
    for folder in args.folders:
        run_folder(folder, args.width)


if __name__ == "__main__":
    main()
