"""``curvslice verify OUTDIR``: independent re-check of a slice folder; exit 1 on a violation."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict

from curvslice.verify import format_table, verify_outdir


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("verify", help="re-check every artefact of a slice folder from the files alone",
                       description=__doc__)
    p.add_argument("outdir", help="output folder of `curvslice slice`")
    p.add_argument("--json", action="store_true", help="print the checks as JSON instead of a table")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    results = verify_outdir(args.outdir)
    if args.json:
        print(json.dumps([asdict(c) for c in results], indent=2, default=str))
    else:
        print(format_table(results))
    failed = [c for c in results if not c.passed]
    if failed and not args.json:
        print(f"\n{len(failed)} check(s) FAILED")
    return 1 if failed else 0
