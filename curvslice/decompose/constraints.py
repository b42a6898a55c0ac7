"""The collision-avoidance constraints of the RoboFDM decomposition (thesis §2.4.3).

- Constraint I: the base cross-sections (each part's section by its base plane) do not intersect
  each other (Fig. 2.6). Two planar regions in non-parallel planes meet only on the planes' common
  line, so each region is cut by that line into intervals and the interval sets must not overlap
  by more than ``tol``; regions in one plane must not overlap in area.
- Constraint II: every base plane faces up, read here in the platform frame: its normal makes a
  positive dot product with the root's build direction (the platform's up), so the nozzle never
  reaches under the platform.
- Platform clearance (not in the thesis; its §2.6 names Constraint II as a collision heuristic that
  falls short): a part printed with its direction tilted by θ from the platform's normal must keep
  its lowest point :func:`platform_clearance` (θ) above the platform, or the extruder -- the bodies
  of the workcell, the thesis's UR3 cell by default -- hits the platform while printing it.
- Accessibility (not in the thesis either; §2.6 limitation 5): printing a part, the extruder --
  its bodies swept over every nozzle position of the part, turned about the nozzle axis as the
  robot may turn the platform (Eq. 4.3) -- must find a turn that holds none of the material of the
  parts that may be printed before it (:func:`turn_hits`). Constraint I stops only the
  crossing base sections of Fig. 2.6; a part leaning over a part printed before it still meets the
  heater block or the extruder body above its first layers (the bunny's ears over its head).
"""

from __future__ import annotations

import numpy as np
import shapely
import trimesh
from shapely import affinity

from curvslice.decompose.parts import Plane
from curvslice.workcell import Body, Workcell


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


def _hull_points(body: Body, sections: int = 64) -> np.ndarray:
    """Points whose convex hull holds the workcell body (box corners; a cylinder's two rims; a cone's
    base rim and apex at +length/2, :mod:`curvslice.workcell`; rims circumscribed), in the body's
    parent frame."""
    if body.kind == "box":
        local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * np.asarray(body.dims) / 2
    else:
        r, h = body.dims[0] / np.cos(np.pi / sections), body.dims[1]
        a = 2 * np.pi * np.arange(sections) / sections
        rim = np.c_[r * np.cos(a), r * np.sin(a), np.full(sections, -h / 2)]
        local = np.vstack([rim, rim + [0, 0, h]] if body.kind == "cylinder" else [rim, [[0.0, 0.0, h / 2]]])
    return local @ body.pose[:3, :3].T + body.pose[:3, 3]


def platform_clearance(cell: Workcell, tilt: float, turns: int = 72) -> float:
    """Height (mm) above the platform top that the nozzle tip needs to print with its axis tilted by
    ``tilt`` (rad) from the platform's normal: the depth of the extruder's lowest point (vertices of
    the workcell's extruder bodies in the nozzle frame N) below the tip, at the best of ``turns``
    turns about the nozzle axis (the motion stage may turn the deposition frame about it, Eq. 4.3).
    Constraint II only keeps base planes facing up; a part tilted far from the platform's normal that
    reaches down to the platform cannot be printed without the extruder hitting the platform
    (thesis §2.6, limitation 5)."""
    pts = np.vstack([_hull_points(b) for b in cell.extruder])
    phi = 2 * np.pi * np.arange(turns) / turns
    # height of each point over the tip with N's z tilted by `tilt` towards the horizontal direction at `phi`
    side = pts[:, 0][None, :] * np.cos(phi)[:, None] + pts[:, 1][None, :] * np.sin(phi)[:, None]
    lowest = (pts[:, 2][None, :] * np.cos(tilt) - side * np.sin(tilt)).min(axis=1)
    return float(max(0.0, -lowest.max()))


def clearance_table(cell: Workcell, step_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """:func:`platform_clearance` at tilts 0..90° every ``step_deg`` (radians, mm), for :func:`np.interp`."""
    tilts = np.radians(np.arange(0.0, 90.0 + step_deg / 2, step_deg))
    return tilts, np.array([platform_clearance(cell, t) for t in tilts])


def clears_platform(vertices: np.ndarray, normal: np.ndarray, root_direction: np.ndarray, platform: float,
                    table: tuple[np.ndarray, np.ndarray] | None) -> bool:
    """Platform clearance of a part (its ``vertices``) printed along ``normal``; ``platform`` is the
    platform top's offset along ``root_direction``; True without a ``table``."""
    if table is None or not len(vertices):
        return True
    tilt = float(np.arccos(np.clip(np.asarray(normal) @ np.asarray(root_direction), -1.0, 1.0)))
    return float((np.asarray(vertices) @ root_direction).min() - platform) >= float(np.interp(tilt, *table)) - 1e-6


def _inside_body(body: Body, x: np.ndarray) -> np.ndarray:
    """Points ``x`` (..., 3) of the body's parent frame inside the body (box; cylinder; cone with its
    base at -length/2 and apex at +length/2, as :mod:`curvslice.workcell` draws them)."""
    local = (x - body.pose[:3, 3]) @ body.pose[:3, :3]
    if body.kind == "box":
        return np.all(np.abs(local) <= np.asarray(body.dims) / 2, axis=-1)
    r, h = body.dims[0], body.dims[1]
    radial, z = np.hypot(local[..., 0], local[..., 1]), local[..., 2]
    reach = r if body.kind == "cylinder" else r * (0.5 - z / h)
    return (np.abs(z) <= h / 2) & (radial <= reach)


def extruder_hits(cell: Workcell, positions: np.ndarray, direction: np.ndarray, obstacles: np.ndarray,
                  turns: int = 12, above: float = 0.5) -> np.ndarray:
    """(positions, turns) bool: with its tip at a position, its axis along ``direction`` and turned by
    2πj/``turns`` about it, some body of the workcell's extruder holds a point of ``obstacles``
    (material printed before) higher than ``above`` mm over the tip (the tip itself rests on the
    layer below). Not in the thesis, whose sequence keeps only Constraints I and II (§2.6 names the gap)."""
    from curvslice.decompose.parts import plane_frame

    out = np.zeros((len(positions), turns), bool)
    if not len(positions) or not len(obstacles):
        return out
    R = plane_frame(np.asarray(direction, float), np.zeros(3))[:3, :3]
    local = (np.asarray(obstacles)[None, :, :] - np.asarray(positions)[:, None, :]) @ R  # (S, O, 3) in N, untilted
    hulls = [_hull_points(b) for b in cell.extruder]
    reach = max(float(np.linalg.norm(h, axis=1).max()) for h in hulls)
    s_idx, o_idx = np.nonzero((local[:, :, 2] > above) & (np.einsum("soi,soi->so", local, local) <= reach * reach))
    pts = local[s_idx, o_idx]
    radius = np.hypot(pts[:, 0], pts[:, 1])
    phi = 2 * np.pi * np.arange(turns) / turns
    c, s = np.cos(phi), np.sin(phi)
    inside = np.zeros((len(pts), turns), bool)
    for body, hull in zip(cell.extruder, hulls):  # turns keep a point's height and distance from the axis: a first filter
        near = np.flatnonzero((pts[:, 2] >= hull[:, 2].min()) & (pts[:, 2] <= hull[:, 2].max())
                              & (radius <= np.hypot(hull[:, 0], hull[:, 1]).max()))
        p = pts[near]
        # the obstacles in each turned extruder's frame: rotated by -phi about the axis
        turned = np.stack([p[:, None, 0] * c + p[:, None, 1] * s, -p[:, None, 0] * s + p[:, None, 1] * c,
                           np.broadcast_to(p[:, None, 2], (len(p), turns))], axis=-1)
        inside[near] |= _inside_body(body, turned)
    if len(s_idx):  # s_idx is sorted (np.nonzero): OR the pairs of each position by segments
        starts = np.flatnonzero(np.r_[True, s_idx[1:] != s_idx[:-1]])
        out[s_idx[starts]] = np.logical_or.reduceat(inside, starts, axis=0)
    return out


def material_points(mesh: trimesh.Trimesh, spacing: float = 2.0, seed: int = 0) -> np.ndarray:
    """Points standing for a part's material as an obstacle of the extruder: its surface sampled
    about one point per ``spacing``² mm² (every extruder body is wider than ``spacing``; the nozzle
    cone, narrower, reaches past its tip only :data:`ABOVE_TIP_MM`)."""
    count = max(1, int(np.ceil(mesh.area / spacing**2)))
    return trimesh.sample.sample_surface(mesh, count, seed=seed)[0]


#: Material this close over the nozzle tip (mm, along the build direction) is the layer being
#: printed on, not an obstacle (half a layer of a 1 mm nozzle, as :func:`extruder_hits`).
ABOVE_TIP_MM = 0.5


def nozzle_positions(part: trimesh.Trimesh, samples: int = 100, seed: int = 0) -> np.ndarray:
    """Nozzle positions standing for a part's printing: ``samples`` area-weighted points of its surface
    (its outer perimeters, where the extruder passes closest to other material)."""
    return trimesh.sample.sample_surface(part, samples, seed=seed)[0]


def turn_hits(cell: Workcell, positions: np.ndarray, direction: np.ndarray, offset: float,
              obstacles: np.ndarray) -> np.ndarray:
    """Accessibility of a part printed along ``direction`` from its base plane ``direction·x =
    offset``: (positions, turns) bool, whether the extruder at each of its nozzle ``positions``
    (:func:`nozzle_positions`) turned about its axis (:func:`extruder_hits`) holds some of the
    ``obstacles`` (material printed before it, :func:`material_points`); a position is *blocked*
    when every turn hits. Material lower than the base plane cannot be over a nozzle position and is
    skipped first."""
    d = np.asarray(direction, float)
    obs = np.asarray(obstacles).reshape(-1, 3)
    return extruder_hits(cell, positions, d, obs[obs @ d > offset + ABOVE_TIP_MM], above=ABOVE_TIP_MM)
