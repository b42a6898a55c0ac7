"""Every third-party package the code imports is declared in pyproject.toml (issue 13).

The code's imports are read with ``ast`` (every ``import``/``from`` at any depth, so lazy imports inside
functions count too), the standard library and our own packages are set aside, and each remaining
top-level module is mapped to the distribution that provides it (``importlib.metadata``). A module
that no declared distribution provides fails the test: CI installs into a fresh virtual environment,
so an undeclared dependency would otherwise reach users as a ``ModuleNotFoundError``.
"""

from __future__ import annotations

import ast
import importlib.metadata as md
import re
import sys
from pathlib import Path

import pytest

try:
    import tomllib
except ImportError:  # Python 3.10
    tomllib = pytest.importorskip("tomli")

ROOT = Path(__file__).resolve().parent.parent
OWN = {"curvslice", "benchmarks", "tests", "generate"} | {p.stem for p in (ROOT / "tests").glob("*.py")}
CODE = [ROOT / "curvslice", ROOT / "benchmarks", ROOT / "models"]

#: Declared for what the code needs without importing it by name; each with the reason.
INDIRECT = {
    "rtree": "trimesh's proximity queries (nearest points, signed distance) import it",
    "charset-normalizer": "trimesh decodes text mesh files with it",
    "example-robot-data": "ships the UR URDFs and meshes that kinematics loads from the cmeel prefix",
    "pytest-timeout": "a pytest plugin, used through the timeout marker and option",
    "ipykernel": "the kernel nbclient runs the notebooks in",
    "tomli": "tomllib's back-port, imported under another name on Python 3.10",
}


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _requirement_names(requirements: list[str]) -> set[str]:
    return {_norm(re.match(r"[A-Za-z0-9_.\-]+", r).group(0)) for r in requirements}


def _declared() -> tuple[set[str], set[str]]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    runtime = _requirement_names(project["dependencies"])
    test = _requirement_names(project.get("optional-dependencies", {}).get("test", []))
    return runtime, test


def imported_modules(folders: list[Path]) -> dict[str, set[str]]:
    """Top-level modules imported by the Python files under ``folders`` -> the files importing them."""
    found: dict[str, set[str]] = {}
    for folder in folders:
        for path in sorted(folder.rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    found.setdefault(name.split(".")[0], set()).add(str(path.relative_to(ROOT)))
    return {m: f for m, f in found.items() if m not in OWN and m not in sys.stdlib_module_names}


def providers() -> dict[str, set[str]]:
    """Top-level module -> distributions installing it, from every installed distribution's file list.

    Broader than ``packages_distributions()``: it also sees single-file extension modules
    (``manifold3d.cpython-311-….so``) and modules installed under a ``.pth``-added prefix (the cmeel
    wheels put ``pinocchio`` in ``cmeel.prefix/lib/python3.X/site-packages``).
    """
    found: dict[str, set[str]] = {m: {_norm(d) for d in ds} for m, ds in md.packages_distributions().items()}
    for dist in md.distributions():
        name = _norm(dist.metadata["Name"])
        for line in (dist.read_text("RECORD") or "").splitlines():
            path = line.split(",")[0]
            if "/site-packages/" in path:
                path = path.split("/site-packages/", 1)[1]
            top, _, rest = path.partition("/")
            if (rest or top.endswith((".py", ".so"))) and not top.endswith((".dist-info", ".data")) and top != "..":
                found.setdefault(top.split(".")[0], set()).add(name)
    return found


def _undeclared(modules: dict[str, set[str]], declared: set[str]) -> list[str]:
    providers_ = providers()
    missing = []
    for module, files in sorted(modules.items()):
        dists = providers_.get(module, set())
        if not dists & declared:
            where = ", ".join(sorted(files)[:3])
            missing.append(f"{module} (from {sorted(dists) or 'no installed distribution'}; imported in {where})")
    return missing


def test_library_imports_are_declared_dependencies() -> None:
    runtime, _ = _declared()
    missing = _undeclared(imported_modules(CODE), runtime)
    assert not missing, "imported but not in pyproject's dependencies: " + "; ".join(missing)


def test_test_imports_are_declared_in_the_test_extra() -> None:
    runtime, test = _declared()
    missing = _undeclared(imported_modules([ROOT / "tests"]), runtime | test)
    assert not missing, "tests import packages missing from dependencies and the test extra: " + "; ".join(missing)


def test_every_declared_dependency_is_used() -> None:
    """The other direction: a declaration nobody imports is either listed in INDIRECT with its reason or dead."""
    runtime, test = _declared()
    found = providers()
    used = {d for m in imported_modules([*CODE, ROOT / "tests"]) for d in found.get(m, ())}
    unused = sorted((runtime | test) - used - {_norm(n) for n in INDIRECT})
    assert not unused, f"declared but never imported (drop them or say why in INDIRECT): {unused}"


def test_the_scan_sees_lazy_imports(tmp_path: Path) -> None:
    """The scanner itself: an import inside a function body is found (viz and drape import lazily)."""
    module = ROOT / "curvslice" / "cli" / "slice.py"
    tree = imported_modules([module.parent])
    assert "numpy" in tree and "curvslice" not in tree and "json" not in tree
