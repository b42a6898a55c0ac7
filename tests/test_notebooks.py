"""The notebooks execute top to bottom without error (each asserts the thesis's claims it shows), and
they are committed with their outputs stripped."""

from __future__ import annotations

import re
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("[0-9][0-9]_*.ipynb"))


def test_the_five_notebooks_are_there():
    assert [p.name[:2] for p in NOTEBOOKS] == ["01", "02", "03", "04", "05"]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_is_stored_without_outputs(path):
    book = nbformat.read(path, as_version=4)
    code = [c for c in book.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)


def _shared_models_read(book) -> list[str]:
    """The ../shared/models files a notebook's code reads (``SHARED / "name.stl"`` outside comments)."""
    code = "\n".join(line.split("#")[0] for c in book.cells if c.cell_type == "code" for line in c.source.splitlines())
    return re.findall(r'SHARED\s*/\s*"([^"]+)"', code)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_executes(path, tmp_path, monkeypatch, shared_model):
    monkeypatch.setenv("CURVSLICE_NOTEBOOK_OUT", str(tmp_path))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    book = nbformat.read(path, as_version=4)
    for name in _shared_models_read(book):  # (skips when ../shared/models lacks it, as every test reading it does)
        shared_model(Path(name).stem)
    NotebookClient(book, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
    errors = [o for c in book.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors
    images = sum("image/png" in o.get("data", {}) for c in book.cells if c.cell_type == "code" for o in c.outputs)
    assert images >= 1  # the plots were drawn
