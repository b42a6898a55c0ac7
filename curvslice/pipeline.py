"""The pipeline: one place that composes the stages (thesis Fig. 3.2 / §3.3 overview).

* :class:`Settings` holds every parameter of ``curvslice slice`` with its default and unit — the only
  place a default lives; the CLI builds its options from it.
* Each stage is a :class:`Stage` of :data:`STAGES`: its name, the settings it reads, a function from the
  earlier results to a typed result, and how that result is saved to and loaded from the output folder
  (the file contract: ``field.npz``, ``layers/``, ``toolpaths.npz`` / ``.gcode``, robot programs).
* :func:`run` (also ``curvslice.slice``) runs the stages up to ``until`` and returns a :class:`Slice`;
  with ``out`` it writes the folder atomically, with ``resume`` it reuses every stage whose key — a hash of
  the model, its settings and the earlier stages' keys, stored in ``report.json`` — is unchanged.

Three lines in a notebook::

    import curvslice
    s = curvslice.slice("kitten.stl", curvslice.Settings(voxel=0.8), until="toolpaths")
    s.toolpaths.positions.shape
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
import time
from collections import Counter
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from tqdm import tqdm

from curvslice import __version__
from curvslice.convex_front import GROW_EPS, PEEL_EPS
from curvslice.errors import CurvsliceError
from curvslice.executors import Executor, InProcess, Threads
from curvslice.growing_field import METHODS, growing_field
from curvslice.outdir import atomic_folder
from curvslice.peeling_field import peeling_field
from curvslice.platform import DEFAULT_MARGIN, DEFAULT_THICKNESS, disc_platform, load_platform
from curvslice.solid import load_solid
from curvslice.validate import check_number
from curvslice.toolpaths import START_RULES, Toolpaths, ToolpathSettings, plan_toolpaths, save_toolpaths
from curvslice.verify.toolpaths import layer_cover
from curvslice.voxelize import VoxelGrid, voxelize
from curvslice.working_surfaces import extract_working_surfaces, layer_levels, load_layers, write_layers

#: Bump when a stage's output changes for the same settings: old folders then are not resumed from.
PIPELINE_VERSION = 1


def setting(default: Any, help: str, stage: str, unit: str = "", **cli: Any) -> Any:
    """A :class:`Settings` field: default, help text, the stage that reads it, unit, and CLI extras
    (``flag``, ``choices``, ``degrees`` for an angle the CLI takes in degrees, ``negate`` for a
    ``--no-X`` switch)."""
    return field(default=default, metadata={"help": help, "stage": stage, "unit": unit, **cli})


def setting_bounds(f: dataclasses.Field) -> tuple[float, float, str, bool]:
    """(lowest, highest, unit, integer) of a numeric :class:`Settings` field as users give it: an angle the
    CLI takes in degrees has its bounds in degrees."""
    m = f.metadata
    integer = isinstance(f.default, int) or f.type == "int | None"
    if m.get("degrees"):
        return float(np.degrees(m["lo"])), float(np.degrees(m["hi"])), "degrees", integer
    return m["lo"], m["hi"], m["unit"], integer


@dataclass(frozen=True)
class Settings:
    """Every parameter of the pipeline (mm, radians, mm/min), grouped by the stage that reads it."""

    # placement of the model (the field stage loads it)
    up: str = setting("z", "model axis that points up", "field", choices=("x", "-x", "y", "-y", "z", "-z"))
    size: float | None = setting(None, "scale uniformly so the longest extent is SIZE", "field", "mm",
                                  lo=0.01, hi=10_000.0)
    scale: float = setting(1.0, "uniform scale factor (ignored with size)", "field", lo=1e-6, hi=1e6)
    # platform T (§3.4.1: it takes part in every convex front)
    platform: str | None = setting(None, "platform mesh in the model frame (top at z = 0); default: a disc slab", "field")
    platform_margin: float = setting(DEFAULT_MARGIN, "disc radius beyond the footprint", "field", "mm", lo=0.0, hi=1000.0)
    platform_thickness: float = setting(DEFAULT_THICKNESS, "disc thickness", "field", "mm", lo=0.1, hi=1000.0)
    # volume decomposition (§3.4)
    voxel: float = setting(1.0, "voxel width w (the thesis used about the nozzle diameter)", "field", "mm",
                           lo=0.001, hi=100.0)  # below ~0.3 mm the memory limit decides, naming the GiB
    method: str = setting("pg-sp-gcfa", "growing-field method: gcfa (Alg. 1), sp-gcfa (Alg. 3), pg-sp-gcfa (Alg. 5)",
                          "field", choices=METHODS)
    delta_f: int = setting(1, "Δf, the peeling-field threshold step of Alg. 5", "field", lo=1, hi=1000)
    eps: float = setting(GROW_EPS, "ε of the inside test (Definitions 2-3), in voxel widths", "field", "w",
                         lo=0.0, hi=10.0)
    peel_eps: float = setting(PEEL_EPS, "ε of the peeling shells (Alg. 4), in voxel widths", "field", "w",
                              lo=0.0, hi=10.0)
    memory_limit: float = setting(8.0, "refuse grids needing more than this", "field", "GiB", lo=0.01, hi=4096.0)
    # working surfaces (§3.4.5)
    layer_height: float | None = setting(None, "d of Eq. 3.2 (default: the voxel width; 0.25-4 w)", "layers", "mm",
                                          lo=0.0025, hi=400.0)
    # tool-paths (§3.5.1-3.5.2)
    path_width: float | None = setting(None, "spacing of the spiral passes (default: voxel / 0.8, the nozzle of §3.6)",
                                       "toolpaths", "mm", lo=0.005, hi=300.0)
    step: float = setting(1.0, "re-sampling distance along the paths (§3.5.2)", "toolpaths", "mm", lo=0.05, hi=50.0)
    filament: float = setting(1.75, "filament diameter", "toolpaths", "mm", lo=0.1, hi=10.0)
    feed: float = setting(600.0, "nozzle speed along the paths", "toolpaths", "mm/min", lo=1.0, hi=60_000.0)
    max_tilt: float = setting(float(np.radians(40.0)), "largest angle between tool and layer normal (the shipped "
                              "nozzle cone clears 40°)", "toolpaths", "rad", degrees=True, lo=0.0,
                              hi=float(np.radians(89.0)))
    gap_passes: bool = setting(True, "extra passes through the gaps the spirals leave (§3.7)", "toolpaths",
                               flag="--no-gap-passes", negate=True)
    start_rule: str = setting("chain", "where each layer's spiral starts: chain (nearest where the previous layer "
                              "ended: least travel, but a sequential fold) or seam (nearest a fixed point of the part: "
                              "layers are independent tasks that scale over workers, about 1 %% more motion)",
                              "toolpaths", choices=START_RULES)
    # robot (§3.5.3, §4.3.1)
    robot: str | None = setting(None, "workcell: ur3, ur5, ur10, irb120 (shipped) or a workcell JSON file; "
                                "without it the robot stage is skipped", "robot")
    rotations: int | None = setting(None, "p, rotations about the nozzle axis per waypoint (default: the workcell's)",
                                    "robot", lo=1, hi=720)
    max_rotations: int | None = setting(None, "largest p when doubling to remove splits (default: 4 p)", "robot",
                                        lo=1, hi=2880)
    motion_cost: str = setting("l1", "edge weight: Eq. 3.4 (l1) or Eq. 4.5 (quadratic)", "robot",
                               choices=("l1", "quadratic"))
    trajectory: str = setting("jerk", "jerk: the graph path jerk-optimized (§4.3.2) within the workcell's acceleration "
                              "and jerk limits, moves between segments by Ruckig; graph: the graph search's path as it "
                              "is (§4.3.1, for comparison)", "robot", choices=("jerk", "graph"))

    def __post_init__(self) -> None:
        """Every number finite and in its range (unit named), choices and cross-field limits: checked when
        the settings are made, before any stage runs (issue 15)."""
        for f in dataclasses.fields(self):
            value, m = getattr(self, f.name), f.metadata
            if value is None and f.default is None:
                continue
            if "choices" in m and value not in m["choices"]:
                raise CurvsliceError(f"setting {f.name} must be one of {', '.join(m['choices'])}, got {value!r}")
            if "lo" in m:
                lo, hi, unit, integer = setting_bounds(f)
                shown = float(np.degrees(value)) if m.get("degrees") and isinstance(value, (int, float)) else value
                check_number(shown, f"setting {f.name}", unit, lo=lo, hi=hi, integer=integer)
        w = self.voxel
        for name, low, high in (("layer_height", 0.25, 4.0), ("path_width", 0.5, 3.0)):
            value = getattr(self, name)
            if value is not None and not low * w <= value <= high * w:
                raise CurvsliceError(f"setting {name} must lie between {low:g} and {high:g} voxel widths "
                                     f"({low * w:g}-{high * w:g} mm at voxel {w:g} mm), got {value:g} mm")
        if self.rotations and self.max_rotations and self.max_rotations < self.rotations:
            raise CurvsliceError(f"setting max_rotations ({self.max_rotations}) must be at least rotations "
                                 f"({self.rotations})")

    def replace(self, **changes: Any) -> Settings:
        """A copy with ``changes`` (unknown names are an error)."""
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise CurvsliceError(f"unknown setting(s): {', '.join(sorted(unknown))}")
        return dataclasses.replace(self, **changes)

    def of_stage(self, stage: str) -> dict[str, Any]:
        """The settings ``stage`` reads, by name."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.metadata["stage"] == stage}

    def toolpath_settings(self) -> ToolpathSettings:
        """The tool-path stage's parameters; the path width defaults to voxel / 0.8 (the nozzle of §3.6)."""
        return ToolpathSettings(path_width=self.path_width or self.voxel / 0.8, step=self.step,
                                filament_diameter=self.filament, feed=self.feed, max_tilt=self.max_tilt,
                                fill_gaps=self.gap_passes, start_rule=self.start_rule)


# ---------------------------------------------------------------------------------------------- results


@dataclass
class FieldResult:
    """Solid H, platform T, conservative voxels H̄, peeling field F̄ and growing field G (§3.4.1-3.4.4)."""

    solid: trimesh.Trimesh
    platform_vertices: np.ndarray
    grid: VoxelGrid
    peeling: np.ndarray
    growing: np.ndarray
    report: dict


@dataclass
class LayersResult:
    """One trimmed working surface per layer, in print order (§3.4.5)."""

    layers: list[trimesh.Trimesh]
    report: dict


@dataclass
class ToolpathsResult:
    """Oriented, extruding samples of every layer (§3.5.1-3.5.2) and the settings they were made with."""

    toolpaths: Toolpaths
    settings: ToolpathSettings
    report: dict


@dataclass
class RobotResult:
    """The joint trajectory of the workcell's arm (§3.5.3, §4.3); ``motion`` is None when skipped."""

    workcell: Any
    motion: Any
    report: dict | str


@dataclass
class Context:
    """What a stage function gets: the model, the settings, the earlier results, a progress bar, and
    the executor its per-layer tasks run on (:mod:`curvslice.executors`; never changes a result)."""

    model: str | Path | trimesh.Trimesh
    settings: Settings
    results: dict[str, Any]
    quiet: bool = True
    executor: Executor = field(default_factory=InProcess)

    def bar(self, desc: str, total: int, unit: str = "voxel") -> tqdm:
        return tqdm(total=total, desc=desc, unit=unit, unit_scale=True, leave=False, disable=self.quiet,
                    dynamic_ncols=True)


# ----------------------------------------------------------------------------------------------- stages


def _load(ctx: Context) -> tuple[trimesh.Trimesh, dict]:
    s = ctx.settings
    solid, load = load_solid(ctx.model, up=s.up, size=s.size, scale=s.scale)
    return solid, asdict(load)


def run_field(ctx: Context) -> FieldResult:
    """Solid → conservative voxels → inverse peeling field → growing field (§3.4.1-3.4.4)."""
    s, timings = ctx.settings, {}
    start = time.perf_counter()
    solid, load = _load(ctx)
    timings["load"] = time.perf_counter() - start
    extent = float(solid.extents.max())
    if extent < 4 * s.voxel:
        raise CurvsliceError(f"voxel {s.voxel:g} mm is too coarse for a model {extent:.3g} mm across (fewer than 4 "
                             f"voxels): choose --voxel {extent / 20:.2g} or less")
    platform = load_platform(s.platform) if s.platform else disc_platform(
        solid, margin=s.platform_margin, thickness=s.platform_thickness)
    start = time.perf_counter()
    grid = voxelize(solid, s.voxel, memory_limit=int(s.memory_limit * 2**30))
    timings["voxelize"] = time.perf_counter() - start
    n = int(grid.occupied.sum())
    peel = np.zeros(grid.shape, np.int32)
    if s.method == "pg-sp-gcfa":
        start = time.perf_counter()
        with ctx.bar("peeling field", n) as bar:
            peel = peeling_field(grid, platform.vertices, eps=s.peel_eps, progress=bar)
        timings["peeling"] = time.perf_counter() - start
    start = time.perf_counter()
    with ctx.bar(f"growing field ({s.method})", n) as bar:
        growing, stats = growing_field(grid, platform.vertices, s.method, peeling=peel, delta_f=s.delta_f,
                                       eps=s.eps, progress=bar)
    timings["growing"] = time.perf_counter() - start
    vertices = np.asarray(platform.vertices, float)
    report = {
        "load": load, "grid_shape": list(grid.shape), "voxels": n, "layers": stats.layers, "missed": stats.missed,
        "max_peeling": int(peel.max()), "shadow_tests": stats.shadow_tests,
        "shadow_fallbacks": stats.shadow_fallbacks, "held_back": stats.held_back,
        "threshold_steps": stats.threshold_steps, "layer_sizes": stats.layer_sizes,
        "platform_radius_mm": round(float(np.linalg.norm(vertices[:, :2], axis=1).max()), 3),
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }
    if not ctx.quiet:
        print(f"field: {n} voxels, {stats.layers} layers, {stats.missed} missed ({timings['growing']:.1f} s growing)")
    return FieldResult(solid, vertices, grid, peel, growing, report)


def save_field(r: FieldResult, out: Path, s: Settings) -> None:
    r.solid.export(out / "solid.stl")
    np.savez_compressed(
        out / "field.npz", occupied=r.grid.occupied, peeling=r.peeling, growing=r.growing, origin=r.grid.origin,
        voxel_size=np.float64(r.grid.voxel_size), method=np.str_(s.method), platform_vertices=r.platform_vertices,
        eps=np.float64(s.eps),
    )


def load_field(ctx: Context, folder: Path, report: dict) -> FieldResult:
    """The field from ``field.npz``; H is loaded again from the model (solid.stl holds float32 vertices)."""
    solid, _ = _load(ctx)
    with np.load(folder / "field.npz") as f:
        grid = VoxelGrid(f["occupied"], f["origin"], float(f["voxel_size"]))
        return FieldResult(solid, f["platform_vertices"], grid, f["peeling"], f["growing"], report)


def run_layers(ctx: Context) -> LayersResult:
    """Growing field → one working surface per layer, dual-contoured and trimmed by H (§3.4.5)."""
    s, fr = ctx.settings, ctx.results["field"]
    grid = fr.grid
    count = len(layer_levels(int(fr.growing.max()), grid.voxel_size, s.layer_height))
    start = time.perf_counter()
    with ctx.bar("working surfaces", count, unit="layer") as bar:
        layers = extract_working_surfaces(fr.growing, grid.origin, grid.voxel_size, fr.solid,
                                          layer_height=s.layer_height, occupied=grid.occupied, progress=bar,
                                          executor=ctx.executor)
    faces = [len(m.faces) for m in layers]
    report = {
        "count": len(layers), "layer_height_mm": s.layer_height or grid.voxel_size,
        "triangles": sum(faces), "untrimmed_triangles": sum(m.metadata["untrimmed_faces"] for m in layers),
        "triangles_per_layer": faces,
        "lowered": [m.metadata["layer"] for m in layers if m.metadata["lowered"]],
        "empty": [m.metadata["layer"] for m in layers if not len(m.faces)],
        "separated_vertices": sum(m.metadata["separated_vertices"] for m in layers),
        "dropped_faces": sum(m.metadata["dropped_faces"] for m in layers),
        "dual_contouring_s": round(sum(m.metadata["dc_seconds"] for m in layers), 3),
        "trimming_s": round(sum(m.metadata["trim_seconds"] for m in layers), 3),
        "timings_s": {"layers": round(time.perf_counter() - start, 3)},
    }
    if not ctx.quiet:
        print(f"layers: {len(layers)} working surfaces, {sum(faces)} triangles ({report['timings_s']['layers']:.1f} s)")
    return LayersResult(layers, report)


def run_toolpaths(ctx: Context) -> ToolpathsResult:
    """Working surfaces → connected Fermat spirals, Eq. 3.3 orientations, extrusion (§3.5.1-3.5.2)."""
    layers = ctx.results["layers"].layers
    settings = ctx.settings.toolpath_settings()
    start = time.perf_counter()
    with ctx.bar("tool-paths", len(layers), unit="layer") as bar:
        tp = plan_toolpaths(layers, settings, progress=bar, executor=ctx.executor)
    seconds = time.perf_counter() - start
    if not len(tp.positions):
        raise CurvsliceError(f"no tool-path fits on any of the {len(layers)} layers (every region is narrower than "
                             f"the path width {settings.path_width:g} mm): choose a smaller --voxel or --path-width")
    own = [(i, m, tp.layer == i) for i, m in enumerate(layers, start=1) if len(m.faces)]
    cover = ctx.executor.map(_layer_cover, [(i, m, tp.positions[at], tp.path[at], tp.bead[at]) for i, m, at in own],
                             width=settings.path_width)
    rows = tp.layers
    report = {
        "path_width_mm": settings.path_width, "samples": len(tp.positions), "pieces": sum(r["pieces"] for r in rows),
        "jumps": sum(r["jumps"] for r in rows), "gap_passes": sum(r["gap_passes"] for r in rows),
        "thin_passes": sum(r["thin_passes"] for r in rows), "off_layer_links": sum(r.get("off_layer_links", 0) for r in rows),
        "travel_mm": round(sum(r["travel_mm"] for r in rows), 3), "length_mm": round(sum(r["length_mm"] for r in rows), 3),
        "filament_mm": round(float(tp.extrusion.sum()), 3),
        "coverage_min": round(min((c for c, _ in cover), default=0.0), 4),
        "coverage_mean": round(float(np.mean([c for c, _ in cover])) if cover else 0.0, 4),
        "overlap_max": round(max((o for _, o in cover), default=0.0), 4),
        "spirals_s": round(tp.seconds["spirals"], 3), "orientation_s": round(tp.seconds["orientation"], 3),
        "per_layer": rows,
        "timings_s": {"toolpaths": round(seconds, 3)},
    }
    if not ctx.quiet:
        print(f"toolpaths: {report['samples']} samples, {report['pieces']} pieces ({report['jumps']} jumps), coverage "
              f"min {100 * report['coverage_min']:.1f}% mean {100 * report['coverage_mean']:.1f}% ({seconds:.1f} s)")
    return ToolpathsResult(tp, settings, report)


def _layer_cover(layer: tuple[int, trimesh.Trimesh, np.ndarray, np.ndarray, np.ndarray], width: float) -> tuple[float, float]:
    """:func:`~curvslice.verify.toolpaths.layer_cover` of one layer ``(number, mesh, positions, path, bead)``: a
    task of its own on the executor (it ran in the client, one layer after the other, after the stage)."""
    i, mesh, positions, path, bead = layer
    return layer_cover(mesh, positions, path, width, seed=i, bead=bead)


def run_robot(ctx: Context) -> RobotResult:
    """Oriented waypoints → pose-continuous, jerk-optimized joint trajectory of the workcell's arm
    (§3.5.3, §4.3), layer blocks as tasks on the executor -- in order where that is threads: a block runs 10-30 s,
    pinocchio and fcl hold the GIL (the kitten's stage 5 % faster on two), and an interrupt would wait for the
    running blocks. Skipped (``motion`` None) when no robot is set."""
    from curvslice.motion import motion_summary  # pinocchio / fcl only when a robot is planned
    from curvslice.robot_stage import plan_robot
    from curvslice.workcell import load_workcell

    s = ctx.settings
    if s.robot is None:
        return RobotResult(None, None, "skipped: no robot given")
    cell = load_workcell(s.robot)
    if s.rotations:
        cell = cell.with_rotations(s.rotations)
    tp = ctx.results["toolpaths"].toolpaths
    n = len(tp.positions)
    start = time.perf_counter()
    with ctx.bar(f"robot motion ({cell.name})", len(np.unique(tp.layer)), unit="layer") as bar:
        _, motion, jerk = plan_robot(cell, toolpath_arrays(tp), ctx.results["layers"].layers,
                                     ctx.results["field"].platform_vertices, s.motion_cost, s.max_rotations,
                                     s.trajectory, InProcess() if isinstance(ctx.executor, Threads) else ctx.executor, bar)
    if n and not len(motion.q):
        raise CurvsliceError(f"the workcell {cell.name} reaches none of the {n} waypoints with a collision-free pose: "
                             "move the part within the arm's reach (workcell JSON: platform/nozzle pose) or pick "
                             "another robot")
    seconds = time.perf_counter() - start
    graph_s = sum(layer["seconds"] for layer in motion.layers)
    skipped = [entry for layer in motion.layers for entry in layer["skipped_rows"]]
    report = {"workcell": cell.name, "robot": cell.robot, **motion_summary(motion, n), "jerk": jerk,
              "skipped_reasons": dict(Counter(e["reason"].split(" (")[0] for e in skipped)),
              "timings_s": {"robot": round(seconds, 3), "robot_graph": round(graph_s, 3),  # task seconds, summed
                            "robot_trajectory": round(float(jerk.get("seconds", 0.0)), 3)}}
    if not ctx.quiet:
        print(f"robot: {report['rows']}/{n} waypoints, {report['segments']} motions ({report['splits']} splits), "
              f"{report['skipped']} skipped, {report['deviated']} with the axis tilted "
              f"(max {report['max_deviation_deg']:.1f} deg), max joint step {report['max_joint_step_rad']:.4f} rad "
              f"({report['timings_s']['robot']:.1f} s)")
    return RobotResult(cell, motion, report)


def save_robot(r: RobotResult, out: Path, s: Settings, results: dict[str, Any]) -> None:
    if r.motion is None:
        return
    from curvslice.exporters.joints_csv import write_robot_outputs
    from curvslice.kinematics import load_robot

    write_robot_outputs(out, r.workcell, load_robot(r.workcell.robot).family,
                        toolpath_arrays(results["toolpaths"].toolpaths), r.motion)


def load_toolpaths(folder: Path, report: dict) -> Toolpaths:
    """:class:`Toolpaths` from ``toolpaths.npz`` and the per-layer rows of the stage's report section."""
    with np.load(folder / "toolpaths.npz") as f:
        arrays = {k: f[k] for k in f.files}
    return Toolpaths(**{k: arrays[k] for k in TOOLPATH_ARRAYS}, bead=arrays["bead"], layers=report["per_layer"],
                     seconds={"spirals": report["spirals_s"], "orientation": report["orientation_s"]})


#: The arrays of ``toolpaths.npz`` that later stages read.
TOOLPATH_ARRAYS = ("positions", "normals", "layer", "path", "extrusion", "thickness", "feed")


def toolpath_arrays(tp: Toolpaths) -> dict[str, np.ndarray]:
    """The ``toolpaths.npz`` arrays of ``tp`` by name (what the robot stage and the exporters read)."""
    return {k: getattr(tp, k) for k in TOOLPATH_ARRAYS}


@dataclass(frozen=True)
class Stage:
    """A pipeline stage: ``run(ctx) -> result``, ``save(result, folder, settings, results)``,
    ``load(ctx, folder, report) -> result``, and the output files it owns (for resume)."""

    name: str
    run: Callable[[Context], Any]
    save: Callable[..., None]
    load: Callable[[Context, Path, dict], Any] | None
    files: tuple[str, ...]


#: The pipeline, in order. Add a stage here: everything else (CLI --stages, resume, report) follows.
STAGES: tuple[Stage, ...] = (
    Stage("field", run_field, lambda r, out, s, res: save_field(r, out, s), load_field, ("field.npz", "solid.stl")),
    Stage("layers", run_layers, lambda r, out, s, res: write_layers(out, r.layers),
          lambda ctx, folder, report: LayersResult(load_layers(folder), report), ("layers",)),
    Stage("toolpaths", run_toolpaths, lambda r, out, s, res: save_toolpaths(out, r.toolpaths, r.settings),
          lambda ctx, folder, report: ToolpathsResult(load_toolpaths(folder, report), ctx.settings.toolpath_settings(),
                                                      report),
          ("toolpaths.npz", "toolpaths.gcode")),
    Stage("robot", run_robot, save_robot, None, ()),
)
STAGE_NAMES: tuple[str, ...] = tuple(s.name for s in STAGES)


def stage(name: str) -> Stage:
    """The registered stage called ``name`` (benchmarks time stages one by one through this)."""
    for s in STAGES:
        if s.name == name:
            return s
    raise CurvsliceError(f"unknown stage {name!r}; choose one of {', '.join(STAGE_NAMES)}")


# ------------------------------------------------------------------------------------------- the slice


@dataclass
class Slice:
    """The results of one run, by stage, with its settings and ``report.json`` content."""

    model: str
    settings: Settings
    results: dict[str, Any]
    report: dict
    folder: Path | None = None

    @property
    def field(self) -> FieldResult:
        return self.results["field"]

    @property
    def layers(self) -> list[trimesh.Trimesh]:
        return self.results["layers"].layers

    @property
    def toolpaths(self) -> Toolpaths:
        return self.results["toolpaths"].toolpaths

    @property
    def robot(self) -> RobotResult:
        return self.results["robot"]


def model_digest(model: str | Path | trimesh.Trimesh) -> str:
    """SHA-256 of the model: the file's bytes, or an in-memory mesh's vertex and face arrays."""
    h = hashlib.sha256()
    if isinstance(model, trimesh.Trimesh):
        h.update(np.ascontiguousarray(model.vertices, np.float64).tobytes())
        h.update(np.ascontiguousarray(model.faces, np.int64).tobytes())
    else:
        path = Path(model)
        if not path.is_file():
            raise CurvsliceError(f"{path}: no such file")
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def stage_keys(model: str | Path | trimesh.Trimesh, settings: Settings) -> dict[str, str]:
    """Per stage, a hash of the model, the settings of this and every earlier stage (the robot stage's:
    with the workcell's content, so an edited workcell file is never reused), and the pipeline version:
    a stage whose key is unchanged would compute the same result."""
    keys, previous = {}, f"{PIPELINE_VERSION}:{model_digest(model)}"
    for stage in STAGES:
        inputs = settings.of_stage(stage.name)
        if stage.name == "robot" and settings.robot is not None:  # the workcell's content, not only its name
            from curvslice.workcell import load_workcell, workcell_to_dict

            inputs["workcell"] = workcell_to_dict(load_workcell(settings.robot))
        text = json.dumps([previous, stage.name, inputs], sort_keys=True, default=str)
        previous = keys[stage.name] = hashlib.sha256(text.encode()).hexdigest()[:16]
    return keys


def read_report(folder: str | Path) -> dict:
    """``report.json`` of a slice folder (a clear error when it is missing or not JSON)."""
    path = Path(folder) / "report.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise CurvsliceError(f"{folder} is not a curvslice output folder (no report.json)") from None
    except (OSError, ValueError) as exc:
        raise CurvsliceError(f"{path} is not readable JSON ({exc})") from None


def settings_of(folder: str | Path) -> Settings:
    """The :class:`Settings` a slice folder was made with."""
    report = read_report(folder)
    stored = report.get("parameters")
    if report.get("pipeline") != PIPELINE_VERSION or not isinstance(stored, dict):
        raise CurvsliceError(f"{folder}/report.json has no settings (made by an older curvslice); slice afresh")
    names = {f.name for f in dataclasses.fields(Settings)}
    return Settings(**{k: v for k, v in stored.items() if k in names})


def run(model: str | Path | trimesh.Trimesh, settings: Settings | None = None, until: str = "toolpaths",
        out: str | Path | None = None, resume: str | Path | None = None, force: bool = False, quiet: bool = True,
        after: Callable[[Slice, Path], None] | None = None, redo: str | None = None,
        executor: Executor | None = None) -> Slice:
    """Run the stages up to and including ``until`` on ``model`` (a mesh file or a Trimesh).

    ``out``: write the output folder atomically (an existing one is replaced only with ``force``).
    ``resume``: a folder of an earlier run whose stages are reused while their keys match (their files
    are copied, their results loaded); the first stage whose key differs and every later one run anew, and
    so do stage ``redo`` and every later one (to time or re-check a stage whose inputs did not change).
    ``after(slice, tmp)`` may add files to the folder before it becomes final (the CLI's preview).
    ``executor``: where the stages' per-layer tasks run (default in-process; a Dask cluster from
    :func:`curvslice.executors.open_executor`) -- the results are the same.
    """
    settings = settings or Settings()
    stage(until)  # an unknown name is an error before any work
    if settings.robot is not None and STAGE_NAMES.index(until) >= STAGE_NAMES.index("robot"):
        from curvslice.workcell import load_workcell

        load_workcell(settings.robot)  # a bad workcell fails now, not after the slicing stages
    keys = stage_keys(model, settings)
    old = _reusable(resume, keys, redo) if resume is not None else {}
    protect = () if isinstance(model, trimesh.Trimesh) else (Path(model),)
    folder = atomic_folder(out, force=force, protect=protect) if out is not None else nullcontext(None)
    with folder as tmp:
        result = _run_stages(model, settings, until, keys, old, tmp, quiet, executor or InProcess())
        if tmp is not None:
            if after is not None:
                after(result, tmp)
            # every file written, so `curvslice verify` can require each one (a deleted file is a FAIL)
            result.report["files"] = sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file())
            (tmp / "report.json").write_text(json.dumps(result.report, indent=2, default=_jsonable))
    if out is not None:
        result.folder = Path(out)
    return result


def _reusable(resume: str | Path, keys: dict[str, str], redo: str | None = None) -> dict[str, Any]:
    """The leading stages of folder ``resume`` before ``redo`` whose keys equal ``keys``: name -> (folder,
    report section)."""
    folder = Path(resume)
    report = read_report(folder)
    done, old_keys = report.get("stages", []), report.get("stage_keys", {})
    reuse = {}
    for stage in STAGES:
        if stage.name == redo or stage.name not in done or old_keys.get(stage.name) != keys[stage.name] \
                or stage.load is None:
            break
        reuse[stage.name] = (folder, report.get(stage.name, {}))
    return reuse


def _run_stages(model, settings: Settings, until: str, keys: dict[str, str], old: dict[str, Any],
                tmp: Path | None, quiet: bool, executor: Executor) -> Slice:
    report: dict[str, Any] = {
        "curvslice": __version__, "model": str(Path(model).resolve()) if not isinstance(model, trimesh.Trimesh) else
        "<in-memory mesh>", "pipeline": PIPELINE_VERSION, "stages": [], "reused": [], "stage_keys": {},
        "parameters": asdict(settings),
        "timings_s": {},
    }
    ctx = Context(model, settings, {}, quiet, executor)
    start = time.perf_counter()
    for stage in STAGES[:STAGE_NAMES.index(until) + 1]:
        if stage.name in old:
            folder, section = old[stage.name]
            if tmp is not None:
                for name in stage.files:
                    _copy(folder / name, tmp / name)
            ctx.results[stage.name] = stage.load(ctx, folder, section)
            report["reused"].append(stage.name)
            if not quiet:
                print(f"{stage.name}: reused from {folder}")
        else:
            ctx.results[stage.name] = stage.run(ctx)
            if tmp is not None:
                stage.save(ctx.results[stage.name], tmp, settings, ctx.results)
        section = ctx.results[stage.name].report
        report[stage.name] = section
        if isinstance(section, dict):
            report["timings_s"].update({k: v for k, v in section.get("timings_s", {}).items()
                                        if stage.name not in old})
        if isinstance(section, str):  # skipped (the robot stage without a robot): nothing written to verify
            continue
        report["stages"].append(stage.name)
        report["stage_keys"][stage.name] = keys[stage.name]
    report["timings_s"]["total"] = round(time.perf_counter() - start, 3)
    return Slice(report["model"], settings, ctx.results, report)


def _copy(src: Path, dst: Path) -> None:
    if src.is_dir():
        shutil.copytree(src, dst)
    elif src.is_file():
        shutil.copy2(src, dst)
    else:
        raise CurvsliceError(f"cannot resume: {src} is missing from the earlier output folder")


def _jsonable(obj: object) -> object:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (np.ndarray, Path, tuple)):
        return obj.tolist() if isinstance(obj, np.ndarray) else str(obj)
    raise CurvsliceError(f"report value of type {type(obj).__name__} is not JSON-serializable")

