"""The benchmark suite: every pipeline stage timed separately on the shared models, plus a size sweep.

Each case (a model at a voxel size) runs the pipeline once, stage by stage; a stage is repeated in
place (same inputs, deterministic outputs) up to ``repeat`` times while its accumulated time stays
under ``budget`` seconds, so fast stages get a median and a spread and slow ones are run once. The
peak resident memory of each stage is read from ``/proc/self/status`` (VmHWM, reset before the
stage through ``/proc/self/clear_refs``). Library calls only: the suite times what ``curvslice
slice`` runs, stage by stage, and writes ``results.json``, ``RESULTS.md`` and ``results.png``.

Stages: load/repair/place, voxelize, peeling field (Alg. 4), growing field by each method (Alg. 1,
1+3, 5), working surfaces (dual contouring, trimming; §3.4.5), heat-method geodesics, Fermat
spirals, orientations (§3.5.1-3.5.2), IK ladder, ladder-graph search, motion planning with lazy
collision checks (§3.5.3, §4.3.1), export (extended G-code, joints.csv, robot program).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import platform
import re
import signal
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from curvslice.errors import CurvsliceError
from curvslice.executors import MAX_THREADS, default_threads

REPO = Path(__file__).resolve().parents[1]
STANDARD = (("bunny", 1.0), ("fertility", 0.76), ("kitten", 0.8), ("rocker-arm", 0.8), ("fandisk", 0.8))
SWEEP = ("kitten", (1.6, 1.2, 0.8, 0.6))
QUICK_STANDARD = (("tee", 2.0), ("arch", 1.5))
QUICK_SWEEP = ("arch", (2.5, 2.0, 1.5))
METHODS = ("gcfa", "sp-gcfa", "pg-sp-gcfa")
ROBOT_WAYPOINTS = 2_545  # Table 4.2, WS1
QUICK_ROBOT_WAYPOINTS = 150

#: Stage keys in pipeline order, with the label the tables use.
STAGE_LABELS = {
    "field_gcfa": "field stage, gcfa (load … growing)",
    "field_sp-gcfa": "field stage, sp-gcfa (load … growing)",
    "field_pg-sp-gcfa": "field stage, pg-sp-gcfa (load … growing)",
    "load": "load / repair / place",
    "voxelize": "voxelize (conservative)",
    "peeling": "peeling field (Alg. 4)",
    "growing_gcfa": "growing: gcfa (Alg. 1)",
    "growing_sp-gcfa": "growing: sp-gcfa (Alg. 1+3)",
    "growing_pg-sp-gcfa": "growing: pg-sp-gcfa (Alg. 5)",
    "surfaces": "working surfaces (total)",
    "dual_contouring": "· dual contouring",
    "trimming": "· trimming by H",
    "geodesics": "geodesics (heat method)",
    "toolpaths_and_cover": "tool-path stage incl. coverage check",
    "toolpaths": "tool-paths (total)",
    "toolpaths_one_thread": "tool-paths in order on one thread (--threads 1)",
    "spirals": "· Fermat spirals (incl. geodesics)",
    "orientation": "· orientations (Eq. 3.3)",
    "toolpaths_workers": "tool-paths on a local Dask cluster (--workers)",
    "ik": "IK ladder (p rotations)",
    "graph_search": "ladder-graph search",
    "motion": "robot stage (graph + jerk + fcl)",
    "jerk": "· jerk optimization + time-scaling (§4.3.2)",
    "collision_estimate": "collision estimators vs fcl (§4.4)",
    "export": "export (G-code, joints, program)",
}
#: Stages whose time is the sum of per-layer figures the library reports inside another stage.
DERIVED = {"dual_contouring", "trimming", "spirals", "orientation", "jerk"}
MISSING: dict[str, str] = {}
#: benchmarks/bench_collision.py's labelled configurations per layer and training samples in the suite
COLLISION_SET, QUICK_COLLISION_SET = (20_000, 3_000), (2_000, 500)


# ----------------------------------------------------------------------------- measuring


def _status_mb(key: str) -> float | None:
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return None
    m = re.search(rf"^{key}:\s+(\d+) kB", text, re.M)
    return int(m.group(1)) / 1024 if m else None


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


class StageTimeout(Exception):
    """A stage ran past the suite's per-stage time limit and was stopped."""


@contextmanager
def _deadline(seconds: float | None) -> Iterator[None]:
    """Raise :class:`StageTimeout` in the block after ``seconds`` (SIGALRM; main thread only)."""
    if not seconds or not hasattr(signal, "setitimer") or threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        raise StageTimeout

    old = signal.signal(signal.SIGALRM, stop)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@dataclass
class StageResult:
    """Wall times of the repetitions of one stage and its peak memory (MB; None if unknown);
    ``timeout_s`` is set when the stage was stopped at the time limit (then ``times`` is empty)."""

    times: list[float] = field(default_factory=list)
    peak_rss_mb: float | None = None
    peak_above_start_mb: float | None = None
    timeout_s: float | None = None

    def summary(self) -> dict[str, object]:
        if not self.times:
            return {"times_s": [], "reps": 0, "median_s": None, "min_s": None, "max_s": None,
                    "peak_rss_mb": None, "peak_above_start_mb": None, "timeout_s": self.timeout_s}
        t = np.asarray(self.times, float)
        return {
            "times_s": [round(float(x), 4) for x in t], "reps": len(t),
            "median_s": round(float(np.median(t)), 4), "min_s": round(float(t.min()), 4),
            "max_s": round(float(t.max()), 4),
            "peak_rss_mb": None if self.peak_rss_mb is None else round(self.peak_rss_mb, 1),
            "peak_above_start_mb": None if self.peak_above_start_mb is None else round(self.peak_above_start_mb, 1),
        }


@dataclass
class Recorder:
    """Times stages with repetitions under a per-stage budget; prints one line per stage."""

    repeat: int = 3
    budget: float = 20.0
    quiet: bool = False
    timeout: float | None = None
    stages: dict[str, StageResult] = field(default_factory=dict)

    def run(self, key: str, fn: Callable[[], object], derived: Callable[[object], dict[str, float]] | None = None):
        """Run ``fn`` up to ``repeat`` times (at least once); return its last result. ``derived``
        maps a result to sub-stage seconds recorded beside (e.g. dual contouring inside surfaces).
        Raises :class:`StageTimeout` (after recording it) when the first run passes ``timeout`` s."""
        res = StageResult()
        result = None
        while len(res.times) < max(1, self.repeat) and (not res.times or sum(res.times) < self.budget):
            start_rss = _status_mb("VmRSS")
            reset = _reset_peak()
            t0 = time.perf_counter()
            try:
                with _deadline(None if res.times else self.timeout):
                    result = fn()
            except StageTimeout:
                res.timeout_s = self.timeout
                self.stages[key] = res
                if not self.quiet:
                    print(f"  {STAGE_LABELS.get(key, key):36s} stopped after {self.timeout:g} s", flush=True)
                raise
            res.times.append(time.perf_counter() - t0)
            peak = _status_mb("VmHWM") if reset else None
            if peak is not None:
                res.peak_rss_mb = max(res.peak_rss_mb or 0.0, peak)
                res.peak_above_start_mb = max(res.peak_above_start_mb or 0.0, peak - (start_rss or 0.0))
            for sub, seconds in (derived(result) if derived else {}).items():
                self.stages.setdefault(sub, StageResult()).times.append(seconds)
        self.stages[key] = res
        if not self.quiet:
            s = res.summary()
            print(f"  {STAGE_LABELS.get(key, key):36s} {s['median_s']:9.3f} s  (n={s['reps']}, "
                  f"{s['min_s']:.3f}-{s['max_s']:.3f}; peak {s['peak_rss_mb']} MB)", flush=True)
        return result


# ----------------------------------------------------------------------------- one case


def robot_subset(toolpaths, target: int) -> np.ndarray:
    """Rows of the first layers (print order) that together reach ``target`` waypoints."""
    layer = np.asarray(toolpaths.layer)
    values, counts = np.unique(layer, return_counts=True)
    upto = values[min(int(np.searchsorted(np.cumsum(counts), target)), len(values) - 1)]
    return np.flatnonzero(layer <= upto)


def run_case(model: Path, voxel: float, *, methods: tuple[str, ...] = METHODS, robot: str | None = "ur5",
             robot_waypoints: int = ROBOT_WAYPOINTS, downstream: bool = True, repeat: int = 3,
             budget: float = 20.0, timeout: float | None = None, quiet: bool = False,
             workers: int | None = None, threads: int | None = None) -> dict[str, object]:
    """All stages on one model at one voxel size, each timed alone through the pipeline's registry
    (:func:`curvslice.pipeline.stage`); returns the case's JSON record. The field stage runs once per
    growing method; its load / voxelize / peeling / growing times are recorded beside. A stage stopped at
    ``timeout`` is recorded as such; the stages that need its result are then left out. ``workers``: the
    tool-path stage is also timed on a local Dask cluster of that many processes, right after it ran
    in-process (the 1 vs N row; the cluster's start-up is not timed). ``threads``: the in-process stages' threads
    (:func:`curvslice.executors.open_executor`; default the command line's); with more than one, the tool-path
    stage is also timed in order on one thread, right after."""
    from curvslice.executors import open_executor

    with open_executor(threads=threads) as executor:
        return _run_case(model, voxel, methods, robot, robot_waypoints, downstream, repeat, budget, timeout, quiet,
                         workers, executor)


def _run_case(model: Path, voxel: float, methods: tuple[str, ...], robot: str | None, robot_waypoints: int,
              downstream: bool, repeat: int, budget: float, timeout: float | None, quiet: bool, workers: int | None,
              executor) -> dict[str, object]:
    """:func:`run_case` with its stages' ``executor`` open."""
    from curvslice.pipeline import Context, Settings, stage

    rec = Recorder(repeat=repeat, budget=budget, quiet=quiet, timeout=timeout)
    if not quiet:
        print(f"{model.stem} @ {voxel} mm", flush=True)
    settings = Settings(voxel=voxel, robot=robot)
    counts: dict[str, object] = {}
    ctx = None
    for method in methods:
        c = Context(model, settings.replace(method=method), {}, executor=executor)
        try:
            field_ = rec.run(f"field_{method}", lambda c=c: stage("field").run(c),
                             lambda r, m=method: {("growing_" + m if k == "growing" else k): v
                                                  for k, v in r.report["timings_s"].items()})
        except StageTimeout:
            continue
        rep = field_.report
        counts.update(voxels=rep["voxels"], grid_shape=rep["grid_shape"])
        counts[method] = {"layers": rep["layers"], "missed": rep["missed"], "shadow_tests": rep["shadow_tests"]}
        if method == "pg-sp-gcfa" or ctx is None:
            ctx, counts["max_peeling"] = c, rep["max_peeling"]
            c.results["field"] = field_
    if downstream and ctx is not None:
        try:
            _downstream(rec, ctx, robot_waypoints, counts, workers)
        except StageTimeout:
            pass
    return {"model": model.stem, "voxel_mm": voxel, "counts": counts, "workers": workers, "threads": executor.workers,
            "stages": {k: v.summary() for k, v in rec.stages.items()}}


def _downstream(rec: Recorder, ctx, robot_waypoints: int, counts: dict[str, object], workers: int | None = None) -> None:
    from curvslice.geodesic import boundary_distance
    from curvslice.pipeline import stage
    from curvslice.toolpaths import clean_surface

    ctx.results["layers"] = rec.run(
        "surfaces", lambda: stage("layers").run(ctx),
        lambda r: {"dual_contouring": sum(m.metadata["dc_seconds"] for m in r.layers),
                   "trimming": sum(m.metadata["trim_seconds"] for m in r.layers)})
    layers = ctx.results["layers"].layers
    counts["surfaces"] = {"layers": len(layers), "empty": sum(len(m.faces) == 0 for m in layers),
                          "triangles": int(sum(len(m.faces) for m in layers))}
    cleaned = [clean_surface(m) for m in layers]
    rec.run("geodesics", lambda: [boundary_distance(m.vertices, m.faces) for m in cleaned if len(m.faces)])
    # the stage also measures coverage for its report: its wall time is kept apart from the planning time
    ctx.results["toolpaths"] = rec.run(
        "toolpaths_and_cover", lambda: stage("toolpaths").run(ctx),
        lambda r: {"toolpaths": r.report["timings_s"]["toolpaths"], "spirals": r.report["spirals_s"],
                   "orientation": r.report["orientation_s"]})
    tp = ctx.results["toolpaths"].toolpaths
    if ctx.executor.workers > 1:
        _toolpaths_on_one_thread(rec, layers, ctx.settings.toolpath_settings(), tp)
    if workers:
        _toolpaths_on_workers(rec, layers, ctx.settings.toolpath_settings(), workers, tp)
    counts["toolpaths"] = {"samples": int(len(tp.positions)), "pieces": int(len(np.unique(tp.path))),
                           "layers_with_paths": int(len(np.unique(tp.layer)))}
    if ctx.settings.robot and len(tp.positions):
        try:
            _robot(rec, ctx, robot_waypoints, counts)
        except StageTimeout:
            ctx.results.pop("robot", None)  # recorded as stopped; the export writes the tool-paths only
    with tempfile.TemporaryDirectory() as tmp:
        def export() -> None:
            for name in ("toolpaths", "robot"):
                if name in ctx.results:
                    stage(name).save(ctx.results[name], Path(tmp), ctx.settings, ctx.results)
        rec.run("export", export)


def _toolpaths_on_one_thread(rec: Recorder, layers, settings, reference) -> None:
    """The tool-path planning in order on one thread (``--threads 1``), beside the stage on the suite's threads:
    its arrays must be the same."""
    from curvslice.toolpaths import plan_toolpaths

    tp = rec.run("toolpaths_one_thread", lambda: plan_toolpaths(layers, settings))
    if not all(np.array_equal(getattr(tp, k), getattr(reference, k)) for k in ("positions", "normals", "bead", "extrusion")):
        raise CurvsliceError("tool-paths on one thread differ from those on several")


def _toolpaths_on_workers(rec: Recorder, layers, settings, workers: int, reference) -> None:
    """The tool-path planning on a local cluster of ``workers`` processes (started, and the library imported
    on each, before the clock starts); its arrays must be the in-process ones."""
    import importlib

    from curvslice.executors import open_executor
    from curvslice.toolpaths import plan_toolpaths

    with open_executor(workers=workers) as ex:
        ex.client.run(importlib.import_module, "curvslice.toolpaths.plan")
        tp = rec.run("toolpaths_workers", lambda: plan_toolpaths(layers, settings, executor=ex))
    if not np.array_equal(tp.positions, reference.positions):
        raise CurvsliceError(f"tool-paths on {workers} workers differ from the in-process ones")


def _robot(rec: Recorder, ctx, target: int, counts: dict) -> None:
    """The robot stage on the first layers' ``target`` waypoints, and its IK ladder and graph search
    timed alone beside it (Table 4.2's "init")."""
    import dataclasses

    from curvslice.kinematics import load_robot
    from curvslice.ladder import circular_joints, ladder, shortest_path
    from curvslice.motion import segment_speeds, step_times
    from curvslice.pipeline import stage
    from curvslice.workcell import load_workcell

    full = ctx.results["toolpaths"]
    tp = full.toolpaths
    rows = robot_subset(tp, target)
    subset = dataclasses.replace(tp, **{k: getattr(tp, k)[rows] for k in (
        "positions", "normals", "layer", "path", "extrusion", "thickness", "feed", "bead")})
    ctx.results["toolpaths"] = dataclasses.replace(full, toolpaths=subset)
    robot, cell = load_robot(ctx.settings.robot), load_workcell(ctx.settings.robot)
    per_layer = [np.flatnonzero(subset.layer == v) for v in np.unique(subset.layer)]
    rungs = rec.run("ik", lambda: [ladder(robot, cell, subset.positions[r], subset.normals[r], cell.rotations)
                                   for r in per_layer])
    circ = circular_joints(*cell.limits(robot))

    def search() -> int:
        breaks = 0
        for r, (q, valid) in zip(per_layer, rungs):
            dt = step_times(subset.positions[r], segment_speeds(subset.path[r], subset.feed[r], cell), cell.min_step_time)
            path, _, _ = shortest_path(q, valid, dt, cell.max_joint_speed, circ)
            breaks += int((np.diff(path.segment[path.segment >= 0]) != 0).sum())
        return breaks

    breaks = rec.run("graph_search", search)
    ctx.results["robot"] = rec.run("motion", lambda: stage("robot").run(ctx),
                                   lambda r: {"jerk": r.report["timings_s"]["robot_trajectory"]})
    motion, jerk = ctx.results["robot"].motion, ctx.results["robot"].report["jerk"]
    counts["robot"] = {"robot": ctx.settings.robot, "waypoints": len(rows), "layers": len(per_layer),
                       "rotations": cell.rotations, "ik_nodes": int(sum(v.sum() for _, v in rungs)),
                       "breaks_without_collisions": breaks, "rows": int(len(motion.q)),
                       "segments": int(len(np.unique(motion.segment))),
                       "collision_checks": int(sum(s["collision_checks"] for s in motion.layers)),
                       "trajectory": {k: jerk.get(k) for k in ("before", "after", "rows_over_limits",
                                                               "time_scaling_added_pct", "rows_projected")}}
    layer = int(subset.layer[per_layer[len(per_layer) // 2][0]])
    _collision_estimate(rec, ctx, layer, *(QUICK_COLLISION_SET if target <= QUICK_ROBOT_WAYPOINTS else COLLISION_SET),
                        counts)


def _collision_estimate(rec: Recorder, ctx, layer: int, configs: int, samples: int, counts: dict) -> None:
    """benchmarks/bench_collision.py (the learned SVM of §4.4 and the sphere proxy against fcl on
    ``configs`` labelled configurations near the contact C-space, ``samples`` Algorithm 7 training
    samples) on one layer; its rows go into ``counts``."""
    from benchmarks import bench_collision
    from curvslice.pipeline import stage

    with tempfile.TemporaryDirectory() as tmp:
        for name in ("field", "layers"):
            stage(name).save(ctx.results[name], Path(tmp), ctx.settings, ctx.results)

        def estimate() -> list[dict]:
            with contextlib.redirect_stdout(io.StringIO()):  # its JSON lines: the rows are kept instead
                return bench_collision.run(Path(tmp), [layer], configs, samples, 0.05, ctx.settings.robot)

        counts["collision_estimate"] = rec.run("collision_estimate", estimate)


# ----------------------------------------------------------------------------- the suite


def machine() -> dict[str, object]:
    """What the figures were measured on (the load average says whether the machine was shared)."""
    import scipy
    import trimesh

    cpu = "unknown"
    try:
        info = Path("/proc/cpuinfo").read_text()
        m = re.search(r"^model name\s*:\s*(.+)$", info, re.M)
        mhz = re.search(r"^cpu MHz\s*:\s*([\d.]+)", info, re.M)
        cpu = (m.group(1).strip() if m else cpu) + (f" at {float(mhz.group(1)) / 1000:.2f} GHz" if mhz else "")
    except OSError:
        pass
    mem = _meminfo_gb()
    return {
        "nproc": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "cpu": cpu, "memory_gb": mem, "python": platform.python_version(), "numpy": np.__version__,
        "scipy": scipy.__version__, "trimesh": trimesh.__version__, "platform": platform.platform(),
        "loadavg_start": list(os.getloadavg()),
    }


def _meminfo_gb() -> float | None:
    try:
        m = re.search(r"^MemTotal:\s+(\d+) kB", Path("/proc/meminfo").read_text(), re.M)
        return round(int(m.group(1)) / 2**20, 1) if m else None
    except OSError:
        return None


def models_dir() -> Path:
    env = os.environ.get("CURVSLICE_MODELS")
    return Path(env) if env else REPO.parent / "shared" / "models"


def _model_path(name: str, quick: bool) -> Path:
    path = (REPO / "models" if quick else models_dir()) / f"{name}.stl"
    if not path.is_file():
        raise CurvsliceError(f"benchmark model {path} not found; set CURVSLICE_MODELS to the folder of the shared models")
    return path


def run_suite(*, quick: bool = False, repeat: int = 3, budget: float = 20.0, methods: tuple[str, ...] = METHODS,
              robot: str | None = "ur5", models: tuple[str, ...] | None = None, sweep: bool = True,
              timeout: float | None = None, quiet: bool = False, workers: int | None = 2, threads: int | None = None,
              checkpoint: Callable[[dict[str, object]], None] | None = None) -> dict[str, object]:
    """Standard cases (+ the size sweep) → the JSON record written by :func:`write_outputs`;
    ``checkpoint(result)`` is called after every case with the record so far (``complete`` False)."""
    standard = QUICK_STANDARD if quick else STANDARD
    if models:
        unknown = set(models) - {m for m, _ in standard}
        if unknown:
            raise CurvsliceError(f"--models {', '.join(sorted(unknown))}: choose from {', '.join(m for m, _ in standard)}")
        standard = tuple((m, w) for m, w in standard if m in models)
    sweep_model, sweep_sizes = QUICK_SWEEP if quick else SWEEP
    target = QUICK_ROBOT_WAYPOINTS if quick else ROBOT_WAYPOINTS
    out: dict[str, object] = {
        "suite": "quick" if quick else "full", "machine": machine(),
        "settings": {"repeat": repeat, "budget_s": budget, "timeout_s": timeout, "methods": list(methods), "robot": robot,
                     "workers": workers, "threads": threads if threads is not None else default_threads(),
                     "robot_waypoints": target, "standard": [list(c) for c in standard],
                     "sweep": {"model": sweep_model, "voxels_mm": list(sweep_sizes)} if sweep else None},
        "standard": [], "sweep": [], "complete": False,
    }
    start = time.perf_counter()

    def done(kind: str, case: dict[str, object]) -> None:
        out[kind].append(case)
        out["machine"]["loadavg_end"] = list(os.getloadavg())
        out["wall_s"] = round(time.perf_counter() - start, 1)
        if checkpoint:
            checkpoint(out)

    for name, voxel in standard:
        done("standard", run_case(_model_path(name, quick), voxel, methods=methods, robot=robot, robot_waypoints=target,
                                  repeat=repeat, budget=budget, timeout=timeout, quiet=quiet, workers=workers,
                                  threads=threads))
    for voxel in sweep_sizes if sweep else ():
        done("sweep", run_case(_model_path(sweep_model, quick), voxel, methods=("pg-sp-gcfa",), robot=None,
                               repeat=repeat, budget=budget, timeout=timeout, quiet=quiet, threads=threads))
    if not quick:  # Table 2.1: the bunny's RoboFDM decomposition and its printed parts' fabrication time
        from benchmarks.bench_decompose import decomposition_case

        out["decompose"] = []
        done("decompose", decomposition_case(_model_path("bunny", quick), print_parts=True))
    out["complete"] = True
    return out


def write_outputs(result: dict[str, object], outdir: Path) -> list[Path]:
    """``results.json``, ``RESULTS.md`` and ``results.png`` in ``outdir``."""
    outdir.mkdir(parents=True, exist_ok=True)
    paths = [outdir / "results.json", outdir / "RESULTS.md", outdir / "results.png"]
    paths[0].write_text(json.dumps(result, indent=1) + "\n")
    paths[1].write_text(markdown(result))
    plot(result, paths[2])
    return paths


# ----------------------------------------------------------------------------- report


def _fmt(x: float | None) -> str:
    if x is None:
        return "–"
    if abs(x) >= 100:
        return f"{x:,.0f}"
    return f"{x:.1f}" if abs(x) >= 10 else f"{x:.3g}"


def _cell(stage: dict | None) -> str:
    if stage is None:
        return "–"
    if stage["median_s"] is None:
        return f"> {_fmt(stage['timeout_s'])} (stopped)"
    if stage["reps"] == 1:
        return _fmt(stage["median_s"])
    return f"{_fmt(stage['median_s'])} ({_fmt(stage['min_s'])}–{_fmt(stage['max_s'])}, n={stage['reps']})"


def _median(case: dict, key: str) -> float | None:
    st = case["stages"].get(key)
    return None if st is None else st["median_s"]


def _ratio(ours: float | None, ref: float | None) -> str:
    return "–" if ours is None or not ref else f"{ours / ref:.2f}"


def _case_title(case: dict) -> str:
    return f"{case['model']} @{case['voxel_mm']:g} mm"


def _sum(*values: float | None) -> float | None:
    return None if any(v is None for v in values) else float(sum(values))


def markdown(result: dict[str, object]) -> str:
    """The report: machine, stage times, memory, counts, the published figures beside ours, the sweep."""
    from benchmarks.paper import AUTHORS_CPP, AUTHORS_MACHINE, PAPER_MACHINE, TABLE_3_1, TABLE_4_2

    m, st, cases = result["machine"], result["settings"], result["standard"]
    flag = " --quick" if result["suite"] == "quick" else ""
    lines = [
        f"# curvslice benchmark ({result['suite']} suite)", "",
        f"Regenerate with `curvslice bench{flag}` (or `python -m benchmarks{flag}`). Every stage is a library call "
        f"timed on its own; a stage is repeated in place (at most {st['repeat']} runs) while its total stays "
        f"under {st['budget_s']:g} s, so cells read "
        "`median (min–max, n)`, or one figure when it ran once. Seconds, wall clock. "
        + (f"A stage still running after {st['timeout_s']:g} s is stopped ('stopped'), and the stages needing "
           "its result are left out." if st.get("timeout_s") else ""), "",
        "## Machine", "",
        f"- CPU: {m['cpu']}, {m['nproc']} cores available; memory {m['memory_gb']} GB",
        f"- Python {m['python']}, numpy {m['numpy']}, scipy {m['scipy']}, trimesh {m['trimesh']}; {m['platform']}",
        f"- load average at start {', '.join(f'{x:.2f}' for x in m['loadavg_start'])}, at end "
        f"{', '.join(f'{x:.2f}' for x in m.get('loadavg_end', []))}; suite wall time {result.get('wall_s', 0):,.0f} s",
    ]
    if not result.get("complete", True):
        done = len(result["standard"]) + len(result.get("sweep") or [])
        lines.append(f"- **partial run**: {done} case(s) written so far; the suite was still running or was stopped")
    if max(m["loadavg_start"][0], *(m.get("loadavg_end") or [0])) > 0.5 * m["nproc"]:
        lines.append(f"- **the machine was shared during the run** (load average above {0.5 * m['nproc']:g} on "
                     f"{m['nproc']} cores): figures are upper bounds")
    lines += ["", "## Stage times on the standard models (s)", "",
              "| stage | " + " | ".join(_case_title(c) for c in cases) + " |",
              "|---|" + "---|" * len(cases)]
    keys = [k for k in STAGE_LABELS if any(k in c["stages"] for c in cases)]
    for k in keys:
        lines.append(f"| {STAGE_LABELS[k]} | " + " | ".join(_cell(c["stages"].get(k)) for c in cases) + " |")
    threads = st.get("threads") or 1
    lines += ["", (f"The per-layer tasks of the working surfaces and tool-path stages run on {threads} threads of "
                   "the process (`--threads`, as `curvslice slice` does by default; the robot stage's blocks run in "
                   "order); the row 'in order on one thread' "
                   "times the tool-path stage without them, right after, arrays identical (checked). "
                   if threads > 1 else "The stages run in order on one thread (`--threads 1`). ")
              + "Rows starting with · are parts of the total above them (summed per-layer times the library "
              "reports: on several threads they add up the threads' time, more than the wall clock)"
              + (f"; the robot rows use the first layers of the tool-paths, in print order, until they hold at least "
                 f"{st['robot_waypoints']:,} waypoints (Table 4.2's WS1 has 2,545), p = 30 rotations, the shipped "
                 f"{st['robot']} workcell." if st.get("robot") else "; no robot stage (--robot none)."), ""]
    lines += workers_table(cases, m["nproc"])
    lines += ["## Counts", "",
              "| case | voxels | " + " | ".join(f"{x} layers / missed" for x in st["methods"])
              + " | surfaces (empty) | tool-path samples / pieces | robot waypoints / segments |",
              "|---|---|" + "---|" * len(st["methods"]) + "---|---|---|"]
    for c in cases:
        n = c["counts"]
        meth = [f"{n[x]['layers']} / {n[x]['missed']}" if x in n else "–" for x in st["methods"]]
        surf = f"{n['surfaces']['layers']} ({n['surfaces']['empty']})" if "surfaces" in n else "–"
        tp = f"{n['toolpaths']['samples']:,} / {n['toolpaths']['pieces']:,}" if "toolpaths" in n else "–"
        rb = f"{n['robot']['waypoints']:,} / {n['robot']['segments']}" if "robot" in n else "–"
        lines.append(f"| {_case_title(c)} | {n['voxels']:,} | " + " | ".join(meth) + f" | {surf} | {tp} | {rb} |")
    lines += ["", "## Peak memory per stage (MB resident; in brackets: above the resident size at the stage's start)", "",
              "The peak is the process's resident high-water mark, reset before each stage. Memory the allocator "
              "keeps after an earlier stage or case counts as already resident, so the bracketed growth is exact "
              "for the first case and a lower bound after it.", "",
              "| stage | " + " | ".join(_case_title(c) for c in cases) + " |", "|---|" + "---|" * len(cases)]
    for k in keys:
        if k in DERIVED:
            continue
        cells = []
        for c in cases:
            s = c["stages"].get(k)
            cells.append("–" if s is None or s["peak_rss_mb"] is None else f"{s['peak_rss_mb']:,.0f} (+{s['peak_above_start_mb']:,.0f})")
        lines.append(f"| {STAGE_LABELS[k]} | " + " | ".join(cells) + " |")

    lines += ["", "## Beside the thesis, Table 3.1", "", f"Thesis: {PAPER_MACHINE}; hollowed models. Ratio = ours / "
              "thesis (below 1: we are faster). The thesis's 'Total' is the whole decomposition (peeling field + "
              "growth with shadow prevention); ours is peeling + pg-sp-gcfa growth; its 'Shadow Prev.' is only a "
              "part of the growth, shown beside our whole growth.", "",
              "| model | figure | thesis | ours | ratio |", "|---|---|---|---|---|"]
    for c in cases:
        ref = TABLE_3_1.get(c["model"])
        if ref is None:
            continue
        n = c["counts"]
        grow = _median(c, "growing_pg-sp-gcfa")
        rows = [  # (figure, thesis, ours, ratio shown)
            ("voxels", ref["voxels"], n["voxels"], False),
            ("peeling field s", ref["peeling"], _median(c, "peeling"), True),
            ("shadow prev. s (ours: whole growth)", ref["shadow"], grow, True),
            ("decomposition total s", ref["total"], _sum(_median(c, "peeling"), grow), True),
            ("working surfaces s", ref["surfaces"], _median(c, "surfaces"), True),
            ("tool-paths s", ref["toolpaths"], _median(c, "toolpaths"), True),
            ("missed voxels", ref["missed"], n.get("pg-sp-gcfa", {}).get("missed"), False),
        ]
        for name, theirs, ours, ratio in rows:
            lines.append(f"| {_case_title(c)} | {name} | {_fmt(theirs)} | {_fmt(ours)} | {_ratio(ours, theirs) if ratio else '–'} |")
    if not any(c["model"] in TABLE_3_1 for c in cases):
        lines.append("| (no model of Table 3.1 in this suite) | | | | |")

    lines += ["", "## Beside the authors' C++ code on a 2-core machine (../shared/DESIGN.md)", "", f"{AUTHORS_MACHINE}. "
              "Its voxel counts include a one-voxel shell its voxelizer adds. 'written' = layers whose trimmed "
              "surface is non-empty. Ratio = ours / theirs.", "",
              "| case (theirs) | voxels theirs / ours | peeling s theirs / ours (ratio) | growing s theirs / ours (ratio) "
              "| missed theirs / ours | layers theirs / ours | trimming s theirs / ours (ratio) | layers written theirs / ours |",
              "|---|---|---|---|---|---|---|---|"]
    for (model, voxel, method), ref in AUTHORS_CPP.items():
        c = next((c for c in cases if c["model"] == model), None)
        if c is None or method not in c["counts"]:
            continue
        n = c["counts"]
        note = "" if abs(c["voxel_mm"] - voxel) < 1e-9 else f" (ours @{c['voxel_mm']:g} mm)"
        peel, grow, trim = _median(c, "peeling"), _median(c, f"growing_{method}"), _median(c, "trimming")
        written = n["surfaces"]["layers"] - n["surfaces"]["empty"] if "surfaces" in n else None
        theirs_written = "–" if ref["written"] is None else f"{ref['written']} of {ref['extracted']}"
        lines.append(
            f"| {model} @{voxel:g} mm, {method}{note} | {ref['voxels']:,} / {n['voxels']:,} "
            f"| {_fmt(ref['peeling'])} / {_fmt(peel) if method == 'pg-sp-gcfa' else '–'} ({_ratio(peel, ref['peeling']) if method == 'pg-sp-gcfa' else '–'}) "
            f"| {_fmt(ref['growing'])} / {_fmt(grow)} ({_ratio(grow, ref['growing'])}) "
            f"| {ref['missed']} / {n[method]['missed']} | {ref['layers']} / {n[method]['layers']} "
            f"| {_fmt(ref['trimming'])} / {_fmt(trim) if method == 'pg-sp-gcfa' else '–'} ({_ratio(trim, ref['trimming']) if method == 'pg-sp-gcfa' else '–'}) "
            f"| {theirs_written} / {written if written is not None and method == 'pg-sp-gcfa' else '–'} |")
    if not any(c["model"] == model for model, _, _ in AUTHORS_CPP for c in cases):
        lines.append("| (no shared model in this suite) | | | | | | | |")

    ws1 = TABLE_4_2["WS1"]
    lines += ["", "## Motion beside the thesis, Table 4.2", "",
              f"WS1: {ws1['waypoints']:,} waypoints, init (IK ladder + graph search) {ws1['init']:g} s, jerk optimization "
              f"{ws1['optm']:g} s, dense graph {ws1['dense']:,.0f} s ({PAPER_MACHINE}). Ours on the first layers of each model "
              "(per-waypoint rates make the sizes comparable; ratio = ours / thesis per waypoint).", "",
              "| case | waypoints | IK s | graph search s | IK + search s per 1k wpt (ratio to WS1 init) "
              "| robot stage s per 1k wpt (ratio to WS1 total) | jerk opt. s per 1k wpt (ratio to WS1 optm) "
              "| J / max jerk lower | print time added | collision checks |", "|---|---|---|---|---|---|---|---|---|---|"]
    per_k = ws1["init"] / ws1["waypoints"] * 1000
    optm_k, total_k = (ws1[k] / ws1["waypoints"] * 1000 for k in ("optm", "total"))
    estimators = []
    for c in cases:
        if "ik" not in c["stages"]:
            continue
        rb = c["counts"].get("robot")
        ik, gs, mo, jk = (_median(c, k) for k in ("ik", "graph_search", "motion", "jerk"))
        if rb is None:  # the motion stage was stopped before the counts were known
            lines.append(f"| {_case_title(c)} | ≥ {st['robot_waypoints']:,} | {_fmt(ik)} | {_fmt(gs)} | – "
                         f"| {_cell(c['stages'].get('motion'))} in all | – | – | – | – |")
            continue
        init_k = (ik + gs) / rb["waypoints"] * 1000
        mo_k = mo / rb["waypoints"] * 1000
        tr = rb.get("trajectory") or {}
        if jk is not None and tr.get("after"):
            jk_k = jk / rb["waypoints"] * 1000
            b, a = tr["before"], tr["after"]
            lower_j = 100 * (1 - a["total_squared_jerk"] / max(b["total_squared_jerk"], 1e-300))
            lower_max = 100 * (1 - max(a["max_jerk"]) / max(max(b["max_jerk"]), 1e-300))
            jerk_cells = (f"{_fmt(jk_k)} ({jk_k / optm_k:.2f}) | {lower_j:.1f} % / {lower_max:.1f} % "
                          f"| {tr['time_scaling_added_pct']:.1f} %")
        else:
            jerk_cells = "– | – | –"
        lines.append(f"| {_case_title(c)} | {rb['waypoints']:,} | {_fmt(ik)} | {_fmt(gs)} | {_fmt(init_k)} ({init_k / per_k:.2f}) "
                     f"| {_fmt(mo_k)} ({mo_k / total_k:.2f}) | {jerk_cells} | {rb['collision_checks']:,} |")
        estimators += [(c, r) for r in c["counts"].get("collision_estimate") or []]
    if estimators:
        lines += ["", "Collision estimation (§4.4, benchmarks/bench_collision.py) against fcl on labelled configurations "
                  "near the contact C-space of one layer of the robot subset (false \"free\" must be 0):", "",
                  "| case | layer | estimator | configs | false free | false collision % | query µs per config | training s |",
                  "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {_case_title(c)} | {r['layer']} | {r['estimator']} | {r['configs']:,} | {r['false_free']} "
                  f"| {r['false_collision_pct']:.2f} | {r['query_us_per_config']:.1f} | {r.get('train_s', 0.0):.2f} |"
                  for c, r in estimators]

    sweep = result.get("sweep") or []
    if sweep:
        skeys = [k for k in STAGE_LABELS if k not in DERIVED and all(k in c["stages"] for c in sweep)]
        lines += ["", f"## Size sweep: {sweep[0]['model']} at {len(sweep)} voxel sizes", "",
                  "Exponent = slope of log(time) against log(voxels) (least squares): how each stage's cost grows "
                  "with the voxel count.", "",
                  "| stage | " + " | ".join(f"@{c['voxel_mm']:g} mm ({c['counts']['voxels']:,} vx)" for c in sweep) + " | exponent |",
                  "|---|" + "---|" * (len(sweep) + 1)]
        for k in skeys:
            slope = sweep_exponent(sweep, k)
            lines.append(f"| {STAGE_LABELS[k]} | " + " | ".join(_cell(c["stages"][k]) for c in sweep)
                         + f" | {'–' if slope is None else f'{slope:.2f}'} |")
    if result.get("decompose"):
        from benchmarks.bench_decompose import table_2_1_lines

        lines += [""] + table_2_1_lines(result["decompose"])
    if result.get("verify"):
        from benchmarks.bench_verify import markdown as verify_markdown

        lines += ["", verify_markdown(result["verify"]["runs"], result["verify"]["header"])]
    lines += ["", "## Not yet implemented", ""]
    lines += [f"- {name}: {why}" for name, why in MISSING.items()] or ["- (nothing listed)"]
    lines += ["", "![time per stage; time against voxels](results.png)", ""]
    return "\n".join(lines)


def workers_table(cases: list[dict], nproc: int) -> list[str]:
    """The 1 vs N workers section: the tool-path planning in-process and on a local cluster, same run."""
    rows = [c for c in cases if _median(c, "toolpaths_workers") and _median(c, "toolpaths")]
    if not rows:
        return []
    lines = ["## Tool-paths: 1 vs N workers", "",
             f"The same planning in-process and on a local Dask cluster of N processes (`--workers N`), one after "
             f"the other in this run ({nproc} cores; the load average above says how much of them the run had). "
             "Arrays identical (checked). benchmarks/SCALING.md projects more workers from per-layer costs.", "",
             "| case | workers | in-process s | on N workers s | speed-up |", "|---|---|---|---|---|"]
    for c in rows:
        one, many = _median(c, "toolpaths"), _median(c, "toolpaths_workers")
        lines.append(f"| {_case_title(c)} | {c['workers']} | {_fmt(one)} | {_fmt(many)} | {one / many:.2f}× |")
    return lines + [""]


def sweep_exponent(sweep: list[dict], key: str) -> float | None:
    """Least-squares slope of log t against log voxels over the sweep (None below two sizes)."""
    pts = [(c["counts"]["voxels"], c["stages"][key]["median_s"]) for c in sweep if key in c["stages"]]
    pts = [(v, t) for v, t in pts if v > 0 and t is not None and t > 0]
    if len(pts) < 2:
        return None
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def plot(result: dict[str, object], path: Path) -> Path:
    """Left: median time per stage and model (log axis). Right: time against voxels, log-log, per stage."""
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    cases, sweep = result["standard"], result.get("sweep") or []
    fig = Figure(figsize=(15, 6.5), dpi=100)
    ax = fig.add_subplot(1, 2, 1)
    keys = [k for k in STAGE_LABELS if k not in DERIVED and any(k in c["stages"] for c in cases)]
    colors = colormaps["tab10"](np.arange(max(len(cases), 1)) % 10)
    h = 0.8 / max(len(cases), 1)
    for i, c in enumerate(cases):
        y = np.arange(len(keys)) + i * h
        t = [np.nan if c["stages"].get(k, {}).get("median_s") is None else c["stages"][k]["median_s"] for k in keys]
        ax.barh(y, t, height=h, color=colors[i], label=f"{_case_title(c)} ({c['counts']['voxels']:,} vx)")
    ax.set_yticks(np.arange(len(keys)) + 0.4 - h / 2, [STAGE_LABELS[k] for k in keys], fontsize=8)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("median wall time (s)")
    ax.set_title("time per stage")
    ax.legend(fontsize=8, loc="upper right")  # the fast first stages leave that corner empty
    ax = fig.add_subplot(1, 2, 2)
    if sweep:
        skeys = [k for k in keys if all(k in c["stages"] for c in sweep)]
        cmap = colormaps["tab20"]
        v = np.array([c["counts"]["voxels"] for c in sweep], float)
        for j, k in enumerate(skeys):
            t = np.array([np.nan if c["stages"][k]["median_s"] is None else c["stages"][k]["median_s"] for c in sweep])
            slope = sweep_exponent(sweep, k)
            if slope is None:
                continue
            ax.loglog(v, t, "o-", color=cmap(j % 20), label=f"{STAGE_LABELS[k]} (slope {slope:.2f})")
        ax.set_xlabel("voxels")
        ax.set_ylabel("median wall time (s)")
        ax.set_title(f"size sweep: {sweep[0]['model']} at " + ", ".join(f"{c['voxel_mm']:g}" for c in sweep) + " mm")
        if ax.lines:
            ax.legend(fontsize=7)
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    return path


# ----------------------------------------------------------------------------- command line


def add_arguments(p) -> None:
    """Options shared by ``curvslice bench`` and ``python -m benchmarks``."""
    p.add_argument("--quick", action="store_true", help="the small repository models (tee, arch) for CI: about a minute on 2 cores")
    p.add_argument("--out", help="folder for results.json, RESULTS.md, results.png (default: benchmarks/ for the full "
                   "suite, ./bench_quick for --quick)")
    p.add_argument("--repeat", type=int, default=3, help="repetitions per stage (while under --budget)")
    p.add_argument("--budget", type=float, default=20.0, help="stop repeating a stage once its runs total this many seconds")
    p.add_argument("--stage-timeout", type=float, default=900.0, help="stop a stage after this many seconds (0: never) "
                   "and leave out the stages that need its result")
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS, help="growing-field methods to time")
    p.add_argument("--models", nargs="+", help="only these standard models")
    p.add_argument("--robot", default="ur5", help="workcell for the robot stages; 'none' skips them")
    p.add_argument("--no-sweep", action="store_true", help="skip the size sweep")
    p.add_argument("--workers", type=int, default=2, help="also time the tool-path stage of the standard models on a "
                   "local Dask cluster of this many processes, beside the in-process run (0: skip)")
    p.add_argument("--threads", type=int, help="threads of the in-process stages (default: as `curvslice slice`, the "
                   f"cores available, at most {MAX_THREADS}); with more than one, the tool-path stage is also timed on one")
    p.add_argument("--quiet", action="store_true", help="no per-stage lines")
    p.add_argument("--verify-only", action="store_true", help="only the verify table (benchmarks/bench_verify.py): "
                   "slice every shared model at its standard settings and the kitten variants, verify, and replace "
                   "that section of RESULTS.md (and the 'verify' rows of results.json) in --out")
    p.add_argument("--no-verify-table", action="store_true", help="leave the verify table out of the full suite")
    p.add_argument("--scratch", help="folder for the verify table's slice folders (default: a temporary one)")
    p.add_argument("--verify-jobs", type=int, default=1, help="verify-table runs at once, each in its own process")
    p.add_argument("--reuse", action="store_true", help="verify table: keep the runs already recorded in --scratch "
                   "(resume an interrupted table)")


def execute(args) -> int:
    """Run the suite from parsed options and write its outputs."""
    if args.repeat < 1 or args.budget < 0:
        raise CurvsliceError("--repeat must be at least 1 and --budget non-negative")
    out = Path(args.out) if args.out else (Path.cwd() / "bench_quick" if args.quick else REPO / "benchmarks")
    if args.verify_only:
        return execute_verify_table(args, out)
    result = run_suite(quick=args.quick, repeat=args.repeat, budget=args.budget, methods=tuple(args.methods),
                       robot=None if str(args.robot).lower() == "none" else args.robot,
                       models=tuple(args.models) if args.models else None, sweep=not args.no_sweep,
                       timeout=args.stage_timeout or None, quiet=args.quiet, workers=args.workers or None,
                       threads=args.threads,
                       checkpoint=lambda partial: write_outputs(partial, out))
    if not args.quick and not args.no_verify_table:
        result["verify"] = verify_table(tuple(args.models) if args.models else None, args.scratch, args.quiet,
                                        args.verify_jobs, args.reuse)
    for path in write_outputs(result, out):
        print(f"wrote {path}")
    return 0


def source_commit() -> str:
    """The commit the library was run from, for a results header: short hash, and whether curvslice/ has
    uncommitted changes (else the commit that last changed it)."""
    import subprocess

    def git(*a: str) -> str:
        try:
            return subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True, check=True).stdout.strip()
        except (OSError, subprocess.CalledProcessError):
            return ""

    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    if git("status", "--porcelain", "--", "curvslice"):
        commit += " with uncommitted changes to curvslice/"
    elif last := git("log", "-1", "--format=%h", "--", "curvslice"):
        commit += f" (curvslice/ last changed in {last})"
    return commit


def verify_table(models: tuple[str, ...] | None, scratch: str | None, quiet: bool, jobs: int = 1,
                 reuse: bool = False) -> dict[str, object]:
    """The verify table's runs (:mod:`benchmarks.bench_verify`), ``jobs`` at once in their own processes,
    and what they were run on."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from benchmarks import bench_verify

    header = {"commit": source_commit(), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
              "load": ", ".join(f"{x:.1f}" for x in os.getloadavg()),
              "command": "curvslice bench --verify-only" + (f" --models {' '.join(models)}" if models else ""),
              "jobs": jobs}
    todo = bench_verify.cases(models)
    paths = [models_dir() / f"{case.model}.stl" for case in todo]
    if missing := [str(p) for p in paths if not p.is_file()]:
        raise CurvsliceError(f"verify table: models {', '.join(missing)} not found; set CURVSLICE_MODELS")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(scratch) if scratch else Path(tmp)
        if jobs > 1:
            with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
                records = list(pool.map(bench_verify.run_case, todo, paths, [work] * len(todo), [quiet] * len(todo),
                                        [reuse] * len(todo)))
        else:
            records = [bench_verify.run_case(case, path, work, quiet, reuse) for case, path in zip(todo, paths)]
    header["load_end"] = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return {"header": header, "runs": records}


def execute_verify_table(args, out: Path) -> int:
    """``--verify-only``: the verify table alone, spliced into ``out``/RESULTS.md and results.json."""
    from benchmarks import bench_verify

    table = verify_table(tuple(args.models) if args.models else None, args.scratch, args.quiet, args.verify_jobs,
                         args.reuse)
    out.mkdir(parents=True, exist_ok=True)
    data = out / "results.json"
    result = json.loads(data.read_text()) if data.exists() else {}
    result["verify"] = table
    data.write_text(json.dumps(result, indent=1) + "\n")
    bench_verify.splice(out / "RESULTS.md", bench_verify.markdown(table["runs"], table["header"]))
    print(f"wrote {data} and the verify section of {out / 'RESULTS.md'}")
    return 0 if all(r["passed"] for r in table["runs"]) else 1
