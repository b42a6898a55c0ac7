"""``curvslice bench``: time every pipeline stage on the shared models (plus a size sweep) and write
``results.json``, ``RESULTS.md`` (with the thesis's Table 3.1 / 4.2 figures beside ours) and
``results.png``. ``--quick`` runs the small repository models for CI."""

from __future__ import annotations

import argparse

from benchmarks.run import add_arguments, execute


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="benchmark every stage (JSON, markdown with the paper's figures, PNG)",
                       description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    add_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    return execute(args)
