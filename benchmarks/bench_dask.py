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


def per_layer_costs(layers, settings, rule: str = "chain") -> dict:
    """CPU seconds (``process_time``: what a dedicated core would take, whatever else runs on this shared
    machine) of every layer's three tasks run in order in this process, the client's own part, and
    the travel between consecutive layers (last sample of one to the first of the next). ``rule``: where
    a layer starts -- ``chain`` (where the previous one ended: the pipeline's rule), ``none`` (its own
    first ring, independent of the others) or ``seam`` (nearest a fixed point, the part's lowest-x,
    mid-y corner of its bounding box at the platform: independent of the others, like a slicer's
    aligned seam)."""
    t0 = time.process_time()
    cleaned = [tp_plan.clean_surface(m) for m in layers]
    supports = [tp_plan.layer_support(s) for s in cleaned]
    client = time.process_time() - t0
    prep, fold, orient, ends = [], [], [], []
    wall = time.perf_counter()
    previous = None
    lo, hi = np.min([m.bounds[0] for m in cleaned if len(m.faces)], axis=0), \
        np.max([m.bounds[1] for m in cleaned if len(m.faces)], axis=0)
    seam = tp_plan._Folded(None, [], np.array([lo[0], 0.5 * (lo[1] + hi[1]), 0.0]), 0, 0, 0.0)
    for k in range(len(cleaned)):
        t = time.process_time()
        p = tp_plan._prepare_layer(k, cleaned, supports, settings)
        t1 = time.process_time()
        start = previous if rule == "chain" else None if rule == "none" else seam
        f = tp_plan._fold_layer(p, start, k, cleaned, settings)
        if rule != "chain" and previous is not None:  # path ids still numbered on (no effect on geometry)
            f.first_path, f.next_path = previous.next_path, previous.next_path + len(f.samples)
        t2 = time.process_time()
        arrays, _, _, _ = tp_plan._orient_layer(k, f, cleaned, supports, settings)
        t3 = time.process_time()
        prep.append(t1 - t), fold.append(t2 - t1), orient.append(t3 - t2)
        if "positions" in arrays:
            ends.append((arrays["positions"][0], arrays["positions"][-1]))
        previous = f
    between = [float(np.linalg.norm(b[0] - a[1])) for a, b in zip(ends[:-1], ends[1:])]
    return {"layers": len(cleaned), "client_s": client, "prepare_s": prep, "fold_s": fold, "orient_s": orient,
            "wall_s": time.perf_counter() - wall, "travel_between_layers_mm": float(np.sum(between))}


def amdahl(costs: dict, workers: tuple[int, ...] = (1, 2, 4, 8, 16, 32, 64), sequential_s: float = 0.0,
           parallel_s: float = 0.0, scale: float = 1.0, chained: bool = True) -> list[dict]:
    """Projected seconds on N dedicated workers: the tool-path stage by :func:`makespan` of the measured
    per-layer costs, and with ``sequential_s`` / ``parallel_s`` the stages before it (the field and the
    layers' separation; the layers' contouring and trimming, split N ways), all times ``scale``. The
    chain of folds is the sequential part (Amdahl): no number of workers beats it."""
    one = makespan(costs, 1, scale) + (sequential_s + parallel_s) * scale
    rows = []
    for n in workers:
        stage = makespan(costs, n, scale, chained)
        whole = stage + (sequential_s + parallel_s / n) * scale
        rows.append({"workers": n, "toolpaths_s": round(stage, 1), "speedup": round(makespan(costs, 1, scale) / stage, 2),
                     "to_toolpaths_s": round(whole, 1), "total_speedup": round(one / whole, 2)})
    return rows


def makespan(costs: dict, n: int, scale: float = 1.0, chained: bool = True) -> float:
    """Seconds the tool-path stage takes on ``n`` dedicated workers under the task priorities of
    :func:`plan_toolpaths` (folds 2, preparations 1, orientations 0; ties in submission order), by list
    scheduling the measured per-layer costs (no transfer or scheduler overhead). ``chained=False``: a
    start rule that does not depend on the previous layer (no fold waits for the one before)."""
    prep, fold, orient = ([c * scale for c in costs[k]] for k in ("prepare_s", "fold_s", "orient_s"))
    m = len(prep)
    done: dict[tuple[str, int], float] = {}
    free = [0.0] * n
    todo = [("fold", k) for k in range(m)] + [("prep", k) for k in range(m)] + [("orient", k) for k in range(m)]
    need = {"prep": lambda k: [], "fold": lambda k: [("prep", k)] + ([("fold", k - 1)] if k and chained else []),
            "orient": lambda k: [("fold", k)]}
    cost = {"prep": prep, "fold": fold, "orient": orient}
    while todo:
        w = int(np.argmin(free))
        ready = [t for t in todo if all(d in done for d in need[t[0]](t[1]))]
        # the first ready task by priority that can start now, else the one whose inputs come first
        start = {t: max([free[w]] + [done[d] for d in need[t[0]](t[1])]) for t in ready}
        now = [t for t in ready if start[t] <= free[w]]
        task = now[0] if now else min(ready, key=lambda t: start[t])
        todo.remove(task)
        done[task] = start[task] + cost[task[0]][task[1]]
        free[w] = done[task]
    return max(done.values()) + costs["client_s"] * scale


def resize(costs: dict, factor: float) -> dict:
    """Per-layer costs of the same part with ``factor`` times the voxels: factor^(1/3) times the layers
    (the part's height in voxel widths), each factor^(2/3) times the work (its area in voxels), the
    measured profile stretched over the new layer count."""
    m = len(costs["prepare_s"])
    count = int(round(m * factor ** (1 / 3)))
    where = np.minimum((np.arange(count) * m / count).astype(int), m - 1)
    out = {k: [float(c) for c in np.asarray(costs[k])[where] * factor ** (2 / 3)] for k in ("prepare_s", "fold_s", "orient_s")}
    return {**out, "client_s": costs["client_s"] * factor}


def _import_plan() -> None:
    import curvslice.toolpaths.plan  # noqa: F401 -- a worker's imports, not timed with its tasks


def timed_run(layers, settings, workers: int | None) -> dict:
    """Wall seconds of :func:`plan_toolpaths` (cluster start-up and the workers' imports apart) and the CPU
    seconds it took in this process and on the workers."""
    t = time.perf_counter()
    with open_executor(workers=workers) as ex:
        cpu = (lambda: ex.client.run(time.process_time)) if workers else (lambda: {})
        if workers:
            ex.client.run(_import_plan)
        up = time.perf_counter() - t
        before, c0, t = cpu(), time.process_time(), time.perf_counter()
        tp = tp_plan.plan_toolpaths(layers, settings, executor=ex)
        wall, client_cpu, after = time.perf_counter() - t, time.process_time() - c0, cpu()
    return {"workers": workers or 0, "startup_s": round(up, 3), "stage_s": round(wall, 3),
            "client_cpu_s": round(client_cpu, 3), "workers_cpu_s": round(sum(after[k] - before[k] for k in after), 3),
            "loadavg": os.getloadavg(), "toolpaths": tp}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", help="slice folder with layers/ (e.g. /work/data/kitten08_new)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--independent", nargs="*", default=[], choices=("none", "seam"),
                    help="also measure these start rules (travel between layers)")
    ap.add_argument("--skip-costs", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--separation-s", type=float, default=0.0,
                    help="seconds of the layers' separation (sequential) within the report's trimming_s")
    ap.add_argument("--costs-from", help="per-layer costs from this earlier --json output instead of measuring")
    ap.add_argument("--project-voxels", type=float, nargs="*", default=[],
                    help="also project a part of this many voxels from the measured per-layer costs (resize)")
    args = ap.parse_args()
    folder = Path(args.folder)
    layers = load_layers(folder)
    settings = settings_of(folder).toolpath_settings()
    out = {"folder": str(folder), "loadavg_before": os.getloadavg(), "cpus": os.cpu_count(), "runs": []}
    for r in range(args.repeat):
        for workers in (None, args.workers):
            run = timed_run(layers, settings, workers)
            tp = run.pop("toolpaths")
            out["runs"].append(run)
            print(run, flush=True)
            if workers is None:
                reference = tp
            else:
                same = all(np.array_equal(getattr(reference, k), getattr(tp, k)) for k in ARRAYS)
                out["runs"][-1]["identical"] = same
                print("identical arrays:", same, flush=True)
    if out["runs"]:
        for key in ("stage_s", "client_cpu_s"):
            inproc = np.median([r[key] for r in out["runs"] if r["workers"] == 0])
            dask = np.median([r[key] + (r["workers_cpu_s"] if key != "stage_s" else 0.0)
                              for r in out["runs"] if r["workers"]])
            out["ratio_" + key] = round(float(inproc / dask), 3)
        print("in-process / with workers: wall %.3f, CPU seconds %.3f" % (out["ratio_stage_s"], out["ratio_client_cpu_s"]))
    if not args.skip_costs:
        costs = json.loads(Path(args.costs_from).read_text())["costs"] if args.costs_from else \
            per_layer_costs(layers, settings)
        out["costs"] = costs
        total = sum(costs["prepare_s"]) + sum(costs["fold_s"]) + sum(costs["orient_s"]) + costs["client_s"]
        print({k: round(sum(v), 2) if isinstance(v, list) else v for k, v in costs.items()},
              "fold share %.3f" % (sum(costs["fold_s"]) / total))
        for rule in args.independent:
            ind = per_layer_costs(layers, settings, rule)
            out[f"start_{rule}"] = {"travel_between_layers_mm": ind["travel_between_layers_mm"],
                                    "fold_s": sum(ind["fold_s"])}
            print(f"start rule {rule}: travel between layers %.1f mm (chained: %.1f mm)"
                  % (ind["travel_between_layers_mm"], costs["travel_between_layers_mm"]))
        report = json.loads((folder / "report.json").read_text())
        field = sum(report["timings_s"].get(k, 0.0) for k in ("load", "voxelize", "peeling", "growing"))
        split = report["layers"]  # contouring + trimming run per layer; separation and set-up do not
        par = split["dual_contouring_s"] + split["trimming_s"] - args.separation_s
        seq = field + report["timings_s"]["layers"] - par
        cpu_share = sum(costs["prepare_s"] + costs["fold_s"] + costs["orient_s"]) / costs["wall_s"]
        out["projection"] = {"field_and_layers_wall_s": [seq, par], "cpu_share_of_wall": cpu_share}
        for voxels in [report["field"]["voxels"]] + args.project_voxels:
            factor = voxels / report["field"]["voxels"]
            c = resize(costs, factor)
            for chained in (True, False):
                rows = amdahl(c, sequential_s=seq * cpu_share * factor, parallel_s=par * cpu_share * factor,
                              chained=chained)
                out["projection"][f"{int(voxels)} voxels, {'chained' if chained else 'independent'} starts"] = rows
                print(int(voxels), "voxels", "chained" if chained else "independent", flush=True)
                for row in rows:
                    print(row)
    out["loadavg_after"] = os.getloadavg()
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
