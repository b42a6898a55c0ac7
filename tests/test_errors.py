"""A missing third-party package is one actionable line and a non-zero exit, never a traceback (issue 13)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from curvslice.errors import CurvsliceError, require

ROOT = Path(__file__).resolve().parent.parent


def test_require_names_the_pip_package() -> None:
    with pytest.raises(CurvsliceError, match=r"pip install \"scikit-learn\"") as info:
        require("sklearn.no_such_submodule_xyz", "for the learned collision estimate")
    assert "learned collision estimate" in str(info.value)


@pytest.mark.parametrize("blocked, argv", [
    ("rtree", ["verify", "FOLDER"]),        # trimesh's proximity queries, deep inside a stage
    ("ezdxf", ["drape", "--help"]),          # a command module's own import
])
def test_cli_reports_a_missing_package_in_one_line(tmp_path: Path, blocked: str, argv: list[str]) -> None:
    """Hide one installed package from a real CLI run (a meta-path blocker) and read what the user sees."""
    (tmp_path / "sitecustomize.py").write_text(
        "import sys\n"
        "class _Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        f"        if name.split('.')[0] == {blocked!r}:\n"
        "            raise ModuleNotFoundError(f\"No module named '{name}'\", name=name)\n"
        "sys.meta_path.insert(0, _Block())\n")
    folder = ROOT / "models" / "tee.stl"
    if argv[0] == "verify":  # a minimal slice folder whose verification needs trimesh.proximity
        pytest.importorskip("rtree")
        out = tmp_path / "tee"
        subprocess.run([sys.executable, "-m", "curvslice", "slice", str(folder), "--voxel", "4", "--no-verify", "--stages",
                        "layers", "--quiet", "--out", str(out)], check=True, capture_output=True)
        argv = ["verify", str(out)]
    env = {"PYTHONPATH": f"{tmp_path}:{ROOT}", "PATH": "/usr/bin:/bin"}
    r = subprocess.run([sys.executable, "-m", "curvslice", *argv], capture_output=True, text=True, env=env)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and f"pip install \"{blocked}\"" in lines[0], r.stderr
