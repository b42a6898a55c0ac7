"""``curvslice slice MODEL``: run the pipeline stages in order and write one output folder.

The stages are plain functions ``stage(ctx) -> None`` listed in :data:`STAGES`; each calls the
library, writes its artefacts into ``ctx.out`` (a temporary folder made final only on success),
keeps what later stages need in ``ctx.data`` and its figures in ``ctx.report``. No algorithm here.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from curvslice import __version__
from curvslice.collision import CollisionScene
from curvslice.convex_front import GROW_EPS, PEEL_EPS
from curvslice.errors import CurvsliceError
from curvslice.exporters.joints_csv import write_robot_outputs
from curvslice.growing_field import METHODS, growing_field
from curvslice.kinematics import ROBOT_NAMES, load_robot
from curvslice.motion import motion_summary, plan_print
from curvslice.outdir import atomic_folder
from curvslice.peeling_field import peeling_field
from curvslice.platform import DEFAULT_MARGIN, DEFAULT_THICKNESS, disc_platform, load_platform
from curvslice.solid import UP_AXES, load_solid
from curvslice.toolpaths import ToolpathSettings, plan_toolpaths, save_toolpaths
from curvslice.verify.toolpaths import layer_cover
from curvslice.voxelize import voxelize
from curvslice.workcell import load_workcell
from curvslice.working_surfaces import extract_working_surfaces, layer_levels, write_layers


@dataclass
class Context:
    """What the stages share: parsed arguments, the folder being written, the report and data."""

    args: argparse.Namespace
    out: Path
    report: dict = field(default_factory=dict)
    data: dict = field(default_factory=dict)

    def bar(self, desc: str, total: int, unit: str = "voxel") -> tqdm:
        return tqdm(total=total, desc=desc, unit=unit, unit_scale=True, leave=False,
                    disable=self.args.quiet, dynamic_ncols=True)

    @contextmanager
    def timed(self, key: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        self.report.setdefault("timings_s", {})[key] = round(time.perf_counter() - start, 3)


def stage_field(ctx: Context) -> None:
    """Solid → conservative voxels → inverse peeling field → growing field (§3.4.1-3.4.4)."""
    a = ctx.args
    with ctx.timed("load"):
        solid, load = load_solid(a.model, up=a.up, size=a.size, scale=a.scale)
    platform = load_platform(a.platform) if a.platform else disc_platform(
        solid, margin=a.platform_margin, thickness=a.platform_thickness)
    with ctx.timed("voxelize"):
        grid = voxelize(solid, a.voxel, memory_limit=int(a.memory_limit * 2**30))
    n = int(grid.occupied.sum())
    peel = np.zeros(grid.shape, np.int32)
    if a.method == "pg-sp-gcfa":
        with ctx.timed("peeling"), ctx.bar("peeling field", n) as bar:
            peel = peeling_field(grid, platform.vertices, eps=a.peel_eps, progress=bar)
    with ctx.timed("growing"), ctx.bar(f"growing field ({a.method})", n) as bar:
        growing, stats = growing_field(grid, platform.vertices, a.method, peeling=peel,
                                       delta_f=a.delta_f, eps=a.eps, progress=bar)
    solid.export(ctx.out / "solid.stl")
    np.savez_compressed(
        ctx.out / "field.npz", occupied=grid.occupied, peeling=peel, growing=growing,
        origin=grid.origin, voxel_size=np.float64(grid.voxel_size), method=np.str_(a.method),
        platform_vertices=np.asarray(platform.vertices, float), eps=np.float64(a.eps),
    )
    ctx.data.update(solid=solid, platform=platform, grid=grid, peeling=peel, growing=growing)
    ctx.report["load"] = asdict(load)
    ctx.report["field"] = {
        "grid_shape": list(grid.shape), "voxels": n, "layers": stats.layers, "missed": stats.missed,
        "max_peeling": int(peel.max()), "shadow_tests": stats.shadow_tests,
        "shadow_fallbacks": stats.shadow_fallbacks, "held_back": stats.held_back,
        "threshold_steps": stats.threshold_steps, "layer_sizes": stats.layer_sizes,
        "platform_radius_mm": round(float(np.linalg.norm(platform.vertices[:, :2], axis=1).max()), 3),
    }
    if not a.quiet:
        print(f"field: {n} voxels, {stats.layers} layers, {stats.missed} missed "
              f"({ctx.report['timings_s'].get('growing', 0):.1f} s growing)")


def stage_layers(ctx: Context) -> None:
    """Growing field → one working surface per layer, dual-contoured and trimmed by H (§3.4.5)."""
    a, d = ctx.args, ctx.data
    grid = d["grid"]
    count = len(layer_levels(int(d["growing"].max()), grid.voxel_size, a.layer_height))
    with ctx.timed("layers"), ctx.bar("working surfaces", count, unit="layer") as bar:
        layers = extract_working_surfaces(d["growing"], grid.origin, grid.voxel_size, d["solid"],
                                          layer_height=a.layer_height, occupied=grid.occupied, progress=bar)
        write_layers(ctx.out, layers)
    d["layers"] = layers
    faces = [len(m.faces) for m in layers]
    ctx.report["layers"] = {
        "count": len(layers), "layer_height_mm": a.layer_height or grid.voxel_size,
        "triangles": sum(faces), "untrimmed_triangles": sum(m.metadata["untrimmed_faces"] for m in layers),
        "triangles_per_layer": faces,
        "lowered": [m.metadata["layer"] for m in layers if m.metadata["lowered"]],
        "empty": [m.metadata["layer"] for m in layers if not len(m.faces)],
        "separated_vertices": sum(m.metadata["separated_vertices"] for m in layers),
        "dropped_faces": sum(m.metadata["dropped_faces"] for m in layers),
        "dual_contouring_s": round(sum(m.metadata["dc_seconds"] for m in layers), 3),
        "trimming_s": round(sum(m.metadata["trim_seconds"] for m in layers), 3),
    }
    if not a.quiet:
        print(f"layers: {len(layers)} working surfaces, {sum(faces)} triangles "
              f"({ctx.report['timings_s']['layers']:.1f} s)")


def stage_toolpaths(ctx: Context) -> None:
    """Working surfaces → connected Fermat spirals, Eq. 3.3 orientations, E, extended G-code (§3.5.1-3.5.2)."""
    a, layers = ctx.args, ctx.data["layers"]
    settings = ToolpathSettings(
        path_width=a.path_width or ctx.data["grid"].voxel_size / 0.8, step=a.step, filament_diameter=a.filament,
        feed=a.feed, max_tilt=float(np.radians(a.max_tilt)), fill_gaps=not a.no_gap_passes)
    with ctx.timed("toolpaths"), ctx.bar("tool-paths", len(layers), unit="layer") as bar:
        tp = plan_toolpaths(layers, settings, progress=bar)
        save_toolpaths(ctx.out, tp, settings)
    ctx.data["toolpaths"] = tp
    cover = [layer_cover(m, tp.positions[tp.layer == i], tp.path[tp.layer == i], settings.path_width, seed=i,
                         bead=tp.bead[tp.layer == i]) for i, m in enumerate(layers, start=1) if len(m.faces)]
    rows = tp.layers
    ctx.report["toolpaths"] = {
        "path_width_mm": settings.path_width, "samples": len(tp.positions), "pieces": sum(r["pieces"] for r in rows),
        "jumps": sum(r["jumps"] for r in rows), "gap_passes": sum(r["gap_passes"] for r in rows),
        "thin_passes": sum(r["thin_passes"] for r in rows),
        "travel_mm": round(sum(r["travel_mm"] for r in rows), 3), "length_mm": round(sum(r["length_mm"] for r in rows), 3),
        "filament_mm": round(float(tp.extrusion.sum()), 3),
        "coverage_min": round(min((c for c, _ in cover), default=0.0), 4),
        "coverage_mean": round(float(np.mean([c for c, _ in cover])) if cover else 0.0, 4),
        "overlap_max": round(max((o for _, o in cover), default=0.0), 4),
        "spirals_s": round(tp.seconds["spirals"], 3), "orientation_s": round(tp.seconds["orientation"], 3),
        "per_layer": rows,
    }
    if not a.quiet:
        r = ctx.report["toolpaths"]
        print(f"toolpaths: {r['samples']} samples, {r['pieces']} pieces ({r['jumps']} jumps), coverage "
              f"min {100 * r['coverage_min']:.1f}% mean {100 * r['coverage_mean']:.1f}% "
              f"({ctx.report['timings_s']['toolpaths']:.1f} s)")


def stage_robot(ctx: Context) -> None:
    """Oriented waypoints → pose-continuous joint trajectory of the workcell's arm, robot programs
    (§3.5.3, §4.3.1). Runs only when ``--robot`` names a workcell."""
    a = ctx.args
    if a.robot is None:
        ctx.report["robot"] = "skipped: no --robot given"
        return
    cell = load_workcell(a.robot)
    if a.rotations:
        cell = cell.with_rotations(a.rotations)
    robot = load_robot(cell.robot)
    with np.load(ctx.out / "toolpaths.npz") as f:
        toolpaths = {k: f[k] for k in f.files}
    layers, n = ctx.data["layers"], len(toolpaths["positions"])
    scene = CollisionScene(robot, cell, ctx.data["platform"].vertices)
    with ctx.timed("robot"), ctx.bar(f"robot motion ({cell.name})", n, unit="waypoint") as bar:
        motion = plan_print(robot, cell, toolpaths, lambda layer: scene.for_layer(layers, layer),
                            cost=a.motion_cost, max_rotations=a.max_rotations, progress=bar.update)
        write_robot_outputs(ctx.out, cell, robot.family, toolpaths, motion)
    ctx.report["robot"] = {"workcell": cell.name, "robot": cell.robot, **motion_summary(motion, n)}
    if not a.quiet:
        r = ctx.report["robot"]
        print(f"robot: {r['rows']}/{n} waypoints, {r['segments']} motions ({r['splits']} splits), "
              f"{r['skipped']} skipped, {r['deviated']} with the axis tilted (max {r['max_deviation_deg']:.1f} deg), "
              f"max joint step {r['max_joint_step_rad']:.4f} rad "
              f"({ctx.report['timings_s']['robot']:.1f} s)")


#: The pipeline, in order: (name, stage function).
STAGES: list[tuple[str, Callable[[Context], None]]] = [
    ("field", stage_field),
    ("layers", stage_layers),
    ("toolpaths", stage_toolpaths),
    ("robot", stage_robot),
]


DESCRIPTION = (
    "Decompose a solid into curved, support-free, accessible layers (thesis §3.4), cover them with "
    "Fermat-spiral tool-paths (§3.5.1-3.5.2) and, with --robot, plan pose-continuous robot motion "
    "(§3.5.3). Writes one output folder: field.npz, solid.stl, layers/, toolpaths.gcode/.npz, robot "
    "programs and report.json; check it with `curvslice verify OUTDIR`."
)


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows defaults, except where the help text already explains them or there is none."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text or action.default in (None, False, argparse.SUPPRESS):
            return text
        return super()._get_help_string(action)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("slice", help="slice a solid into curved, support-free layers (and beyond)",
                       description=DESCRIPTION, formatter_class=_HelpFormatter)
    p.add_argument("model", help="mesh file (STL, OBJ, PLY, OFF), millimetres")
    p.add_argument("--out", help="output folder (default: MODELNAME_slice in the current folder)")
    p.add_argument("--force", action="store_true", help="replace an existing output folder")
    p.add_argument("--stages", default=STAGES[-1][0], choices=[s for s, _ in STAGES],
                   help="run the pipeline up to and including this stage")
    g = p.add_argument_group("model placement")
    g.add_argument("--up", default="z", choices=sorted(UP_AXES), help="model axis that points up")
    g.add_argument("--size", type=float, help="scale uniformly so the longest extent is SIZE mm")
    g.add_argument("--scale", type=float, default=1.0, help="uniform scale factor (ignored with --size)")
    g = p.add_argument_group("platform T")
    g.add_argument("--platform", help="platform mesh in the model frame (top at z = 0); default: a disc slab")
    g.add_argument("--platform-margin", type=float, default=DEFAULT_MARGIN, help="disc radius beyond the footprint, mm")
    g.add_argument("--platform-thickness", type=float, default=DEFAULT_THICKNESS, help="disc thickness, mm")
    g = p.add_argument_group("volume decomposition (§3.4)")
    g.add_argument("--voxel", type=float, default=1.0, help="voxel width w, mm")
    g.add_argument("--method", default="pg-sp-gcfa", choices=METHODS, help="growing-field method")
    g.add_argument("--delta-f", type=int, default=1, help="Δf, peeling-field threshold step (Alg. 5)")
    g.add_argument("--eps", type=float, default=GROW_EPS, help="ε of the inside test, in voxel widths")
    g.add_argument("--peel-eps", type=float, default=PEEL_EPS, help="ε of the peeling shells, in voxel widths")
    g.add_argument("--memory-limit", type=float, default=8.0, help="refuse grids needing more than this, GiB")
    g.add_argument("--layer-height", type=float, help="d of Eq. 3.2, mm (default: the voxel width)")
    g = p.add_argument_group("tool-paths (§3.5.1-3.5.2)")
    g.add_argument("--path-width", type=float, help="spacing of the spiral passes, mm (default: voxel / 0.8, the nozzle of §3.6)")
    g.add_argument("--step", type=float, default=1.0, help="re-sampling distance along the paths, mm (§3.5.2)")
    g.add_argument("--filament", type=float, default=1.75, help="filament diameter, mm")
    g.add_argument("--feed", type=float, default=600.0, help="nozzle speed along the paths, mm/min")
    g.add_argument("--max-tilt", type=float, default=40.0,
                   help="largest angle between tool and layer normal, degrees (the shipped nozzle cone clears 40)")
    g.add_argument("--no-gap-passes", action="store_true", help="spirals only: no extra passes through the gaps they leave")
    g = p.add_argument_group("robot (§3.5.3, §4.3.1)")
    g.add_argument("--robot", type=_workcell_arg, help=f"workcell: {', '.join(ROBOT_NAMES)} (shipped) or a workcell JSON file; "
                   "plans the arm's motion and writes joints.csv + programs (without it the robot stage is skipped)")
    g.add_argument("--rotations", type=int,
                   help="p, rotations about the nozzle axis per waypoint (default: the workcell's, 30); a ladder "
                        "starts from p halved while ≥ 8 (30: 15) and doubles it per rung where the motion breaks")
    g.add_argument("--max-rotations", type=int, help="largest p when doubling to remove splits (default: 4 p)")
    g.add_argument("--motion-cost", default="l1", choices=("l1", "quadratic"), help="edge weight: Eq. 3.4 or Eq. 4.5")
    p.add_argument("--quiet", action="store_true", help="no progress bars or summary lines")
    p.add_argument("--preview", action="store_true", help="also write preview.png (layers by print order, cut-away; tool-paths of one layer)")
    p.add_argument("--preview-layer", type=int, help="layer whose tool-paths preview.png shows (default: the middle one)")
    p.set_defaults(run=run)


def _workcell_arg(text: str) -> str:
    """Check ``--robot`` while parsing, not after the slicing stages."""
    try:
        load_workcell(text)
    except CurvsliceError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def run(args: argparse.Namespace) -> int:
    model = Path(args.model)
    out = Path(args.out) if args.out else Path.cwd() / f"{model.stem}_slice"
    last = [s for s, _ in STAGES].index(args.stages)
    with atomic_folder(out, force=args.force, protect=(model,)) as tmp:
        ctx = Context(args=args, out=tmp)
        ctx.report.update(curvslice=__version__, model=str(model.resolve()), stages=[],
                          parameters={k: v for k, v in vars(args).items() if k != "run"})
        start = time.perf_counter()
        for name, stage in STAGES[:last + 1]:
            stage(ctx)
            ctx.report["stages"].append(name)
        ctx.report.setdefault("timings_s", {})["total"] = round(time.perf_counter() - start, 3)
        if args.preview:
            from curvslice.viz import preview_png, read_slice_folder  # matplotlib/meshcat only when asked

            preview_png(read_slice_folder(tmp), tmp / "preview.png", args.preview_layer)
        (tmp / "report.json").write_text(json.dumps(ctx.report, indent=2, default=_jsonable))
    if not args.quiet:
        print(f"wrote {out}")
    return 0


def _jsonable(obj: object) -> object:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (np.ndarray, Path, tuple)):
        return obj.tolist() if isinstance(obj, np.ndarray) else str(obj)
    raise CurvsliceError(f"report value of type {type(obj).__name__} is not JSON-serializable")
