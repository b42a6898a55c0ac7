"""Independent re-checks of every artefact in a slice folder (``curvslice verify OUTDIR``).

Each stage has a module here exposing ``checks(outdir: Path) -> list[Check] | None`` that
recomputes its properties from the written files alone, without calling the code that made them
(returning ``None`` when that stage's artefacts are absent). :func:`verify_outdir` runs them all.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path

from curvslice.errors import CurvsliceError

#: Stage checker modules of ``curvslice.verify``, in pipeline order.
STAGES = ("field", "layers", "toolpaths", "robot")
#: Checker of a `curvslice decompose` folder (RoboFDM, ch. 2).
STAGES += ("decompose",)


@dataclass(frozen=True)
class Check:
    """One verified property: ``passed`` is False on a violation; ``value`` is the measured figure."""

    stage: str
    name: str
    passed: bool
    value: str
    detail: str = ""


def verify_outdir(outdir: str | Path) -> list[Check]:
    """Run every stage's checks whose artefacts exist in ``outdir``."""
    outdir = Path(outdir)
    if not outdir.is_dir():
        raise CurvsliceError(f"{outdir} is not a folder (give the output folder of `curvslice slice`)")
    results: list[Check] = []
    for stage in STAGES:
        module = importlib.import_module(f"curvslice.verify.{stage}")
        found = module.checks(outdir)
        if found is not None:
            results.extend(found)
    if not results:
        raise CurvsliceError(f"{outdir} holds no curvslice artefacts (field.npz missing)")
    return results


def format_table(results: list[Check]) -> str:
    """A fixed-width table: stage, check, PASS/FAIL, measured value, detail."""
    rows = [("stage", "check", "result", "value", "detail")]
    rows += [(c.stage, c.name, "PASS" if c.passed else "FAIL", c.value, c.detail) for c in results]
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    lines = []
    for r in rows:
        lines.append("  ".join(r[i].ljust(widths[i]) for i in range(4)) + ("  " + r[4] if r[4] else ""))
    return "\n".join(lines)
