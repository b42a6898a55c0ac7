"""``curvslice slice MODEL``: parse options into :class:`~curvslice.pipeline.Settings` and call the pipeline.

The options are generated from the Settings fields (their defaults, units and help live there only);
``--resume OUTDIR`` starts from that folder's settings, applies the options given, and reuses every stage
whose inputs are unchanged. No stage composition here: :func:`curvslice.pipeline.run` does it.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from curvslice.errors import CurvsliceError
from curvslice.executors import MAX_THREADS, open_executor
from curvslice.pipeline import STAGE_NAMES, Settings, read_report, run as run_pipeline, setting_bounds, settings_of
from curvslice.validate import argument_type, count, number

DESCRIPTION = (
    "Decompose a solid into curved, support-free, accessible layers (thesis §3.4), cover them with "
    "Fermat-spiral tool-paths (§3.5.1-3.5.2) and, with --robot, plan pose-continuous robot motion "
    "(§3.5.3). Writes one output folder: field.npz, solid.stl, layers/, toolpaths.gcode/.npz, robot "
    "programs and report.json; check it with `curvslice verify OUTDIR`."
)

#: Option groups of the help text, by the stage that reads the setting.
GROUPS = {"field": "model, platform T and volume decomposition (§3.4)", "layers": "working surfaces (§3.4.5)",
          "toolpaths": "tool-paths (§3.5.1-3.5.2)", "robot": "robot (§3.5.3, §4.3.1)"}


def _flag(f: dataclasses.Field) -> str:
    return f.metadata.get("flag") or "--" + f.name.replace("_", "-")


def _type(f: dataclasses.Field):
    """argparse type of a Settings field: finite and in the field's range for numbers (checked while
    parsing, before any stage runs), a shipped name or JSON file for the workcell, text otherwise."""
    if f.name == "robot":
        return argument_type(_workcell, "workcell")
    if "lo" not in f.metadata:
        return str
    lo, hi, unit, integer = setting_bounds(f)
    return count(unit or f.name.replace("_", " "), lo=lo, hi=hi) if integer else number(unit, lo=lo, hi=hi)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("slice", help="slice a solid into curved, support-free layers (and beyond)",
                       description=DESCRIPTION)
    p.add_argument("model", nargs="?", help="mesh file (STL, OBJ, PLY, OFF), millimetres (optional with --resume)")
    p.add_argument("--out", help="output folder (default: MODELNAME_slice in the current folder; with --resume: "
                   "the resumed folder, which then needs --force)")
    p.add_argument("--force", action="store_true", help="replace an existing output folder")
    p.add_argument("--resume", metavar="OUTDIR", help="start from this earlier output folder: its settings, changed by "
                   "the options given; stages whose inputs are unchanged are reused, not recomputed")
    p.add_argument("--stages", default=None, choices=STAGE_NAMES,
                   help="run the pipeline up to and including this stage (default: robot, which is skipped without "
                   "--robot)")
    groups = {stage: p.add_argument_group(title) for stage, title in GROUPS.items()}
    for f in dataclasses.fields(Settings):
        m = f.metadata
        default = np.degrees(f.default) if m.get("degrees") else f.default
        unit = "degrees" if m.get("degrees") else m["unit"]
        shown = "" if default is None else f" (default: {default:g}{' ' + unit if unit else ''})" \
            if isinstance(default, float) else f" (default: {default})"
        if m.get("negate"):
            groups[m["stage"]].add_argument(_flag(f), dest=f.name, action="store_false", default=argparse.SUPPRESS,
                                            help="leave out the " + m["help"])
            continue
        groups[m["stage"]].add_argument(
            _flag(f), dest=f.name, type=_type(f), choices=m.get("choices"), default=argparse.SUPPRESS,
            metavar=None if m.get("choices") else (unit.upper().replace("/", "_") or f.name.upper()) if unit else None,
            help=m["help"] + (f", {unit}" if unit and not shown else "") + shown)
    p.add_argument("--no-verify", action="store_true", help="skip the independent re-check of the written folder "
                   "(`curvslice verify`); by default a failed check makes the exit status 1")
    add_execution_arguments(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars or summary lines")
    p.add_argument("--preview", action="store_true", help="also write preview.png (layers by print order, cut-away; tool-paths of one layer)")
    p.add_argument("--preview-layer", type=int, help="layer whose tool-paths preview.png shows (default: the middle one)")
    p.set_defaults(run=run)


def add_execution_arguments(p: argparse.ArgumentParser, threads: bool = True) -> None:
    """``--threads`` (with ``threads``) / ``--workers`` / ``--scheduler``: where the per-layer tasks run (never
    what they compute)."""
    g = p.add_argument_group("execution (threads or Dask; the results are the same)").add_mutually_exclusive_group()
    if threads:
        g.add_argument("--threads", type=int, metavar="N", help="run per-layer tasks on N threads of this process "
                       f"(default: the cores it may use, at most {MAX_THREADS}; 1: one after the other)")
    g.add_argument("--workers", type=int, metavar="N", help="run per-layer tasks on a local Dask cluster of N "
                   "single-threaded worker processes (default: in this process)")
    g.add_argument("--scheduler", metavar="ADDRESS", help="run them on an existing Dask cluster, e.g. "
                   "tcp://host:8786 (`dask scheduler` + `dask worker`, Kubernetes, SLURM...)")


def _workcell(text: str) -> str:
    """``--robot``: a shipped workcell name or a workcell JSON file, checked while parsing, not after the
    slicing stages."""
    from curvslice.workcell import load_workcell

    load_workcell(text)
    return text


def settings_from_args(args: argparse.Namespace, base: Settings) -> Settings:
    """``base`` with every Settings option given on the command line (angles converted to radians)."""
    given = {}
    for f in dataclasses.fields(Settings):
        if hasattr(args, f.name):
            value = getattr(args, f.name)
            given[f.name] = float(np.radians(value)) if f.metadata.get("degrees") else value
    return base.replace(**given)


def run(args: argparse.Namespace) -> int:
    if args.resume:
        old = read_report(args.resume)
        model = Path(args.model) if args.model else Path(old.get("model", ""))
        base = settings_of(args.resume)
        out = Path(args.out) if args.out else Path(args.resume)
        until = args.stages or (old["stages"][-1] if old.get("stages") else STAGE_NAMES[-1])
    else:
        if not args.model:
            raise CurvsliceError("give a mesh file to slice (or --resume OUTDIR)")
        model, base = Path(args.model), Settings()
        out = Path(args.out) if args.out else Path.cwd() / f"{model.stem}_slice"
        until = args.stages or STAGE_NAMES[-1]
    settings = settings_from_args(args, base)
    if args.resume and settings.robot is not None and args.stages is None:
        until = "robot"  # asking for a robot on resume means planning it
    after = _preview(args) if args.preview else None
    with open_executor(args.workers, args.scheduler, threads=args.threads) as executor:
        run_pipeline(model, settings, until=until, out=out, resume=args.resume, force=args.force, quiet=args.quiet,
                     after=after, executor=executor)
    if not args.quiet:
        print(f"wrote {out}")
    if args.no_verify:
        return 0
    from curvslice.verify import verify_outdir

    failed = [c for c in verify_outdir(out) if not c.passed]
    for c in failed:
        print(f"curvslice slice: verify FAILED: {c.stage} / {c.name}: {c.value} {c.detail}".rstrip(), file=sys.stderr)
    if failed:
        print(f"curvslice slice: {out} was written but fails {len(failed)} check(s) of `curvslice verify`",
              file=sys.stderr)
    return 1 if failed else 0


def _preview(args: argparse.Namespace):
    def write(_slice, tmp: Path) -> None:
        from curvslice.viz import preview_png, read_slice_folder  # matplotlib/meshcat only when asked

        preview_png(read_slice_folder(tmp), tmp / "preview.png", args.preview_layer)
    return write
