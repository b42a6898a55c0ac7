"""Working-surface benchmark (§3.4.5): dual contouring and trimming of every layer, timed apart.

The thesis's reference (Table 3.1): bunny working surfaces 888.72 s (C++, DC + CGAL trimming, 4-core
Xeon); the authors' public code on this kind of 2-core machine trims the bunny at 1.0 mm in 362.8 s
and writes 73 of 93 layers (``benchmarks/paper.py``). Target here: bunny at 1.0 mm ≤ 60 s.

Run ``python benchmarks/bench_surfaces.py [SLICE_DIR ...]`` on slice folders (e.g. from ``curvslice
slice bunny.stl --voxel 1.0 --stages field``: their field is resumed, not recomputed). Without folders
it builds the bunny's field at 1.0 mm (pg-sp-gcfa, about a minute) from ``../shared/models`` first.
Also times the signed distance to ∂H (the trimming's kernel) per 10k points.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import trimesh

from benchmarks.paper import AUTHORS_CPP, TABLE_3_1
from curvslice.pipeline import Context, Settings, run, settings_of, stage
from curvslice.trimming import SolidDistance

TARGET_S = 60.0
MODELS = Path(__file__).resolve().parents[2] / "shared" / "models"


def field_context(model: Path, settings: Settings, resume: Path | None = None) -> Context:
    """The field stage's result (computed, or reused from the slice folder ``resume``) in a pipeline context."""
    result = run(model, settings, until="field", resume=resume)
    return Context(model, settings, {"field": result.field})


def distance_rate(solid: trimesh.Trimesh, n: int = 10_000) -> float:
    """Seconds per 10k signed-distance queries within a voxel of ∂H."""
    sd = SolidDistance.of(solid)
    rng = np.random.default_rng(0)
    pts = trimesh.sample.sample_surface(solid, n, seed=0)[0] + rng.normal(scale=0.5, size=(n, 3))
    start = time.perf_counter()
    sd(pts)
    return (time.perf_counter() - start) * 10_000 / n


def run_case(name: str, ctx: Context, repeat: int) -> None:
    w = ctx.settings.voxel
    solid = ctx.results["field"].solid
    times, dc, trim = [], [], []
    for _ in range(repeat):
        start = time.perf_counter()
        layers = stage("layers").run(ctx).layers
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
        ctx = field_context(MODELS / "bunny.stl", Settings(voxel=1.0))
        print(f"bunny field at 1.0 mm built in {time.perf_counter() - start:.1f} s")
        run_case("bunny", ctx, args.repeat)
    for folder in args.folders:
        settings = settings_of(folder)
        ctx = field_context(Path(run_model(folder)), settings, resume=folder)
        run_case(Path(run_model(folder)).stem, ctx, args.repeat)


def run_model(folder: Path) -> str:
    """The model file a slice folder was made from."""
    from curvslice.pipeline import read_report

    return read_report(folder)["model"]


if __name__ == "__main__":
    main()
