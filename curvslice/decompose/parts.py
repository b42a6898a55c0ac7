"""Planar parts of a RoboFDM decomposition (thesis §2.4): exact plane cuts, base cross-sections, poses.

A part is a closed solid (a :class:`manifold3d.Manifold`, cut exactly by planes) printed in planar
layers along its build direction ``d`` starting on its *base plane* ``d·x = offset`` (the plane
separating it from its parent, oriented from the parent into the part, §2.4.2). The root's base
plane is the platform: its lowest supporting plane along ``d``.
"""

from __future__ import annotations

from dataclasses import dataclass

import manifold3d
import numpy as np
import shapely
import trimesh


@dataclass(frozen=True)
class Plane:
    """Oriented plane ``normal · x = offset`` (unit normal; the part lies on the ``+normal`` side)."""

    normal: np.ndarray
    offset: float

    def frame(self) -> np.ndarray:
        """4x4 frame on the plane: z = normal, origin = the point of the plane nearest the origin."""
        return plane_frame(self.normal, self.normal * self.offset)


def unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def plane_frame(normal: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Right-handed 4x4 frame with z = ``normal`` and x the world x (or y) projected on the plane."""
    z = unit(normal)
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = unit(ref - (ref @ z) * z)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, origin
    return T


def to_manifold(mesh: trimesh.Trimesh) -> manifold3d.Manifold:
    """A trimesh solid as a manifold3d solid (raises ValueError if it is not a closed 2-manifold)."""
    out = manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(mesh.vertices, np.float32),
                                              tri_verts=np.asarray(mesh.faces, np.uint32)))
    if out.status() != manifold3d.Error.NoError:
        raise ValueError(f"not a closed manifold solid: {out.status()}")
    return out


def to_trimesh(solid: manifold3d.Manifold) -> trimesh.Trimesh:
    mesh = solid.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=False)


def centroid(solid: manifold3d.Manifold) -> np.ndarray:
    """Mean vertex position (only used to tell components apart)."""
    return np.asarray(solid.to_mesh().vert_properties)[:, :3].mean(axis=0)


def split(solid: manifold3d.Manifold, plane: Plane) -> tuple[manifold3d.Manifold, list[manifold3d.Manifold]]:
    """Exact cut: (the side below the plane, the connected pieces above it)."""
    above, below = solid.split_by_plane(tuple(float(v) for v in plane.normal), float(plane.offset))
    return below, [] if above.is_empty() else list(above.decompose())


def union(solids: list[manifold3d.Manifold]) -> manifold3d.Manifold:
    solids = [s for s in solids if not s.is_empty()]
    return manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add) if len(solids) > 1 else solids[0]


def cross_section(solid: manifold3d.Manifold, plane: Plane, lift: float = 1e-3) -> shapely.MultiPolygon:
    """The section of ``solid`` by ``plane`` (lifted by ``lift`` mm so a base face is cut just above
    itself), as polygons in the coordinates (x, y) of :meth:`Plane.frame`."""
    T = np.linalg.inv(plane.frame())
    sec = solid.transform(T[:3, :]).slice(lift)
    area = shapely.Polygon()
    for ring in sec.to_polygons():  # outer rings and holes: their even-odd union is the section
        if len(ring) >= 3:
            area = area.symmetric_difference(shapely.Polygon(ring).buffer(0))
    return area if isinstance(area, shapely.MultiPolygon) else shapely.MultiPolygon(
        [g for g in getattr(area, "geoms", [area]) if isinstance(g, shapely.Polygon) and not g.is_empty])


def part_pose(base: Plane, base_centre: np.ndarray, root_frame: np.ndarray) -> np.ndarray:
    """T_P^E of Eq. 2.3: the part frame P (origin at the centre of its base cross-section, z along its
    build direction) in the end-effector frame E (origin at the centre of the root's base plane)."""
    return np.linalg.inv(root_frame) @ plane_frame(base.normal, base_centre)
