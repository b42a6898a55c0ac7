"""Working-surface benchmark (§3.4.5): dual contouring and trimming of every layer, timed apart.

The thesis's reference (Table 3.1): bunny working surfaces 888.72 s (C++, DC + CGAL trimming, 4-core
Xeon); the authors' public code on this kind of 2-core machine trims the bunny at 1.0 mm in 362.8 s
and writes 73 of 93 layers (``benchmarks/paper.py``). Target here: bunny at 1.0 mm ≤ 60 s.

Run ``python benchmarks/bench_surfaces.py [SLICE_DIR ...]`` on folders holding ``field.npz`` and
``solid.stl`` (e.g. from ``curvslice slice bunny.stl --voxel 1.0 --stages field``). Without folders
it builds the bunny's field at 1.0 mm (pg-sp-gcfa, about a minute) from ``../shared/models`` first.
Also times the signed distance to ∂H (the trimming's kernel) per 10k points.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import trimesh

from benchmarks.paper import AUTHORS_CPP, TABLE_3_1
from curvslice.working_surfaces import SolidDistance, extract_working_surfaces

TARGET_S = 60.0
MODELS = Path(__file__).resolve().parents[2] / "shared" / "models"


def bunny_field() -> tuple[dict, trimesh.Trimesh]:
    from curvslice.growing_field import growing_field
    from curvslice.peeling_field import peeling_field
    from curvslice.platform import disc_platform
    from curvslice.solid import load_solid
    from curvslice.voxelize import voxelize

    solid, _ = load_solid(MODELS / "bunny.stl")
    grid = voxelize(solid, 1.0)
    platform = disc_platform(solid).vertices
    growing, _ = growing_field(grid, platform, "pg-sp-gcfa", peeling=peeling_field(grid, platform))
    field = {"growing": growing, "occupied": grid.occupied, "origin": grid.origin, "voxel_size": 1.0}
    return field, solid


def distance_rate(solid: trimesh.Trimesh, n: int = 10_000) -> float:
    """Seconds per 10k signed-distance queries within a voxel of ∂H."""
    sd = SolidDistance.of(solid)
    rng = np.random.default_rng(0)
    pts = trimesh.sample.sample_surface(solid, n, seed=0)[0] + rng.normal(scale=0.5, size=(n, 3))
    start = time.perf_counter()
    sd(pts)
    return (time.perf_counter() - start) * 10_000 / n


def run_case(name: str, field: dict, solid: trimesh.Trimesh, repeat: int) -> None:
    w = float(field["voxel_size"])
    times, dc, trim = [], [], []
    for _ in range(repeat):
        start = time.perf_counter()
        layers = extract_working_surfaces(field["growing"], field["origin"], w, solid, occupied=field["occupied"])
        times.append(time.perf_counter() - start)
        dc.append(sum(m.metadata["dc_seconds"] for m in layers))
        trim.append(sum(m.metadata["trim_seconds"] for m in layers))
    total = float(np.median(times))
    empty = sum(len(m.faces) == 0 for m in layers)
    print(f"{name} @ {w:g} mm: {len(layers)} layers ({empty} empty, "
          f"{sum(m.metadata['lowered'] for m in layers)} lowered), {sum(len(m.faces) for m in layers):,} triangles "
          f"({sum(m.metadata['untrimmed_faces'] for m in layers):,} before trimming)")
    print(f"  working surfaces {total:.1f} s (median of {repeat}; min {min(times):.1f}): "
          f"dual contouring {np.median(dc):.1f} s, trimming {np.median(trim):.1f} s, "
          f"setup {total - np.median(dc) - np.median(trim):.1f} s")
    print(f"  signed distance: {distance_rate(solid):.2f} s per 10k points near ∂H")
    ref = TABLE_3_1.get(name, {}).get("surfaces")
    if ref:
        print(f"  thesis (Table 3.1): {ref:.1f} s -> {ref / total:.0f}x faster; target {TARGET_S:.0f} s: "
              f"{'met' if total <= TARGET_S else 'MISSED'}")
    cpp = AUTHORS_CPP.get((name, w, "pg-sp-gcfa"))
    if cpp and cpp.get("trimming"):
        print(f"  authors' C++ here: trimming {cpp['trimming']:.1f} s, {cpp['written']} of {cpp['extracted']} "
              f"layers written -> ours {len(layers) - empty} of {len(layers)} non-empty")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folders", nargs="*", type=Path, help="slice folders with field.npz and solid.stl")
    parser.add_argument("--repeat", type=int, default=1, help="runs per case (median reported)")
    args = parser.parse_args()
    if not args.folders:
        start = time.perf_counter()
        field, solid = bunny_field()
        print(f"bunny field at 1.0 mm built in {time.perf_counter() - start:.1f} s")
        run_case("bunny", field, solid, args.repeat)
    for folder in args.folders:
        with np.load(folder / "field.npz") as f:
            field = {k: f[k] for k in ("growing", "occupied", "origin", "voxel_size")}
        report = folder / "report.json"
        name = Path(json.loads(report.read_text())["model"]).stem if report.exists() else folder.name
        run_case(name, field, trimesh.load(folder / "solid.stl", force="mesh"), args.repeat)


if __name__ == "__main__":
    main()
