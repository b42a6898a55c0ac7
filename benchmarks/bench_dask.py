"""The tool-path stage in-process vs on a local Dask cluster, side by side, and the per-layer costs of its
three tasks (issue 16, benchmarks/SCALING.md).

    PYTHONPATH=. python -m benchmarks.bench_dask /work/data/kitten08_new --workers 2 --repeat 1 [--independent]

On the layers of a slice folder: (1) every layer's :func:`_prepare_layer` (start-independent rings and
thickness floor), :func:`_fold_layer` (pieces from where the previous layer ended: the sequential chain)
and :func:`_orient_layer` timed one by one in-process; (2) :func:`plan_toolpaths` in-process and with N
workers (cluster start-up timed apart), alternating, ``repeat`` times; the arrays must be equal.
``--independent`` also times a run where every layer starts afresh (``start=None``: the layers no longer
depend on each other) and reports what that costs in travel between layers. Writes JSON to ``--json``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from curvslice.executors import open_executor
from curvslice.pipeline import settings_of
from curvslice.toolpaths import plan as tp_plan
from curvslice.working_surfaces import load_layers

ARRAYS = ("positions", "normals", "layer", "path", "extrusion", "thickness", "bead")


def per_layer_costs(layers, settings, independent: bool = False) -> dict:
    """Seconds of every layer's three tasks run in order in this process, the client's own part, and
    the travel between consecutive layers (last sample of one to the first of the next)."""
    t0 = time.perf_counter()
    cleaned = [tp_plan.clean_surface(m) for m in layers]
    supports = [tp_plan.layer_support(s) for s in cleaned]
    client = time.perf_counter() - t0
    prep, fold, orient, ends = [], [], [], []
    previous = None
    for k in range(len(cleaned)):
        t = time.perf_counter()
        p = tp_plan._prepare_layer(k, cleaned, supports, settings)
        t1 = time.perf_counter()
        f = tp_plan._fold_layer(p, None if independent else previous, k, cleaned, settings)
        if independent and previous is not None:  # path ids still numbered on (no effect on geometry)
            f.first_path, f.next_path = previous.next_path, previous.next_path + len(f.samples)
        t2 = time.perf_counter()
        arrays, _, _, _ = tp_plan._orient_layer(k, f, cleaned, supports, settings)
        t3 = time.perf_counter()
        prep.append(t1 - t), fold.append(t2 - t1), orient.append(t3 - t2)
        if "positions" in arrays:
            ends.append((arrays["positions"][0], arrays["positions"][-1]))
        previous = f
    between = [float(np.linalg.norm(b[0] - a[1])) for a, b in zip(ends[:-1], ends[1:])]
    return {"layers": len(cleaned), "client_s": client, "prepare_s": prep, "fold_s": fold, "orient_s": orient,
            "travel_between_layers_mm": float(np.sum(between))}


def timed_run(layers, settings, workers: int | None) -> tuple[float, float, object]:
    t = time.perf_counter()
    with open_executor(workers=workers) as ex:
        up = time.perf_counter() - t
        t = time.perf_counter()
        tp = tp_plan.plan_toolpaths(layers, settings, executor=ex)
        return up, time.perf_counter() - t, tp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", help="slice folder with layers/ (e.g. /work/data/kitten08_new)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--independent", action="store_true")
    ap.add_argument("--skip-costs", action="store_true")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    folder = Path(args.folder)
    layers = load_layers(folder)
    settings = settings_of(folder).toolpath_settings()
    out = {"folder": str(folder), "loadavg_before": os.getloadavg(), "cpus": os.cpu_count(), "runs": []}
    for r in range(args.repeat):
        for workers in (None, args.workers):
            up, seconds, tp = timed_run(layers, settings, workers)
            out["runs"].append({"workers": workers or 0, "startup_s": round(up, 3), "stage_s": round(seconds, 3),
                                "loadavg": os.getloadavg()})
            print(out["runs"][-1], flush=True)
            if workers is None:
                reference = tp
            else:
                same = all(np.array_equal(getattr(reference, k), getattr(tp, k)) for k in ARRAYS)
                out["runs"][-1]["identical"] = same
                print("identical arrays:", same, flush=True)
    inproc = [r["stage_s"] for r in out["runs"] if r["workers"] == 0]
    dask = [r["stage_s"] for r in out["runs"] if r["workers"]]
    out["speedup"] = round(float(np.median(inproc) / np.median(dask)), 3)
    print("speed-up (median in-process / median with workers):", out["speedup"])
    if not args.skip_costs:
        costs = per_layer_costs(layers, settings)
        out["costs"] = costs
        total = sum(costs["prepare_s"]) + sum(costs["fold_s"]) + sum(costs["orient_s"]) + costs["client_s"]
        print({k: round(sum(v), 2) if isinstance(v, list) else v for k, v in costs.items()},
              "fold share %.3f" % (sum(costs["fold_s"]) / total))
        if args.independent:
            ind = per_layer_costs(layers, settings, independent=True)
            out["independent"] = {"travel_between_layers_mm": ind["travel_between_layers_mm"],
                                  "fold_s": sum(ind["fold_s"])}
            print("independent starts: travel between layers %.1f mm (chained: %.1f mm)"
                  % (ind["travel_between_layers_mm"], costs["travel_between_layers_mm"]))
    out["loadavg_after"] = os.getloadavg()
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
