"""The tool-path stage (and with ``--model`` the whole slice to tool-paths) in-process vs on a local Dask
cluster, side by side in one run, and the per-layer costs of the stage (issue 16, benchmarks/SCALING.md).

    PYTHONPATH=. python -m benchmarks.bench_dask B --model bunny.stl --workers 2 --rules seam chain --json b.json

On the layers of a slice folder ``B``: (1) with ``--model``, the whole slice in-process then with N
workers; (2) per start rule, :func:`plan_toolpaths` in-process then with N workers (cluster start-up
timed apart); both ``repeat`` times, and the arrays must be equal; (3) per start rule, every layer's
:func:`_prepare_layer` (rings and thickness floor), :func:`_fold_layer` (pieces: under ``chain`` from
where the previous layer ended, the sequential fold) and :func:`_orient_layer` timed one by one
in-process, the travel between layers, and the Amdahl projection of 1-64 dedicated workers (and
``--project-voxels``). Writes JSON to ``--json``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from curvslice import pipeline
from curvslice.executors import open_executor
from curvslice.pipeline import Settings, settings_of
from curvslice.toolpaths import START_RULES
from curvslice.toolpaths import plan as tp_plan
from curvslice.working_surfaces import load_layers

ARRAYS = ("positions", "normals", "layer", "path", "extrusion", "thickness", "bead")


def per_layer_costs(layers, settings) -> dict:
    """CPU seconds (``process_time``: what a dedicated core would take, whatever else runs on this shared
    machine) of every layer's three parts -- rings (``prepare``), pieces (``fold``), orientations --
    run in order in this process under ``settings.start_rule``, the client's own part, and the travel
    between consecutive layers (last sample of one to the first of the next). Under ``chain`` the
    pieces of a layer wait for the previous layer's (the sequential fold); under ``seam`` a layer's
    three parts are one task of their own (:func:`~curvslice.toolpaths.plan._layer_toolpaths`)."""
    t0 = time.process_time()
    cleaned = [tp_plan.clean_surface(m) for m in layers]
    supports = [tp_plan.layer_support(s) for s in cleaned]
    seam = tp_plan.seam_point(cleaned)
    client = time.process_time() - t0
    prep, fold, orient, ends = [], [], [], []
    wall = time.perf_counter()
    previous = None
    for k in range(len(cleaned)):
        t = time.process_time()
        p = tp_plan._prepare_layer(k, cleaned, supports, settings)
        t1 = time.process_time()
        if settings.start_rule == "chain":
            f = tp_plan._fold_layer(p, previous, settings)
        else:
            f = tp_plan._fold_layer(p, None, settings, start=seam, backward=k % 2 == 1)
        t2 = time.process_time()
        arrays, _, _, _ = tp_plan._orient_layer(k, f, p, cleaned, supports, settings)
        t3 = time.process_time()
        prep.append(t1 - t), fold.append(t2 - t1), orient.append(t3 - t2)
        if "positions" in arrays:
            ends.append((arrays["positions"][0], arrays["positions"][-1]))
        previous = f
    between = [float(np.linalg.norm(b[0] - a[1])) for a, b in zip(ends[:-1], ends[1:])]
    return {"rule": settings.start_rule, "layers": len(cleaned), "triangles": [len(s.faces) for s in cleaned],
            "client_s": client, "prepare_s": prep, "fold_s": fold,
            "orient_s": orient, "wall_s": time.perf_counter() - wall, "travel_between_layers_mm": float(np.sum(between))}


def amdahl(costs: dict, workers: tuple[int, ...] = (1, 2, 4, 8, 16, 32, 64), sequential_s: float = 0.0,
           parallel_s: float = 0.0, scale: float = 1.0, chained: bool = True) -> list[dict]:
    """Projected seconds on N dedicated workers: the tool-path stage by :func:`makespan` of the measured
    per-layer costs, and with ``sequential_s`` / ``parallel_s`` the stages before it (the field and the
    layers' separation; the layers' contouring and trimming, split N ways), all times ``scale``. Under the
    ``chain`` rule the chain of folds is a sequential part (Amdahl): no number of workers beats it; under
    ``seam`` the largest layer bounds the stage."""
    one = makespan(costs, 1, scale) + (sequential_s + parallel_s) * scale
    rows = []
    for n in workers:
        stage = makespan(costs, n, scale, chained)
        whole = stage + (sequential_s + parallel_s / n) * scale
        rows.append({"workers": n, "toolpaths_s": round(stage, 1), "speedup": round(makespan(costs, 1, scale) / stage, 2),
                     "to_toolpaths_s": round(whole, 1), "total_speedup": round(one / whole, 2)})
    return rows


#: Seconds from a task's end to the start of a task waiting for it (the scheduler's round trip): a worker
#: that finishes a fold has started whatever else it holds before the next fold reaches it.
ROUND_TRIP_S = 0.005


def makespan(costs: dict, n: int, scale: float = 1.0, chained: bool = True, lanes: bool = True,
             round_trip: float = ROUND_TRIP_S) -> float:
    """Seconds the tool-path stage takes on ``n`` dedicated workers under the task priorities of
    :func:`plan_toolpaths` (folds first, then preparations, then orientations, each kind in layer order), by list
    scheduling the measured per-layer costs (no transfer overhead): a task starts ``round_trip`` after
    its inputs at the earliest, and a free worker starts what it can rather than wait. ``lanes`` (the
    executor's, ``n`` > 1): the folds on worker 0, the preparations on the others, orientations by
    :func:`~curvslice.toolpaths.plan._orient_lanes` when ``costs`` has the layers' ``triangles``, else anywhere;
    without lanes as Dask places them: a fold where its layer's preparation ran (its largest input), any other
    task anywhere. ``chained=False``: the ``seam`` rule, one task per layer (its three parts), the largest
    layers first, on the first free worker."""
    prep, fold, orient = ([c * scale for c in costs[k]] for k in ("prepare_s", "fold_s", "orient_s"))
    m = len(prep)
    if not chained:
        free = [0.0] * n
        for k in np.argsort(-np.asarray(costs.get("triangles", [0] * m)), kind="stable"):
            w = int(np.argmin(free))
            free[w] += prep[k] + fold[k] + orient[k]
        return max(free) + costs["client_s"] * scale
    cost = {"prep": prep, "fold": fold, "orient": orient}
    rank = {"fold": 2, "prep": 1, "orient": 0}
    need = {"prep": lambda k: [], "fold": lambda k: [("prep", k)] + ([("fold", k - 1)] if k else []),
            "orient": lambda k: [("fold", k), ("prep", k)]}
    lanes = lanes and n > 1
    lane = {"fold": [0], "prep": list(range(1, n)), "orient": list(range(n))} if lanes else \
        {kind: list(range(n)) for kind in cost}
    placed = {}  # without lanes: each fold where its preparation ran; with them, the orientations'
    if lanes and "triangles" in costs:
        placed = {("orient", k): [0] if where == "chain" else lane["prep"]
                  for k, where in enumerate(tp_plan._orient_lanes(costs["triangles"], n))}
    todo = {(kind, k) for kind in cost for k in range(m)}
    ready_at = {("prep", k): 0.0 for k in range(m)}
    done: dict[tuple[str, int], float] = {}
    free = [0.0] * n
    while todo:
        best = None
        for w in range(n):
            mine = [t for t in ready_at if w in placed.get(t, lane[t[0]])]
            if not mine:
                continue
            start = max(free[w], min(ready_at[t] for t in mine))
            task = max((t for t in mine if ready_at[t] <= start), key=lambda t: (rank[t[0]], -t[1]))
            if best is None or start < best[0]:
                best = (start, w, task)
        start, w, task = best
        todo.remove(task)
        del ready_at[task]
        done[task] = free[w] = start + cost[task[0]][task[1]]
        if task[0] == "prep" and not lanes:
            placed[("fold", task[1])] = [w]
        for after in (("fold", task[1] + 1), ("fold", task[1]), ("orient", task[1])):
            if after in todo and all(d in done for d in need[after[0]](after[1])):
                ready_at[after] = max(done[d] for d in need[after[0]](after[1])) + round_trip
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
    with open_executor(workers=workers, threads=None if workers else 1) as ex:  # (in order against the workers)
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


def whole_run(model: Path, settings: Settings, workers: int | None) -> dict:
    """Wall seconds of the whole slice to tool-paths (field, layers, tool-paths; no files written)
    in-process or on a local cluster of ``workers`` (cluster start-up and the workers' imports apart)."""
    t = time.perf_counter()
    with open_executor(workers=workers, threads=None if workers else 1) as ex:  # (in order against the workers)
        if workers:
            ex.client.run(_import_plan)
        up = time.perf_counter() - t
        t = time.perf_counter()
        result = pipeline.run(model, settings, until="toolpaths", executor=ex)
        wall = time.perf_counter() - t
    return {"workers": workers or 0, "startup_s": round(up, 3), "slice_s": round(wall, 3),
            "timings_s": result.report["timings_s"], "loadavg": os.getloadavg(), "slice": result}


def _same_slice(a, b) -> bool:
    """The field, every tool-path array and the coverage figures of the report equal."""
    cover = ("coverage_min", "coverage_mean", "overlap_max")
    return np.array_equal(a.results["field"].growing, b.results["field"].growing) and \
        all(np.array_equal(getattr(a.toolpaths, k), getattr(b.toolpaths, k)) for k in ARRAYS) and \
        all(a.report["toolpaths"][k] == b.report["toolpaths"][k] for k in cover)


def _ratio(runs: list[dict], key: str) -> float:
    """Median in-process over median with workers of ``key``."""
    one = np.median([r[key] for r in runs if r["workers"] == 0])
    many = np.median([r[key] for r in runs if r["workers"]])
    return round(float(one / many), 3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folder", help="slice folder with layers/ (e.g. /work/data/kitten08_new)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--rules", nargs="+", default=["seam"], choices=START_RULES,
                    help="start rules to time side by side and cost per layer (travel between layers)")
    ap.add_argument("--model", help="also time the whole slice of this model to tool-paths, in-process vs "
                    "workers, in the same run (with the folder's settings)")
    ap.add_argument("--skip-costs", action="store_true")
    ap.add_argument("--json", default=None)
    ap.add_argument("--separation-s", type=float, default=0.0,
                    help="seconds of the layers' separation (sequential) within the report's trimming_s")
    ap.add_argument("--project-voxels", type=float, nargs="*", default=[],
                    help="also project a part of this many voxels from the measured per-layer costs (resize)")
    args = ap.parse_args()
    folder = Path(args.folder)
    layers = load_layers(folder)
    base = settings_of(folder)
    out = {"folder": str(folder), "loadavg_before": os.getloadavg(), "cpus": os.cpu_count(), "runs": [],
           "whole": []}
    for _ in range(args.repeat):
        if args.model:
            for workers in (None, args.workers):
                run = whole_run(Path(args.model), base.replace(start_rule=args.rules[0]), workers)
                s = run.pop("slice")
                out["whole"].append(run)
                if workers is None:
                    reference = s
                else:
                    out["whole"][-1]["identical"] = _same_slice(reference, s)
                print(out["whole"][-1], flush=True)
        for rule in args.rules:
            settings = base.replace(start_rule=rule).toolpath_settings()
            for workers in (None, args.workers):
                run = timed_run(layers, settings, workers)
                tp = run.pop("toolpaths")
                run["rule"] = rule
                out["runs"].append(run)
                if workers is None:
                    reference = tp
                else:
                    run["identical"] = all(np.array_equal(getattr(reference, k), getattr(tp, k)) for k in ARRAYS)
                print(run, flush=True)
    if out["whole"]:
        out["ratio_slice_s"] = _ratio(out["whole"], "slice_s")
        print("whole slice to tool-paths, in-process / with workers: wall %.3f" % out["ratio_slice_s"])
    for rule in args.rules:
        runs = [r for r in out["runs"] if r["rule"] == rule]
        if runs:
            out[f"ratio_stage_s_{rule}"] = _ratio(runs, "stage_s")
            for r in runs:
                r["cpu_s"] = r["client_cpu_s"] + r["workers_cpu_s"]
            out[f"ratio_cpu_s_{rule}"] = _ratio(runs, "cpu_s")
            print("tool-path stage, %s rule, in-process / with workers: wall %.3f, CPU seconds %.3f"
                  % (rule, out[f"ratio_stage_s_{rule}"], out[f"ratio_cpu_s_{rule}"]))
    if args.skip_costs:
        out["loadavg_after"] = os.getloadavg()
        if args.json:
            Path(args.json).write_text(json.dumps(out, indent=1, default=float))
        return
    report = json.loads((folder / "report.json").read_text())
    field = sum(report["timings_s"].get(k, 0.0) for k in ("load", "voxelize", "peeling", "growing"))
    split = report["layers"]  # contouring + trimming run per layer; separation and set-up do not
    par = split["dual_contouring_s"] + split["trimming_s"] - args.separation_s
    seq = field + report["timings_s"]["layers"] - par
    out["projection"] = {"field_and_layers_wall_s": [seq, par]}
    for rule in args.rules:
        costs = per_layer_costs(layers, base.replace(start_rule=rule).toolpath_settings())
        out[f"costs_{rule}"] = costs
        total = sum(costs["prepare_s"]) + sum(costs["fold_s"]) + sum(costs["orient_s"]) + costs["client_s"]
        print(rule, {k: round(sum(v), 2) if isinstance(v, list) else v for k, v in costs.items()},
              "fold share %.3f" % (sum(costs["fold_s"]) / total), flush=True)
        # the field and layers stages' wall seconds of the folder's report, as CPU seconds at this run's share
        cpu_share = sum(costs["prepare_s"] + costs["fold_s"] + costs["orient_s"]) / costs["wall_s"]
        for voxels in [report["field"]["voxels"]] + args.project_voxels:
            factor = voxels / report["field"]["voxels"]
            rows = amdahl(resize(costs, factor), sequential_s=seq * cpu_share * factor,
                          parallel_s=par * cpu_share * factor, chained=rule == "chain")
            out["projection"][f"{int(voxels)} voxels, {rule} rule"] = rows
            print(int(voxels), "voxels,", rule, "rule (CPU share %.2f)" % cpu_share, flush=True)
            for row in rows:
                print(row)
    out["loadavg_after"] = os.getloadavg()
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
