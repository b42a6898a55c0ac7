"""Risky faces and risky area R(·) of a part printed along a direction (thesis Eq. 2.1, §2.4.3).

A face with unit normal ``n`` is *safe* for build direction ``d`` when ``n·d + sin(α_max) ≥ 0``,
otherwise *risky*. The faces lying on the part's base plane (normal ``-d``, on the plane) rest on
the material or platform below and are excluded.

``α_max`` default: the thesis borrows the self-support angle from its ref. [26] without stating a
value; 45° is the usual FDM rule (a wall may lean up to 45° beyond vertical), so
:data:`ALPHA_MAX_DEG` = 45.
"""

from __future__ import annotations

import numpy as np
import trimesh

from curvslice.decompose.parts import Plane

ALPHA_MAX_DEG = 45.0
#: Faces within this distance (mm) of the base plane and facing down along it are the base face.
BASE_TOLERANCE_MM = 1e-2
#: The root stands on the platform: its faces within this distance (mm, about one layer) of its
#: lowest point are the contact, whatever their normal (a scanned model rarely has a flat bottom).
PLATFORM_CONTACT_MM = 0.5


def risky_mask(normals: np.ndarray, direction: np.ndarray, alpha_max: float) -> np.ndarray:
    """Eq. 2.1 violated: ``n·d + sin(α_max) < 0`` per row of ``normals`` (α_max in radians)."""
    return normals @ np.asarray(direction, float) + np.sin(alpha_max) < 0


def base_face_mask(mesh: trimesh.Trimesh, base: Plane, platform: bool = False) -> np.ndarray:
    """Faces lying on the base plane with their normal opposite to the build direction; for the
    root (``platform``) the faces within :data:`PLATFORM_CONTACT_MM` of it."""
    height = mesh.vertices @ base.normal - base.offset
    on_plane = np.all(np.abs(height[mesh.faces]) <= (PLATFORM_CONTACT_MM if platform else BASE_TOLERANCE_MM), axis=1)
    return on_plane if platform else on_plane & (mesh.face_normals @ base.normal < -0.999)


def risky_faces(mesh: trimesh.Trimesh, base: Plane, alpha_max: float, platform: bool = False) -> np.ndarray:
    """Risky faces of a part printed along ``base.normal`` from ``base`` (its base face excluded)."""
    return risky_mask(mesh.face_normals, base.normal, alpha_max) & ~base_face_mask(mesh, base, platform)


def risky_area(mesh: trimesh.Trimesh, base: Plane, alpha_max: float, platform: bool = False) -> float:
    """R(M_i) of §2.4.3 in mm²."""
    return float(mesh.area_faces[risky_faces(mesh, base, alpha_max, platform)].sum())


def lowest_plane(vertices: np.ndarray, direction: np.ndarray) -> Plane:
    """The supporting plane of a point set below it along ``direction`` (the root's platform)."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    return Plane(d, float((np.asarray(vertices) @ d).min()))
