"""``curvslice workcell place --robot ur3 [--box MM]``: nozzle placement by reachability (thesis §2.3.1).

Samples joint configurations, drops the frames whose platform faces down, and moves the shipped
workcell's nozzle to the grid position whose box B holds the most frames. Writes the workcell JSON
and a PNG of the reachability map beside it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from curvslice.decompose.placement import place_nozzle, plot_reachability
from curvslice.errors import CurvsliceError
from curvslice.kinematics import ROBOT_NAMES, load_robot
from curvslice.workcell import load_workcell, save_workcell


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("workcell", help="workcell tools: place the nozzle by reachability (§2.3.1)",
                       description=__doc__)
    actions = p.add_subparsers(dest="workcell_command", required=True, metavar="ACTION")
    q = actions.add_parser("place", help="optimal nozzle position for a robot (exhaustive grid search)")
    q.add_argument("--robot", default="ur3", help=f"shipped workcell ({', '.join(ROBOT_NAMES)}) or a workcell JSON")
    q.add_argument("--box", type=float, default=100.0, help="side of the working envelope B, mm (default 100)")
    q.add_argument("--grid", type=float, default=10.0, help="grid step of the search, mm (B must be a multiple)")
    q.add_argument("--samples", type=int, default=1_000_000, help="joint configurations sampled")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--min-radius", type=float, default=0.0,
                   help="drop frames closer than this to the base axis, mm (default 0: the thesis's rule alone; "
                        "uniform joint sampling otherwise puts the optimum right above the robot)")
    q.add_argument("--out", type=Path, default=None, help="workcell JSON to write (default: workcell_ROBOT_placed.json)")
    q.set_defaults(run=run_place)


def run_place(args: argparse.Namespace) -> int:
    if args.samples < 1 or args.box <= 0 or args.grid <= 0:
        raise CurvsliceError("--samples, --box and --grid must be positive")
    cell = load_workcell(args.robot)
    robot = load_robot(cell.robot)
    start = time.perf_counter()
    try:
        placed, reach = place_nozzle(robot, cell, args.box, args.grid, args.samples, args.seed, args.min_radius)
    except ValueError as exc:
        raise CurvsliceError(str(exc)) from None
    seconds = time.perf_counter() - start
    out = args.out or Path(f"workcell_{cell.robot}_placed.json")
    save_workcell(placed, out)
    plot_reachability(reach, out.with_suffix(".png"), f"{cell.robot.upper()} reachability")
    centre, count = reach.best
    summary = {"robot": cell.robot, "samples": reach.samples, "frames_kept": reach.frames, "box_mm": args.box,
               "grid_mm": args.grid, "min_radius_mm": args.min_radius, "nozzle_mm": [round(float(v), 3) for v in centre], "frames_in_box": count,
               "seconds": round(seconds, 2)}
    out.with_suffix(".report.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(json.dumps(summary))
    print(f"wrote {out} and {out.with_suffix('.png')}")
    return 0
