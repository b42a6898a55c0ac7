"""``curvslice sweep MODEL... --grid NAME=V1,V2 ...``: every model × every combination of the grid's
settings sliced into a folder of its own (through :func:`curvslice.pipeline.run`) and checked
(:func:`curvslice.verify.verify_outdir`); one Dask task per run with ``--workers`` / ``--scheduler``.
``OUT/sweep.csv`` gets a row per run: its settings, each stage's seconds, counts, the verify result,
and the error of a run that failed (the others go on).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from curvslice.cli.slice import _type, add_execution_arguments
from curvslice.errors import CurvsliceError
from curvslice.executors import open_executor
from curvslice.pipeline import STAGE_NAMES, Settings

#: Counts of a run's report copied into the table: column -> (stage section, key).
COUNTS = {"voxels": ("field", "voxels"), "layers": ("layers", "count"), "triangles": ("layers", "triangles"),
          "samples": ("toolpaths", "samples"), "pieces": ("toolpaths", "pieces"), "jumps": ("toolpaths", "jumps"),
          "coverage_min": ("toolpaths", "coverage_min"), "robot_rows": ("robot", "rows")}
#: Seconds of a run's report copied into the table (``timings_s`` keys).
TIMES = ("load", "voxelize", "peeling", "growing", "layers", "toolpaths", "robot", "total")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="slice models × a grid of settings, one folder per run, and a CSV table",
                       description=__doc__)
    p.add_argument("models", nargs="+", help="mesh files")
    p.add_argument("--grid", action="append", default=[], metavar="NAME=V1,V2",
                   help="a setting of `curvslice slice` (underscores, e.g. voxel=0.8,1.0 or method=gcfa,pg-sp-gcfa; "
                        "angles in degrees) and its values; repeat for more settings")
    p.add_argument("--out", required=True, help="folder of the runs' folders and sweep.csv")
    p.add_argument("--stages", default="toolpaths", choices=STAGE_NAMES, help="last stage of every run")
    p.add_argument("--force", action="store_true", help="replace existing run folders")
    add_execution_arguments(p, threads=False)
    p.set_defaults(run=run)


def parse_grid(items: list[str]) -> dict[str, list[Any]]:
    """``["voxel=0.8,1.0", ...]`` -> ``{"voxel": [0.8, 1.0], ...}`` typed as the Settings fields
    (angles given in degrees become radians)."""
    fields = {f.name: f for f in dataclasses.fields(Settings)}
    grid = {}
    for item in items:
        name, _, values = item.partition("=")
        f = fields.get(name.strip())
        if f is None or not values:
            raise CurvsliceError(f"--grid {item!r}: give NAME=V1,V2,... with NAME one of {', '.join(fields)}")
        kind = _type(f)
        parsed = []
        for text in values.split(","):
            value = text.strip().lower() in ("1", "true", "yes") if kind is bool else kind(text.strip())
            parsed.append(float(np.radians(value)) if f.metadata.get("degrees") else value)
        grid[f.name] = parsed
    return grid


def run_name(model: Path, changes: dict[str, Any]) -> str:
    """A run's folder name: the model's stem and its grid values."""
    return "_".join([model.stem] + [f"{k}-{v:g}" if isinstance(v, float) else f"{k}-{v}" for k, v in changes.items()])


def sweep_run(job: tuple[str, dict[str, Any], str, str, bool]) -> dict[str, Any]:
    """One run (a task): slice, verify, and the table row; an error is recorded in the row, not raised."""
    from curvslice.pipeline import run as run_pipeline
    from curvslice.verify import verify_outdir

    model, changes, out, until, force = job
    row: dict[str, Any] = {"model": Path(model).stem, **changes, "folder": out, "status": "ok", "error": ""}
    start = time.perf_counter()
    try:
        report = run_pipeline(model, Settings().replace(**changes), until=until, out=out, force=force).report
        row.update({f"{k}_s": report["timings_s"].get(k, "") for k in TIMES})
        row.update({col: report.get(stage, {}).get(key, "") if isinstance(report.get(stage), dict) else ""
                    for col, (stage, key) in COUNTS.items()})
        failed = [f"{c.stage}.{c.name}" for c in verify_outdir(out) if not c.passed]
        row["verify"] = "PASS" if not failed else "FAIL: " + " ".join(failed)
    except Exception as exc:  # noqa: BLE001 -- a failed run is a row of the table, the sweep goes on
        row.update(status="failed", error=f"{type(exc).__name__}: {exc}".replace("\n", " "),
                   verify="", trace=traceback.format_exc(limit=3).replace("\n", " | "))
    row["wall_s"] = round(time.perf_counter() - start, 3)
    return row


def run(args: argparse.Namespace) -> int:
    grid = parse_grid(args.grid)
    models = [Path(m).resolve() for m in args.models]
    for m in models:
        if not m.is_file():
            raise CurvsliceError(f"{m}: no such file")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    combos = [dict(zip(grid, values)) for values in itertools.product(*grid.values())]
    runs = [(str(m), c, str(out / run_name(m, c)), args.stages, args.force) for m in models for c in combos]
    # (without Dask the runs go one after the other, each in order: a run is no task for a thread)
    local = args.workers is None and args.scheduler is None
    with open_executor(args.workers, args.scheduler, threads=1 if local else None) as executor, \
            tqdm(total=len(runs), desc="sweep", unit="run", dynamic_ncols=True) as bar:
        rows = executor.map(sweep_run, runs, progress=bar)
    columns = list(dict.fromkeys(k for r in rows for k in r if k != "trace")) + ["trace"]
    table = out / "sweep.csv"
    with open(table, "w", newline="") as f:
        writer = csv.DictWriter(f, columns, restval="")
        writer.writeheader()
        writer.writerows(rows)
    failed = sum(r["status"] != "ok" or r["verify"] != "PASS" for r in rows)
    print(f"{len(rows)} runs, {failed} failed or not verified: {table}")
    return 1 if failed else 0
