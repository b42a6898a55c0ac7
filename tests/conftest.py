"""Shared fixtures. Real meshes come from ../shared/models (or $CURVSLICE_MODELS) and are never
committed; tests that need them skip cleanly when the folder is absent."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_models_dir() -> Path:
    env = os.environ.get("CURVSLICE_MODELS")
    return Path(env) if env else REPO.parent / "shared" / "models"


@pytest.fixture
def shared_model():
    """``shared_model("kitten")`` -> Path to ../shared/models/kitten.stl, or skip the test."""

    def get(name: str) -> Path:
        path = shared_models_dir() / f"{name}.stl"
        if not path.exists():
            pytest.skip(f"shared model {path} not present")
        return path

    return get
