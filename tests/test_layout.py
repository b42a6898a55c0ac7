"""Imports flow one way (issue 14): the planar cell tools and the domain types never import the
writers, the verifier, the viewer or the CLI that are built on them."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "curvslice"
DOWNSTREAM = ("curvslice.exporters", "curvslice.verify", "curvslice.viz", "curvslice.cli")


def imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return names


def test_cell_tools_and_domain_types_import_nothing_downstream():
    upstream = [PACKAGE / "robot_path.py", PACKAGE / "flow.py", *sorted((PACKAGE / "cell").glob("*.py"))]
    bad = {
        f"{p.relative_to(PACKAGE.parent)} imports {m}"
        for p in upstream
        for m in imported_modules(p)
        if m.startswith(DOWNSTREAM)
    }
    assert not bad, sorted(bad)


def test_no_flat_cell_modules_left():
    """The old flat modules are gone, so a stale import fails instead of finding a copy."""
    assert not [n for n in ("cell.py", "gcode.py", "drape.py", "levelling.py") if (PACKAGE / n).exists()]
