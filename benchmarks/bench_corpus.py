"""Unseen shapes at finer voxels (issue 18): the regression corpus' procedural solids
(``tests/test_corpus.py``: thin walls, tips, overhangs, holes, a needle, a cup, a knot...) sliced to the
tool-paths at voxel sizes finer than CI's 1.5 mm and re-checked by every ``curvslice verify`` check. CI keeps
the corpus passing at 1.5 mm; this measures how well the rules hold where nobody tuned them: how many solids
pass per voxel size, and every failed check of the others with its figure (the worst layer).

Run from the repository root: ``python -m benchmarks.bench_corpus [--voxels 1.0 0.8] [--jobs 2]``; it prints the
table and writes its section of ``benchmarks/RESULTS.md`` (about 4 CPU minutes per voxel size at 1.0-0.8 mm).
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import multiprocessing
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SECTION = "## Corpus at finer voxels"


@functools.cache
def _corpus():
    """``tests/test_corpus.py`` as a module (loaded once per process) (the solids are defined there, beside the CI test that uses them)."""
    spec = importlib.util.spec_from_file_location("corpus", REPO / "tests" / "test_corpus.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run_case(name: str, voxel: float) -> dict[str, object]:
    """One solid at one voxel size (mm): sliced to the tool-paths in a scratch folder, then verified."""
    from curvslice.cli import main
    from curvslice.verify import verify_outdir

    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / f"{name}.stl"
        _corpus().procedural_solid(name).export(model)
        code = main(["slice", str(model), "--voxel", str(voxel), "--stages", "toolpaths", "--out", str(Path(tmp) / "out"),
                     "--quiet", "--no-verify"])
        failed = ([f"slice exited {code}"] if code else
                  [f"{c.name}: {c.value}" for c in verify_outdir(Path(tmp) / "out") if not c.passed])
    return {"solid": name, "voxel": voxel, "failed": failed, "seconds": round(time.perf_counter() - start, 1)}


def markdown(runs: list[dict], header: dict[str, str]) -> str:
    """The section: passes per voxel size, then every failing case with its failed checks."""
    lines = [SECTION, "",
             f"Refresh with `{header['command']}`. Run on commit {header['commit']} ({header['date']}; load average "
             f"{header['load']} at the start, {header['load_end']} at the end, {header['jobs']} at a time). The corpus' "
             "procedural solids (tests/test_corpus.py; CI runs them at 1.5 mm, all passing) at finer voxels, default path "
             "width (voxel / 0.8), every `curvslice verify` check.", "",
             "| voxel | solids passing every check | failing: checks (worst layer) |", "|---|---|---|"]
    for voxel in sorted({r["voxel"] for r in runs}, reverse=True):
        at = [r for r in runs if r["voxel"] == voxel]
        bad = [r for r in at if r["failed"]]
        detail = "; ".join(f"{r['solid']}: {', '.join(r['failed'])}" for r in bad) or "–"
        lines.append(f"| {voxel:g} mm | {len(at) - len(bad)} of {len(at)} | {detail} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    from benchmarks.bench_verify import splice
    from benchmarks.run import source_commit

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--voxels", type=float, nargs="+", default=[1.0, 0.8], help="voxel sizes, mm")
    parser.add_argument("--solids", nargs="+", help="only these solids (default: all of the corpus)")
    parser.add_argument("--jobs", type=int, default=1, help="cases at once, each in its own process")
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks", help="folder of the RESULTS.md to update")
    args = parser.parse_args()
    solids = args.solids or _corpus().SOLIDS
    cases = [(s, v) for v in args.voxels for s in solids]
    header = {"commit": source_commit(), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
              "load": ", ".join(f"{x:.1f}" for x in os.getloadavg()), "jobs": str(args.jobs),
              "command": "python -m benchmarks.bench_corpus --voxels " + " ".join(f"{v:g}" for v in args.voxels)}
    with ProcessPoolExecutor(args.jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        runs = []
        for run in pool.map(run_case, *zip(*cases)):
            print(f"{run['solid']} @{run['voxel']:g} mm: {'; '.join(run['failed']) or 'every check passes'} "
                  f"({run['seconds']} s)", flush=True)
            runs.append(run)
    header["load_end"] = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    section = markdown(runs, header)
    print(section)
    splice(args.out / "RESULTS.md", section, SECTION)


if __name__ == "__main__":
    main()
