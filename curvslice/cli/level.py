"""``curvslice level``: bed levelling after seed 004 (probe a grid with SearchL, report the map).

``curvslice level routine --xs X0 X1 NX --ys Y0 Y1 NY --cell CELL --out DIR`` writes the RAPID
probing module, which records the touched points to a CSV on the controller; ``curvslice level
report probe.csv`` summarises a measured map. ``curvslice convert --level probe.csv`` applies it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from curvslice.cell.cells import load_cell
from curvslice.cell.levelling import MAX_PROBES, read_probe_csv
from curvslice.errors import CurvsliceError
from curvslice.exporters.rapid import check_identifier, write_probe_routine
from curvslice.outdir import atomic_files
from curvslice.validate import argument_type, check_budget, input_file, number, program_name


def _identifier(text: str) -> str:
    """``--signal``: a RAPID identifier (it is written into the module as is)."""
    check_identifier(text)
    return text


def add_parser(subparsers) -> None:
    p = subparsers.add_parser("level", help="bed levelling: write the RAPID probing routine, or report a probed map",
                              description=__doc__.split("\n\n")[1])
    sub = p.add_subparsers(dest="level_command", required=True, metavar="ACTION")
    r = sub.add_parser("routine", help="write the RAPID SearchL probing module for a grid")
    r.add_argument("--xs", type=number("mm or points"), nargs=3, metavar=("X0", "X1", "NX"), required=True, help="x range and count, mm")
    r.add_argument("--ys", type=number("mm or points"), nargs=3, metavar=("Y0", "Y1", "NY"), required=True, help="y range and count, mm")
    r.add_argument("--cell", default="generic", help="cell preset or JSON file (tool, work object, orientation)")
    r.add_argument("--probe-offset", type=number("mm"), nargs=3, default=(0.0, 0.0, 0.0), metavar=("DX", "DY", "DZ"),
                   help="probe tip minus nozzle tip, mm (seed 004: 24.88 -39.05 2.4)")
    r.add_argument("--signal", type=argument_type(_identifier, "RAPID identifier"), default="diProbe", help="digital input raised by the probe")
    r.add_argument("--name", type=program_name, default="BedProbe", help="module and procedure name")
    r.add_argument("--out", type=Path, default=Path("."), help="output folder")
    r.set_defaults(run=run_routine)
    s = sub.add_parser("report", help="summarise a probed height map (x,y,z CSV)")
    s.add_argument("probe", type=input_file, help="CSV of probed points x,y,z")
    s.set_defaults(run=run_report)


def _axis(spec: list[float], label: str) -> np.ndarray:
    start, stop, count = spec
    if count < 2 or count != int(count) or stop <= start:
        raise CurvsliceError(f"--{label} needs START < STOP (mm) and an integer COUNT >= 2, got {start:g} {stop:g} {count:g}")
    check_budget(f"--{label}: probe points along the axis", count, MAX_PROBES, "probe a coarser grid")
    return np.linspace(start, stop, int(count))


def run_routine(args: argparse.Namespace) -> int:
    xs, ys = _axis(args.xs, "xs"), _axis(args.ys, "ys")
    check_budget("--xs x --ys: probe points", len(xs) * len(ys), MAX_PROBES, "probe a coarser grid")
    cell = load_cell(args.cell)
    with atomic_files(args.out, protect=[Path(args.cell)] if Path(args.cell).is_file() else []) as tmp:
        count = write_probe_routine(
            tmp / f"{args.name}.mod", xs, ys, name=args.name, probe_offset=tuple(args.probe_offset),
            orientation=cell.orientation, signal=args.signal, tool=cell.rapid.tool, wobj=cell.rapid.wobj,
        )
    print(f"wrote {args.out / f'{args.name}.mod'}: {count} probe points, results to HOME:/probe.csv")
    return 0


def run_report(args: argparse.Namespace) -> int:
    hmap = read_probe_csv(args.probe)
    X, Y = np.meshgrid(np.linspace(hmap.xs[0], hmap.xs[-1], 101), np.linspace(hmap.ys[0], hmap.ys[-1], 101))
    tilt = np.degrees(np.arccos(hmap.normal(X, Y)[..., 2]))
    print(f"{len(hmap.xs)} x {len(hmap.ys)} probes over [{hmap.xs[0]:g}..{hmap.xs[-1]:g}] x "
          f"[{hmap.ys[0]:g}..{hmap.ys[-1]:g}] mm: height {hmap.z.min():.3f}..{hmap.z.max():.3f} mm "
          f"(peak-to-peak {np.ptp(hmap.z):.3f} mm), max tilt {tilt.max():.2f} deg")
    return 0
