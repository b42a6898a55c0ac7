"""The manufacturing platform T (thesis §3.4.1): a solid under the model that takes part in every
convex front C(V ∪ T), so material can never be deposited where the nozzle would hit the platform.

Default: a disc slab whose top is the plane z = 0, covering the model's footprint plus a margin
(the paper's set-up used a ~64 mm disc, ~21 mm thick, under a ~60 mm model). Only its convex
hull matters for the fronts; with vertical walls the thickness does not change any front above
z = 0, it only shapes collision and viewer geometry.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from curvslice.errors import CurvsliceError

DEFAULT_MARGIN = 5.0      # mm beyond the footprint
DEFAULT_THICKNESS = 10.0  # mm
SEGMENTS = 64


def disc_platform(solid: trimesh.Trimesh, margin: float = DEFAULT_MARGIN,
                  thickness: float = DEFAULT_THICKNESS, segments: int = SEGMENTS) -> trimesh.Trimesh:
    """A disc slab under ``solid`` (placed on z = 0, centred on the z axis)."""
    if margin < 0 or not thickness > 0:
        raise CurvsliceError("platform margin must be ≥ 0 and thickness > 0")
    radius = float(np.linalg.norm(solid.vertices[:, :2], axis=1).max()) + margin
    # circumscribe the polygon so the true disc of `radius` lies inside it
    radius /= np.cos(np.pi / segments)
    disc = trimesh.creation.cylinder(radius=radius, height=thickness, sections=segments)
    disc.apply_translation([0.0, 0.0, -thickness / 2])
    return disc


def load_platform(path: str | Path) -> trimesh.Trimesh:
    """A user platform mesh, given in the model frame (its top should be at z = 0)."""
    from curvslice.solid import read_mesh

    mesh = read_mesh(path)
    if mesh.bounds[1, 2] > 1e-6:
        raise CurvsliceError(
            f"{path}: the platform reaches z = {mesh.bounds[1, 2]:.3g} mm; its top must be at z ≤ 0 (model frame)"
        )
    return mesh
