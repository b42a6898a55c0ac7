"""Load, check, repair and place the input solid H (thesis §3.3.1: H is a closed solid).

A slicer sees broken meshes every day, so loading is defensive: vertices are merged, degenerate
and duplicate faces dropped, winding made consistent and outward, and holes of at most a few
edges filled. What cannot be repaired safely (large holes, no volume) is refused with a message
that says what to do. The placed solid is in millimetres, Z up, centred on the platform axis
with its lowest point on the platform top z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from curvslice.errors import CurvsliceError

MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off")

#: Axis names accepted by ``--up``.
UP_AXES = {
    "x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0),
    "-x": (-1.0, 0.0, 0.0), "-y": (0.0, -1.0, 0.0), "-z": (0.0, 0.0, -1.0),
}

#: Longest extent (mm) below which a model is most likely in metres or inches-confused.
SUSPICIOUSLY_SMALL_MM = 2.0
#: Longest extent (mm) above which a model is most likely in micrometres.
SUSPICIOUSLY_LARGE_MM = 5000.0


@dataclass
class LoadReport:
    """What loading found and did; stored in ``report.json``."""

    source: str
    faces_in: int
    vertices_in: int
    repairs: list[str] = field(default_factory=list)
    scale: float = 1.0
    up: str = "z"
    extent_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)


def read_mesh(path: str | Path) -> trimesh.Trimesh:
    """Read STL/OBJ/PLY/OFF into one triangle mesh, or raise CurvsliceError saying why not."""
    path = Path(path)
    if not path.exists():
        raise CurvsliceError(f"{path}: no such file")
    if path.is_dir():
        raise CurvsliceError(f"{path} is a folder; give a mesh file ({', '.join(MESH_SUFFIXES)})")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise CurvsliceError(
            f"{path}: unsupported file type {path.suffix or '(none)'}; use one of {', '.join(MESH_SUFFIXES)}"
        )
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except ImportError:
        raise  # a missing package is not a bad mesh: the CLI names the package to install
    except Exception as exc:  # trimesh raises many types for garbage input
        raise CurvsliceError(f"{path}: not a readable {path.suffix[1:].upper()} mesh ({exc})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise CurvsliceError(f"{path}: the file holds no triangles (empty mesh)")
    if not np.isfinite(loaded.vertices).all():
        raise CurvsliceError(f"{path}: vertex coordinates contain NaN or infinity")
    return loaded


def _without_internal_walls(faces: np.ndarray) -> tuple[np.ndarray, int]:
    """Faces to keep: of triangles on the same three vertices, pairs of opposite winding cancel (the wall
    where two touching bodies meet lies inside their union) and one of each same-winding duplicate stays.
    Returns the keep mask and the number of wall faces dropped."""
    order = np.argsort(faces, axis=1)
    odd = ((order[:, 0] > order[:, 1]).astype(int) + (order[:, 0] > order[:, 2]) + (order[:, 1] > order[:, 2])) % 2
    keep, walls = np.ones(len(faces), bool), 0
    for group in trimesh.grouping.group_rows(np.sort(faces, axis=1)):
        if len(group) < 2:
            continue
        even_g, odd_g = group[odd[group] == 0], group[odd[group] == 1]
        pairs = min(len(even_g), len(odd_g))
        keep[even_g[:pairs]] = keep[odd_g[:pairs]] = False
        walls += 2 * pairs
        rest = np.r_[even_g[pairs:], odd_g[pairs:]]
        keep[rest[1:]] = False  # same-winding duplicates: one stays
    return keep, walls


def repair(mesh: trimesh.Trimesh, name: str = "mesh") -> tuple[trimesh.Trimesh, list[str]]:
    """Make ``mesh`` a closed, consistently oriented solid with positive volume.

    Safe repairs only: merge coincident vertices, drop degenerate/duplicate faces, the internal walls
    where touching bodies meet, and unused vertices, fill holes bounded by 3 or 4 edges, unify winding,
    flip inside-out meshes.
    Raises CurvsliceError if the result is still open or has no volume.
    """
    repairs: list[str] = []
    m = mesh.copy()
    n_v, n_f = len(m.vertices), len(m.faces)
    m.merge_vertices()
    if len(m.vertices) < n_v:
        repairs.append(f"merged {n_v - len(m.vertices)} duplicate vertices")
    keep = m.nondegenerate_faces(height=1e-12)
    if not keep.all():
        m.update_faces(keep)
    keep, walls = _without_internal_walls(m.faces)
    if not keep.all():
        m.update_faces(keep)
    if walls:
        repairs.append(f"removed {walls} internal wall faces between touching bodies")
    if len(m.faces) < n_f - walls:
        repairs.append(f"removed {n_f - walls - len(m.faces)} degenerate or duplicate faces")
    m.remove_unreferenced_vertices()
    if len(m.faces) == 0:
        raise CurvsliceError(f"{name}: every face is degenerate (zero area); nothing to print")
    if not m.is_watertight:
        before = len(m.faces)
        trimesh.repair.fill_holes(m)
        if len(m.faces) > before:
            repairs.append(f"filled small holes with {len(m.faces) - before} faces")
    if not m.is_watertight:
        _, uses = np.unique(m.edges_sorted, axis=0, return_counts=True)
        open_edges, shared = int((uses == 1).sum()), int((uses > 2).sum())
        raise CurvsliceError(
            f"{name}: the mesh is not a closed solid after filling small holes ({open_edges} open boundary edges, "
            f"{shared} edges shared by more than two triangles); close or clean it in a mesh editor (e.g. MeshLab "
            "'Close Holes', 'Remove Non-Manifold Edges') and retry"
        )
    if not m.is_winding_consistent:
        trimesh.repair.fix_winding(m)
        repairs.append("made face winding consistent")
    if m.volume < 0:
        m.invert()
        repairs.append("inverted inside-out faces")
    if not m.volume > 0:
        raise CurvsliceError(f"{name}: the mesh encloses no volume; give a solid, not a surface")
    return m, repairs


def orientation_to_z(up: str) -> np.ndarray:
    """4x4 rotation taking the named ``up`` axis to +Z (right-handed, proper rotation)."""
    key = up.strip().lower().lstrip("+")
    if key not in UP_AXES:
        raise CurvsliceError(f"--up must be one of {', '.join(sorted(UP_AXES))}, not {up!r}")
    a = np.array(UP_AXES[key])
    z = np.array([0.0, 0.0, 1.0])
    if np.allclose(a, z):
        return np.eye(4)
    if np.allclose(a, -z):
        return trimesh.transformations.rotation_matrix(np.pi, [1.0, 0.0, 0.0])
    axis = np.cross(a, z)
    return trimesh.transformations.rotation_matrix(np.pi / 2, axis)


def place(mesh: trimesh.Trimesh, up: str = "z", size: float | None = None,
          scale: float = 1.0) -> tuple[trimesh.Trimesh, float]:
    """Rotate ``up`` to +Z, scale (``size`` = longest extent in mm wins over ``scale``),
    centre the bounding box on the platform axis and rest the lowest point on z = 0."""
    m = mesh.copy()
    m.apply_transform(orientation_to_z(up))
    if size is not None:
        if not size > 0:
            raise CurvsliceError(f"--size must be positive, got {size}")
        scale = float(size) / float(m.extents.max())
    elif not scale > 0:
        raise CurvsliceError(f"--scale must be positive, got {scale}")
    m.apply_scale(scale)
    lo, hi = m.bounds
    m.apply_translation([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    return m, scale


def load_solid(path: str | Path | trimesh.Trimesh, up: str = "z", size: float | None = None,
               scale: float = 1.0) -> tuple[trimesh.Trimesh, LoadReport]:
    """Read (or take an in-memory mesh), repair and place a solid: the first stage of the pipeline."""
    if isinstance(path, trimesh.Trimesh):
        raw, path = path.copy(), "<in-memory mesh>"
        if not len(raw.faces) or not np.isfinite(raw.vertices).all():
            raise CurvsliceError("the mesh is empty or has non-finite vertex coordinates")
    else:
        raw = read_mesh(path)
    report = LoadReport(source=str(path), faces_in=len(raw.faces), vertices_in=len(raw.vertices), up=up)
    solid, report.repairs = repair(raw, name=str(path))
    solid, report.scale = place(solid, up=up, size=size, scale=scale)
    extent = float(solid.extents.max())
    if extent < SUSPICIOUSLY_SMALL_MM:
        raise CurvsliceError(
            f"{path}: the model is only {extent:.4g} mm across - probably in metres or inches; "
            "use --size MM (longest extent) or --scale 1000 (m) / --scale 25.4 (in)"
        )
    if extent > SUSPICIOUSLY_LARGE_MM:
        raise CurvsliceError(
            f"{path}: the model is {extent:.4g} mm across - probably in micrometres; use --size MM or --scale 0.001"
        )
    report.extent_mm = tuple(float(e) for e in solid.extents)
    return solid, report
