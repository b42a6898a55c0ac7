"""``curvslice decompose MODEL --out DIR``: RoboFDM planar multi-directional decomposition (thesis ch. 2).

Writes one mesh per part (``part_XX.stl``, in printing order), ``parts.json`` (each part's base
plane, build direction, parent, T_P^E of Eq. 2.3, risky area) and ``report.json``. With ``--print``
also the planar layers of every part (``layers/``) and the tool-paths of the whole sequence in the
platform frame (``toolpaths.npz``, ``toolpaths.gcode``), by the working-surface and tool-path stages;
the decomposition is then made for that layer height (no part thinner than two layers, faces within
one layer over the platform printed on it; 1 mm without ``--print``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from curvslice.decompose import decompose, write_decomposition
from curvslice.decompose.fine_tuning import Settings
from curvslice.decompose.printing import plan_robot, print_decomposition
from curvslice.decompose.risky import ALPHA_MAX_DEG
from curvslice.errors import CurvsliceError
from curvslice.outdir import atomic_folder
from curvslice.solid import load_solid
from curvslice.workcell import load_workcell


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("decompose", help="clip a model by planes into support-free parts printed in sequence (ch. 2)",
                       description=__doc__)
    p.add_argument("model", type=Path, help="closed mesh (STL/OBJ/PLY/OFF), mm, Z up")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--alpha-max", type=float, default=ALPHA_MAX_DEG,
                   help="maximal self-support angle α_max of Eq. 2.1, degrees (default 45: the usual FDM rule; "
                        "the thesis takes it from its ref. [26] without a value)")
    p.add_argument("--root", type=int, default=None,
                   help="coarse patch printed first (default: try each and keep the least risky)")
    p.add_argument("--analysis-tolerance", type=float, default=0.3,
                   help="simplification tolerance of the shape-analysis copy, mm (parts are cut from the full mesh)")
    p.add_argument("--max-parts", type=int, default=Settings.max_parts, help="stop the fine decomposition here")
    p.add_argument("--workcell", default="ur3",
                   help="workcell (name or JSON) whose extruder every part must clear the platform and the parts printed "
                        "before it with; 'none' for Constraints I and II alone (default ur3, the thesis's cell)")
    p.add_argument("--print", action="store_true", dest="print_parts",
                   help="also slice every part in planar layers along its build direction and plan the tool-paths "
                        "of the whole sequence (layers/, toolpaths.npz, toolpaths.gcode)")
    p.add_argument("--voxel", type=float, default=1.0, help="with --print: voxel width of the parts' layers, mm")
    p.add_argument("--layer-height", type=float, default=None, help="with --print: layer height, mm (default: --voxel)")
    p.add_argument("--path-width", type=float, default=None,
                   help="with --print: path width, mm (default: voxel / 0.8, as `curvslice slice`)")
    p.add_argument("--robot", default=None,
                   help="with --print: plan the arm's motion for the whole sequence (workcell name or JSON, e.g. ur3; "
                        "the robot stage of `curvslice slice`: joints.csv, programs, workcell.json)")
    p.add_argument("--robot-parts", type=int, nargs="+", default=None, metavar="K",
                   help="with --robot: plan only these parts (printing sequence numbers), the earlier parts' layers "
                        "still obstacles; the others' samples stay unrealized in the verifier's count")
    p.add_argument("--force", action="store_true", help="replace an existing output folder")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if not 0 < args.alpha_max < 90:
        raise CurvsliceError(f"--alpha-max must be in (0, 90) degrees (got {args.alpha_max})")
    for name in ("voxel", "layer_height", "path_width"):
        value = getattr(args, name)
        if value is not None and not (np.isfinite(value) and 0 < value <= 50):
            raise CurvsliceError(f"--{name.replace('_', '-')} must be in (0, 50] mm (got {value})")
    if (args.robot or args.robot_parts) and not args.print_parts:
        raise CurvsliceError("--robot and --robot-parts need --print (the robot follows the printed tool-paths)")
    if args.robot_parts and not args.robot:
        raise CurvsliceError("--robot-parts needs --robot")
    if args.robot:
        load_workcell(args.robot)
    solid, _ = load_solid(args.model)
    cell = None if args.workcell == "none" else args.workcell
    if cell is not None:
        load_workcell(cell)  # a bad name fails before any work
    # with --print the parts are cut for the layers they will be printed in (no part under two layers)
    layer = (args.layer_height or args.voxel) if args.print_parts else Settings.layer_height
    dec = decompose(solid, args.alpha_max, args.root, args.analysis_tolerance,
                    Settings(max_parts=args.max_parts, workcell=cell, layer_height=layer))
    with atomic_folder(args.out, force=args.force, protect=(args.model,)) as tmp:
        report = write_decomposition(dec, tmp, str(args.model), solid)
        if args.print_parts:
            report.update(print_decomposition(tmp, args.voxel, args.layer_height, args.path_width,
                                              meshes=[p.mesh for p in dec.parts], workcell=cell or "ur3"))
            if args.robot:
                bad = sorted(set(args.robot_parts or []) - set(range(len(dec.parts))))
                if bad:
                    raise CurvsliceError(f"--robot-parts {bad}: the decomposition has parts 0..{len(dec.parts) - 1}")
                report["robot"] = plan_robot(tmp, args.robot, quiet=False, parts=args.robot_parts)
    print(f"{report['parts']} parts in {report['timings_s']['total']:.1f} s; risky area per part (mm²): "
          + ", ".join(f"{a:.1f}" for a in report["risky_area_mm2"]))
    left = [k for k in range(report["parts"]) if k not in report["support_free_parts"]]
    print(f"support-free (≤ {report['support_free_mm2']:g} mm²): {report['parts'] - len(left)} of {report['parts']} parts"
          + ("; remainder (mm², on the underside + elsewhere): " + ", ".join(
              f"part {k} {report['risky_area_mm2'][k]:.1f} ({report['risky_underside_mm2'][k]:.1f} + "
              f"{report['risky_area_mm2'][k] - report['risky_underside_mm2'][k]:.1f})" for k in left) if left else ""))
    print(f"Constraint I violations: {report['constraint_one_violations'] or 'none'}; "
          f"Constraint II violations: {report['constraint_two_violations'] or 'none'}")
    if args.print_parts:
        tp = report["toolpaths"]
        print(f"printed: {report['layers']['count']} planar layers, {tp['samples']} samples, {tp['pieces']} pieces "
              f"({report['layers']['timings_s']['layers']:.1f} s layers, {tp['timings_s']['toolpaths']:.1f} s tool-paths)")
    if args.robot:
        r = report["robot"]
        print(f"robot ({r['workcell']}, parts {r['parts_planned']}): {r['rows']}/{r['waypoints']} waypoints planned, "
              f"{r['skipped']} skipped ({r['skipped_reasons'] or 'none'}), {r['timings_s']['robot']:.1f} s")
    print(f"wrote {args.out}")
    return 0
