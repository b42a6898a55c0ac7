"""``curvslice drape DESIGN.dxf --surface SURFACE``: print a 2D design on a curved platform (seed 000).

Reads the DXF, joins, centres/scales, removes overlaps and fills the design, projects it onto
the surface (``brooks`` = seed 000's platform polynomial, ``poly:c_n,…,c_0`` or a mesh file)
with the surface normal as nozzle axis, and writes RAPID / URScript / extended G-code (and V+)
through the same writers as ``curvslice convert``; ``drape.npz`` keeps the draped points.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from curvslice.cell.cells import check_workspace, load_cell
from curvslice.cell.drape import design_from_paths, drape, draped_robot_path, load_surface, read_dxf
from curvslice.cli.convert import TARGETS, stale_files, write_targets
from curvslice.outdir import atomic_files
from curvslice.validate import input_file, number, program_name

_MM, _POSITIVE_MM = number("mm"), number("mm", lo=0, lo_open=True)
_SPEED = number("mm/s", lo=0, lo_open=True, hi=10_000)


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("drape", help="drape a 2D DXF design onto a curved platform and write robot programs",
                              description=__doc__.split("\n\n")[1])
    p.add_argument("design", type=input_file, help="DXF with lines, arcs, circles, polylines, splines")
    p.add_argument("--surface", required=True, help="'brooks', 'poly:c_n,...,c_0' (z(r), highest power first) or a mesh file")
    p.add_argument("--to", action="append", choices=TARGETS, help="target (repeat for several; default gcode6)")
    p.add_argument("--cell", default="generic", help="cell preset or JSON file (offset, orientation, I/O)")
    p.add_argument("--out", type=Path, default=Path("."), help="output folder")
    p.add_argument("--name", type=program_name, default=None, help="program name (default: the DXF's stem)")
    p.add_argument("--layers", nargs="+", help="only these DXF layers")
    p.add_argument("--skip-unsupported", action="store_true", help="skip text, hatches … instead of failing")
    p.add_argument("--diameter", type=_POSITIVE_MM, help="scale the design to fit this diameter, mm (default: keep size)")
    p.add_argument("--step", type=_POSITIVE_MM, default=0.2, help="sampling step along paths, mm (seed 000: 0.2)")
    p.add_argument("--join-tolerance", type=number("mm", lo=0), default=0.005, help="join ends closer than this, mm (seed 000: 0.005)")
    p.add_argument("--overlap", choices=("first", "evenodd"), default="first",
                   help="first: earlier shapes win overlaps (seed 000); evenodd: nested shapes are holes")
    p.add_argument("--min-area", type=number("mm^2", lo=0), default=0.5, help="drop regions smaller than this, mm^2")
    p.add_argument("--no-fill", action="store_true", help="contours only")
    p.add_argument("--fill-angle", type=number("degrees"), default=0.0, help="scanline angle, degrees")
    p.add_argument("--fill-spacing", type=_POSITIVE_MM, default=0.8, help="scanline spacing, mm")
    p.add_argument("--clearance", type=number("mm", lo=0), default=0.8, help="fill kept this far from contours, mm (seed 000: 0.8)")
    p.add_argument("--fill-lift", type=_MM, default=0.0, help="raise fills along the normal, mm (seed 000: 0.2)")
    p.add_argument("--print-speed", type=_SPEED, default=10.0, help="mm/s")
    p.add_argument("--travel-speed", type=_SPEED, default=50.0, help="mm/s")
    p.add_argument("--travel-lift", type=number("mm", lo=0), default=5.0, help="lift along the normal between paths, mm")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    cell = load_cell(args.cell)
    surface = load_surface(args.surface)
    curves = read_dxf(args.design, layers=args.layers, strict=not args.skip_unsupported)
    design = design_from_paths(
        curves, step=args.step, join_tolerance=args.join_tolerance, diameter=args.diameter, overlap=args.overlap,
        min_area=args.min_area, fill_angle=math.radians(args.fill_angle), fill_spacing=args.fill_spacing,
        clearance=args.clearance, fill=not args.no_fill,
    )
    paths = drape(design, surface, fill_lift=args.fill_lift)
    robot = draped_robot_path(paths, cell, print_speed=args.print_speed, travel_speed=args.travel_speed,
                              travel_lift=args.travel_lift)
    for message in check_workspace(robot.positions, cell, [f"move {i}" for i in range(len(robot))]):
        print(f"curvslice drape: warning: {message}", file=sys.stderr)
    name = args.name or "".join(c if c.isalnum() else "_" for c in args.design.stem)[:20]
    inputs = [args.design, *(Path(s) for s in (args.cell, args.surface) if Path(s).is_file())]
    with atomic_files(args.out, protect=inputs, stale=stale_files(name)) as tmp:
        written = write_targets(robot, cell, args.to or ["gcode6"], tmp, name, source=args.design.name)
        written = [args.out / p.relative_to(tmp) for p in written]
        np.savez_compressed(
            tmp / "drape.npz",
            points=np.vstack([p.points for p in paths]),
            normals=np.vstack([p.normals for p in paths]),
            path=np.repeat(np.arange(len(paths)), [len(p.points) for p in paths]).astype(np.int32),
            kind=np.array([p.kind for p in paths]),
        )
    n_contours = sum(p.kind == "contour" for p in paths)
    print(f"draped {len(design.regions)} regions: {n_contours} contours + {len(paths) - n_contours} fill paths, "
          f"{sum(len(p.points) for p in paths)} points; wrote {', '.join(str(p) for p in written)}, "
          f"{args.out / 'drape.npz'}")
    return 0
