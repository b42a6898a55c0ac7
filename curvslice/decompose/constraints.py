"""The collision-avoidance constraints of the RoboFDM decomposition (thesis §2.4.3).

- Constraint I: the base cross-sections (each part's section by its base plane) do not intersect
  each other (Fig. 2.6). Two planar regions in non-parallel planes meet only on the planes' common
  line, so each region is cut by that line into intervals and the interval sets must not overlap
  by more than ``tol``; regions in one plane must not overlap in area.
- Constraint II: every base plane faces up, read here in the platform frame: its normal makes a
  positive dot product with the root's build direction (the platform's up), so the nozzle never
  reaches under the platform.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely import affinity

from curvslice.decompose.parts import Plane


def _line_intervals(region: shapely.MultiPolygon, frame: np.ndarray, point: np.ndarray, direction: np.ndarray,
                    reach: float) -> list[tuple[float, float]]:
    """Parameter intervals t of ``point + t·direction`` (a line in the region's plane) inside the region."""
    inv = np.linalg.inv(frame)
    a = (inv @ np.r_[point - reach * direction, 1.0])[:2]
    b = (inv @ np.r_[point + reach * direction, 1.0])[:2]
    hit = region.intersection(shapely.LineString([a, b]))
    out = []
    for g in getattr(hit, "geoms", [hit]):
        if isinstance(g, shapely.LineString) and not g.is_empty:
            xy = np.asarray(g.coords)[[0, -1]]
            t = (xy - a) @ (b - a) / ((b - a) @ (b - a)) * 2 * reach - reach
            out.append((float(t.min()), float(t.max())))
    return out


def sections_intersect(pa: Plane, ra: shapely.MultiPolygon, pb: Plane, rb: shapely.MultiPolygon,
                       tol: float = 0.1) -> bool:
    """Constraint I between two base cross-sections (regions in the frames of their planes)."""
    if ra.is_empty or rb.is_empty:
        return False
    direction = np.cross(pa.normal, pb.normal)
    s = np.linalg.norm(direction)
    if s < 1e-6:  # parallel planes: only coplanar ones can meet
        same = pa.normal @ pb.normal > 0
        if abs(pa.offset - (pb.offset if same else -pb.offset)) > tol:
            return False
        to_a = np.linalg.inv(pa.frame()) @ pb.frame()
        rb_in_a = affinity.affine_transform(rb, [*to_a[:2, :2].ravel(), *to_a[:2, 3]])
        return ra.intersection(rb_in_a).area > tol * tol
    direction = direction / s
    # a point on both planes: least-norm solution of [na; nb] x = [ca; cb]
    point = np.linalg.lstsq(np.vstack([pa.normal, pb.normal]), np.array([pa.offset, pb.offset]), rcond=None)[0]
    reach = 1e4
    ia = _line_intervals(ra, pa.frame(), point, direction, reach)
    ib = _line_intervals(rb, pb.frame(), point, direction, reach)
    return any(min(a1, b1) - max(a0, b0) > tol for a0, a1 in ia for b0, b1 in ib)


def constraint_one(planes: list[Plane], regions: list[shapely.MultiPolygon], tol: float = 0.1) -> list[tuple[int, int]]:
    """Pairs (i, j) of base cross-sections violating Constraint I."""
    return [(i, j) for i in range(len(planes)) for j in range(i + 1, len(planes))
            if sections_intersect(planes[i], regions[i], planes[j], regions[j], tol)]


def faces_up(normal: np.ndarray, root_direction: np.ndarray, margin: float = 1e-6) -> bool:
    """Constraint II for one base plane."""
    return float(np.asarray(normal) @ np.asarray(root_direction)) > margin
