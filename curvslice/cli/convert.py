"""``curvslice convert IN.gcode --to vplus|rapid|urscript|gcode6 --cell CELL``: slicer G-code to robot programs.

Reads planar slicer G-code strictly (:mod:`curvslice.cell.gcode`), maps it onto the cell
(:mod:`curvslice.cell.cells`: offset, workspace, nozzle orientation), optionally levels it on a probed
bed (:mod:`curvslice.cell.levelling`) and writes each requested target through the exporters.
Seeds 003 (V+ + Arduino sketch) and 004 (RAPID, bed levelling) describe the targets.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from curvslice.cell.cells import Cell, gcode6_samples, load_cell, robot_path
from curvslice.cell.gcode import read_gcode
from curvslice.cell.levelling import level_path, read_probe_csv
from curvslice.exporters.arduino import write_accelstepper_sketch
from curvslice.exporters import rapid, urscript
from curvslice.exporters.gcode6 import write_gcode6
from curvslice.exporters.rapid import write_rapid
from curvslice.exporters.urscript import write_urscript
from curvslice.exporters.vplus import signal_count, speed_inventory, write_vplus
from curvslice.outdir import atomic_files
from curvslice.robot_path import RobotPath
from curvslice.validate import input_file, number, program_name

TARGETS = ("vplus", "rapid", "urscript", "gcode6")


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "convert",
        help="convert slicer G-code to V+, RAPID, URScript or extended G-code for a robot cell",
        description=__doc__.split("\n\n")[1],
    )
    p.add_argument("gcode", type=input_file, help="planar G-code (Slic3r, PrusaSlicer, Cura) or extended G-code")
    p.add_argument("--to", action="append", choices=TARGETS, required=True, help="target (repeat for several)")
    p.add_argument("--cell", default="generic", help="cell preset name or JSON cell file (default: generic)")
    p.add_argument("--out", type=Path, default=Path("."), help="output folder (default: current folder)")
    p.add_argument("--name", type=program_name, default=None, help="program name (default: the G-code file's stem)")
    p.add_argument("--offset", type=number("mm"), nargs=3, metavar=("X", "Y", "Z"), help="position offset, mm (overrides the cell)")
    p.add_argument("--fixed-orientation", action="store_true", help="ignore nX nY nZ; keep the cell's nozzle orientation")
    p.add_argument("--warn-workspace", action="store_true", help="report moves outside the workspace instead of refusing")
    p.add_argument("--lenient", action="store_true", help="warn about and skip unknown G-code instead of failing")
    p.add_argument("--level", type=input_file, metavar="PROBE_CSV", help="correct Z by a probed bed map (x,y,z CSV, robot frame)")
    p.add_argument("--level-reference", type=number("mm"), default=0.0, help="bed height the G-code assumes, mm (default 0)")
    p.add_argument("--level-tilt", action="store_true", help="also tilt the nozzle normal to the probed bed")
    p.set_defaults(run=run)


def _identifier(stem: str) -> str:
    name = "".join(c if c.isalnum() else "_" for c in stem)
    return name if name[:1].isalpha() else f"p_{name}"


def stale_files(name: str) -> list[str]:
    """Globs of the split files an earlier run of program ``name`` may have left (see :func:`atomic_files`)."""
    return [rapid.SPLIT_FILES.format(name=name), urscript.SPLIT_FILES.format(name=name)]


def write_targets(robot: RobotPath, cell: Cell, targets: list[str], out: Path, name: str, source: str) -> list[Path]:
    """Write ``robot`` once per target into the folder ``out``; returns the files written."""
    written: list[Path] = []
    for target in dict.fromkeys(targets):
        if target == "vplus":
            patterns = speed_inventory(robot)
            write_vplus(out / f"{name}.v2", robot, patterns, cell.vplus, program=name[:15])
            sketch = out / name / f"{name}.ino"
            sketch.parent.mkdir(exist_ok=True)
            write_accelstepper_sketch(sketch, patterns, signal_count(len(patterns), cell.vplus), cell.syringe)
            written += [out / f"{name}.v2", sketch]
        elif target == "rapid":
            written += write_rapid(out, robot, cell.rapid, name=name)
        elif target == "urscript":
            written += write_urscript(out, robot, cell.urscript, name=name)
        else:
            samples = gcode6_samples(robot, cell.orientation)
            header = {"source": source, "cell": cell.name, "offset_mm": list(cell.offset)}
            write_gcode6(out / f"{name}.gcode", header=header, path_id=samples.pop("path_id"), **samples)
            written.append(out / f"{name}.gcode")
    return written


def run(args: argparse.Namespace) -> int:
    cell = load_cell(args.cell)
    changes = {}
    if args.offset is not None:
        changes["offset"] = tuple(args.offset)
    if args.fixed_orientation:
        changes["use_normals"] = False
    if args.warn_workspace:
        changes["workspace_policy"] = "warn"
    cell = dataclasses.replace(cell, **changes)
    program = read_gcode(args.gcode, lenient=args.lenient, home=cell.home)
    robot, warnings = robot_path(program, cell)
    if args.level is not None:
        robot = level_path(robot, read_probe_csv(args.level), reference=args.level_reference, tilt=args.level_tilt)
    for message in program.warnings + warnings:
        print(f"curvslice convert: warning: {message}", file=sys.stderr)
    name = args.name or _identifier(args.gcode.stem)[:20]
    inputs = [args.gcode, *([args.level] if args.level else []), *([Path(args.cell)] if Path(args.cell).is_file() else [])]
    with atomic_files(args.out, protect=inputs, stale=stale_files(name)) as tmp:
        written = write_targets(robot, cell, args.to, tmp, name, source=args.gcode.name)
    print(f"converted {len(robot)} moves from {args.gcode} for cell {cell.name!r}: "
          + ", ".join(str(args.out / p.relative_to(tmp)) for p in written))
    return 0
