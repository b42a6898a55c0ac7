"""Draping a 2D design onto a curved platform (seed 000, Brooks, chapter 4).

The pipeline of seed 000 §4.4: read the DXF's lines, arcs, circles, polylines and splines
(§4.6-4.7), sample them at a fixed arc-length step, join pieces whose ends meet within a
tolerance (§4.7, 0.005 mm), centre the design and scale it to a target diameter (§4.8), remove
overlaps between closed shapes (§4.9: each shape keeps only what earlier shapes do not cover),
fill every region with scanlines at an angle and spacing, kept a clearance away from the
contours (§4.10), and project every point vertically onto the platform (§4.11): a polynomial
surface of revolution z(r) (Eq. 3-1) or a triangle mesh. Each projected point gets the surface
normal as the nozzle axis (§4.15). Contours are printed before fills (§4.13).

Where the seed's scanline pairing broke on tangents and odd crossings (Fig. 4-11 c-d), the
fill here intersects each scanline with the region as a shapely geometry, so a tangent touch is
a point (dropped) and a crossing count never has to be even.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import ezdxf
import ezdxf.path
import numpy as np
import shapely
import trimesh
from shapely.geometry import LineString, MultiPolygon, Polygon

from curvslice import flow
from curvslice.cell.cells import Cell, tool_quaternions
from curvslice.errors import CurvsliceError
from curvslice.robot_path import RobotPath
from curvslice.validate import check_budget

#: Seed 000 Eq. 3-1: the moulded platform, z(r) = -3.309e-8 r⁴ + 2.084e-21 r³ - 0.002343 r² - 4.481e-17 r + 149.6.
BROOKS_PLATFORM = (-3.309e-8, 2.084e-21, -0.002343, -4.481e-17, 149.6)

#: Most path samples a design may need (contours + fills): about 0.5 GB through projection and writers.
MAX_SAMPLES = 5_000_000

_CURVES = {"LINE", "ARC", "CIRCLE", "ELLIPSE", "SPLINE", "LWPOLYLINE", "POLYLINE"}


@dataclass(frozen=True)
class Design:
    """A 2D design ready to drape: closed regions (non-overlapping), open strokes, and fills (mm)."""

    regions: list[Polygon]
    contours: list[np.ndarray]  # closed loops (first point repeated at the end) and open strokes, (n, 2)
    fills: list[np.ndarray]  # scanline fill paths, (n, 2)


@dataclass(frozen=True)
class DrapedPath:
    """One printable path on the surface: points (n, 3) mm, unit normals (n, 3), its kind."""

    points: np.ndarray
    normals: np.ndarray
    kind: str  # "contour" | "fill"


# ------------------------------------------------------------------------------------------ DXF


def _entities(layout, layers: set[str] | None, skipped: list[str]):
    for e in layout:
        if layers is not None and e.dxf.get("layer", "0") not in layers:
            continue
        kind = e.dxftype()
        if kind == "INSERT":
            yield from _entities(e.virtual_entities(), None, skipped)
        elif kind in _CURVES:
            yield e
        else:
            skipped.append(kind)


def read_dxf(path: str | Path, *, layers: list[str] | None = None, tolerance: float = 1e-4,
             strict: bool = True) -> list[np.ndarray]:
    """The DXF's curves as 2D polylines (n, 2), flattened to within ``tolerance`` mm (seed 000 §4.7).

    Lines, arcs, circles, ellipses, splines and (LW)polylines are read, block references exploded.
    Other entities (text, hatches, dimensions) are an error when ``strict`` — the seed silently
    left them out of the print — else skipped. The tolerance grows to 1e-7 of the design's extent,
    so a huge drawing (a circle of radius 1e9) flattens to a few thousand points, not millions.
    """
    path = Path(path)
    if not path.is_file():
        raise CurvsliceError(f"DXF file {path} does not exist")
    try:
        doc = ezdxf.readfile(path)
    except (OSError, ezdxf.DXFStructureError) as exc:
        raise CurvsliceError(f"{path}: not a readable DXF file ({exc})") from None
    skipped: list[str] = []
    curves = []
    paths = [ezdxf.path.make_path(e) for e in _entities(doc.modelspace(), set(layers) if layers else None, skipped)]
    corners = np.array([(v.x, v.y) for p in paths for v in p.control_vertices()], float).reshape(-1, 2)
    if not np.isfinite(corners).all():
        raise CurvsliceError(f"{path}: a curve has a non-finite coordinate")
    extent = float(np.ptp(corners, axis=0).max()) if len(corners) else 0.0
    tolerance = max(tolerance, 1e-7 * extent)
    for p in paths:
        pts = np.array([(v.x, v.y) for v in p.flattening(tolerance)], float)
        if len(pts) >= 2:
            curves.append(pts)
    if skipped and strict:
        kinds = ", ".join(sorted(set(skipped)))
        raise CurvsliceError(f"{path}: unsupported DXF entities ({kinds}); explode them to curves or use --skip-unsupported")
    if not curves:
        raise CurvsliceError(f"{path}: no lines, arcs, circles, polylines or splines found"
                             + (f" on layers {', '.join(layers)}" if layers else ""))
    return curves


# ------------------------------------------------------------------------------ 2D processing


def arc_length(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length (n,) along a polyline."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def resample(points: np.ndarray, step: float) -> np.ndarray:
    """Points at equal arc-length spacing ≤ ``step`` along the polyline, both ends kept.

    The spacing is the polyline length divided by ⌈length / step⌉, so a closed loop has no short
    last piece (seed 000 §4.7 samples at 0.2 mm).
    """
    s = arc_length(points)
    if s[-1] == 0:
        return points[:1].copy()
    n = max(1, math.ceil(s[-1] / step - 1e-9))
    t = np.linspace(0.0, s[-1], n + 1)
    return np.stack([np.interp(t, s, points[:, k]) for k in range(points.shape[1])], axis=1)


def join_paths(paths: list[np.ndarray], tolerance: float = 0.005) -> list[np.ndarray]:
    """Merge pieces whose ends meet within ``tolerance`` (seed 000 §4.7, its four match cases).

    Returns chains; a chain whose ends meet is closed by repeating its first point.
    """
    pending = [np.asarray(p, float) for p in paths if len(p) >= 2]
    chains = []
    while pending:
        chain = pending.pop(0)
        grown = True
        while grown and pending:
            grown = False
            if np.linalg.norm(chain[0] - chain[-1]) <= tolerance:
                break
            ends = np.array([[p[0], p[-1]] for p in pending])  # (m, 2, 2)
            d_end = np.linalg.norm(ends - chain[-1], axis=2)
            d_start = np.linalg.norm(ends - chain[0], axis=2)
            if d_end.min() <= tolerance:
                k, which = np.unravel_index(np.argmin(d_end), d_end.shape)
                piece = pending.pop(k)
                chain = np.vstack([chain, (piece if which == 0 else piece[::-1])[1:]])  # cases 1, 2
                grown = True
            elif d_start.min() <= tolerance:
                k, which = np.unravel_index(np.argmin(d_start), d_start.shape)
                piece = pending.pop(k)
                chain = np.vstack([(piece[::-1] if which == 0 else piece)[:-1], chain])  # cases 4, 3
                grown = True
        if len(chain) > 2 and np.linalg.norm(chain[0] - chain[-1]) <= tolerance:
            chain = chain.copy()
            chain[-1] = chain[0]
        chains.append(chain)
    return chains


def is_closed(path: np.ndarray) -> bool:
    return len(path) > 3 and bool(np.all(path[0] == path[-1]))


def centre_and_scale(paths: list[np.ndarray], diameter: float | None) -> list[np.ndarray]:
    """Move the bounding-box centre to the origin; scale so the farthest point lies at ``diameter``/2."""
    allpts = np.vstack(paths)
    centre = (allpts.min(axis=0) + allpts.max(axis=0)) / 2
    moved = [p - centre for p in paths]
    if diameter is None:
        return moved
    radius = np.linalg.norm(allpts - centre, axis=1).max()
    if radius == 0:
        raise CurvsliceError("the design has no extent to scale")
    return [p * (diameter / 2 / radius) for p in moved]


def remove_overlaps(loops: list[np.ndarray], mode: str = "first", min_area: float = 0.0) -> list[Polygon]:
    """Non-overlapping regions from closed loops (seed 000 §4.9).

    ``"first"``: in drawing order each loop keeps what the earlier ones do not cover (the seed's
    difference-then-union). ``"evenodd"``: nested loops make holes. Pieces below ``min_area`` mm²
    are dropped (§4.4: "entities … too small to print are discarded").
    """
    if mode not in ("first", "evenodd"):
        raise CurvsliceError(f"overlap mode must be 'first' or 'evenodd', not {mode!r}")
    shapes = [shapely.make_valid(Polygon(p)) for p in loops]
    pieces: list[Polygon] = []
    if mode == "evenodd":
        region = Polygon()
        for s in shapes:
            region = region.symmetric_difference(s)
        pieces = _polygons(region)
    else:
        covered = Polygon()
        for s in shapes:
            pieces += _polygons(s.difference(covered))
            covered = covered.union(s)
    return [p for p in pieces if p.area > max(min_area, 1e-12)]


def _polygons(geom) -> list[Polygon]:
    if isinstance(geom, Polygon):
        return [] if geom.is_empty else [geom]
    if isinstance(geom, MultiPolygon):
        return list(geom.geoms)
    return [g for part in getattr(geom, "geoms", []) for g in _polygons(part)]


def region_loops(region: Polygon) -> list[np.ndarray]:
    """The boundary loops of a region (exterior, then holes), each closed."""
    return [np.asarray(r.coords)[:, :2] for r in [region.exterior, *region.interiors]]


def scanline_fill(region: Polygon, angle: float, spacing: float, clearance: float, step: float) -> list[np.ndarray]:
    """Scanline fill paths of ``region`` (seed 000 §4.10): lines at ``angle`` (rad) every ``spacing``
    mm, inside the region shrunk by ``clearance``, sampled every ≤ ``step`` mm, in serpentine
    order; consecutive lines are joined where the joint stays inside."""
    if spacing <= 0 or step <= 0:
        raise CurvsliceError("fill spacing and sampling step must be positive")
    inner = region.buffer(-clearance, quad_segs=64) if clearance > 0 else region
    if inner.is_empty:
        return []
    c, s = math.cos(angle), math.sin(angle)
    along, across = np.array([c, s]), np.array([-s, c])
    pts = np.vstack([np.asarray(g.exterior.coords)[:, :2] for g in _polygons(inner)])
    u, v = pts @ along, pts @ across
    offsets = np.arange(v.min() + spacing / 2, v.max(), spacing)
    guard = inner.buffer(1e-9)
    paths: list[np.ndarray] = []
    for k, off in enumerate(offsets):
        line = LineString([along * (u.min() - 1) + across * off, along * (u.max() + 1) + across * off])
        segments = [np.asarray(g.coords)[:, :2] for g in _lines(inner.intersection(line))]
        segments = [seg for seg in segments if np.linalg.norm(seg[-1] - seg[0]) > 1e-9]
        segments.sort(key=lambda seg: float(seg[0] @ along + seg[-1] @ along))
        segments = [seg if (seg[-1] - seg[0]) @ along > 0 else seg[::-1] for seg in segments]
        if k % 2:
            segments = [seg[::-1] for seg in segments[::-1]]
        for seg in segments:
            seg = resample(seg, step)
            if paths and guard.covers(LineString([paths[-1][-1], seg[0]])) and _next_line(paths[-1], seg, across, spacing):
                paths[-1] = np.vstack([paths[-1], resample(np.array([paths[-1][-1], seg[0]]), step)[1:-1], seg])
            else:
                paths.append(seg)
    return paths


def _lines(geom) -> list[LineString]:
    if isinstance(geom, LineString):
        return [] if geom.is_empty else [geom]
    return [g for part in getattr(geom, "geoms", []) for g in _lines(part)]


def _next_line(path: np.ndarray, seg: np.ndarray, across: np.ndarray, spacing: float) -> bool:
    """True when ``seg`` starts on the scanline right after the one ``path`` ends on."""
    return abs((seg[0] - path[-1]) @ across - spacing) < 1e-6 * max(1.0, spacing)


def order_paths(paths: list[np.ndarray], start: np.ndarray) -> list[np.ndarray]:
    """Greedy nearest-neighbour order; a closed loop is rotated to begin nearest the previous end."""
    remaining = list(paths)
    ordered = []
    here = np.asarray(start, float)
    while remaining:
        best, best_d, best_path = 0, np.inf, None
        for k, p in enumerate(remaining):
            if is_closed(p):
                i = int(np.argmin(np.linalg.norm(p[:-1] - here, axis=1)))
                cand = np.vstack([p[i:-1], p[: i + 1]])
            else:
                cand = p if np.linalg.norm(p[0] - here) <= np.linalg.norm(p[-1] - here) else p[::-1]
            d = float(np.linalg.norm(cand[0] - here))
            if d < best_d:
                best, best_d, best_path = k, d, cand
        remaining.pop(best)
        ordered.append(best_path)
        here = best_path[-1]
    return ordered


def design_from_paths(
    curves: list[np.ndarray],
    *,
    step: float = 0.2,
    join_tolerance: float = 0.005,
    diameter: float | None = None,
    overlap: str = "first",
    min_area: float = 0.5,
    fill_angle: float = 0.0,
    fill_spacing: float = 0.8,
    clearance: float = 0.8,
    fill: bool = True,
) -> Design:
    """Join, centre/scale, de-overlap and fill a design's curves (seed 000 §4.7-4.10)."""
    chains = centre_and_scale(join_paths(curves, join_tolerance), diameter)
    loops = [c for c in chains if is_closed(c)]
    strokes = [c for c in chains if not is_closed(c)]
    regions = remove_overlaps(loops, overlap, min_area)
    length = sum(float(arc_length(c)[-1]) for c in chains) + (sum(r.area for r in regions) / fill_spacing if fill else 0.0)
    check_budget(f"drape: path samples for {length:.4g} mm of contours and fills at a {step:g} mm step",
                 length / step, MAX_SAMPLES, "raise --step or --fill-spacing, or scale the design with --diameter")
    contours = [resample(loop, step) for r in regions for loop in region_loops(r)]
    contours += [resample(s, step) for s in strokes]
    fills = [f for r in regions for f in scanline_fill(r, fill_angle, fill_spacing, clearance, step)] if fill else []
    return Design(regions, order_paths(contours, np.zeros(2)),
                  order_paths(fills, contours[-1][-1] if contours else np.zeros(2)))


# ------------------------------------------------------------------------------------ surfaces


@dataclass(frozen=True)
class PolynomialSurface:
    """A surface of revolution z = p(r), r = √(x² + y²), coefficients highest power first (seed 000 Eq. 3-1)."""

    coefficients: tuple[float, ...]

    def height(self, r) -> np.ndarray:
        return np.polyval(self.coefficients, np.asarray(r, float))

    def slope(self, r) -> np.ndarray:
        """dz/dr; the tangent angle is atan(slope) (seed 000 §4.15.1)."""
        return np.polyval(np.polyder(self.coefficients), np.asarray(r, float))

    def project(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vertical projection (seed 000 §4.11): points (n, 3) on the surface and unit normals (n, 3)."""
        xy = np.asarray(xy, float)
        r = np.hypot(xy[:, 0], xy[:, 1])
        dz = self.slope(r)
        safe = np.where(r > 0, r, 1.0)
        grad = np.where(r[:, None] > 0, dz[:, None] * xy / safe[:, None], 0.0)
        normals = np.column_stack([-grad, np.ones(len(xy))])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        return np.column_stack([xy, self.height(r)]), normals


@dataclass(frozen=True)
class MeshSurface:
    """A platform given as a triangle mesh (mm, Z up); points are projected straight down onto
    its top, normals interpolated from the vertex normals."""

    mesh: trimesh.Trimesh

    def project(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xy = np.asarray(xy, float)
        tri = self.mesh.triangles  # (F, 3, 3)
        lo, hi = tri[:, :, :2].min(axis=1), tri[:, :, :2].max(axis=1)
        cell = max(float(np.median(hi - lo)) * 2, 1e-6)
        origin = lo.min(axis=0)
        # bin triangles into the grid cells their xy boxes overlap
        c0 = np.floor((lo - origin) / cell).astype(np.int64)
        c1 = np.floor((hi - origin) / cell).astype(np.int64)
        ncols = int(c1[:, 0].max()) + 1
        spans = (c1 - c0 + 1)
        counts = spans[:, 0] * spans[:, 1]
        face = np.repeat(np.arange(len(tri)), counts)
        k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        cx = c0[face, 0] + k % spans[face, 0]
        cy = c0[face, 1] + k // spans[face, 0]
        key = cy * ncols + cx
        order = np.argsort(key, kind="stable")
        key, face = key[order], face[order]
        p = np.floor((xy - origin) / cell).astype(np.int64)
        inside_grid = (p[:, 0] >= 0) & (p[:, 0] < ncols) & (p[:, 1] >= 0)
        pkey = np.where(inside_grid, p[:, 1] * ncols + p[:, 0], -1)
        start = np.searchsorted(key, pkey, side="left")
        stop = np.searchsorted(key, pkey, side="right")
        n_cand = np.where(inside_grid, stop - start, 0)
        point = np.repeat(np.arange(len(xy)), n_cand)
        cand = face[np.repeat(start, n_cand) + np.arange(n_cand.sum()) - np.repeat(np.cumsum(n_cand) - n_cand, n_cand)]
        a, b, c = tri[cand, 0], tri[cand, 1], tri[cand, 2]
        q = xy[point]
        det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
        ok = np.abs(det) > 1e-15
        det = np.where(ok, det, 1.0)
        l1 = ((q[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (q[:, 1] - a[:, 1])) / det
        l2 = ((b[:, 0] - a[:, 0]) * (q[:, 1] - a[:, 1]) - (q[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])) / det
        l0 = 1 - l1 - l2
        eps = 1e-12
        hit = ok & (l0 >= -eps) & (l1 >= -eps) & (l2 >= -eps)
        z = l0 * a[:, 2] + l1 * b[:, 2] + l2 * c[:, 2]
        z = np.where(hit, z, -np.inf)
        best = np.full(len(xy), -np.inf)
        np.maximum.at(best, point, z)
        missed = ~np.isfinite(best)
        if missed.any():
            raise CurvsliceError(
                f"{int(missed.sum())} of {len(xy)} design points fall outside the surface mesh in plan view "
                f"(first at x={xy[missed][0, 0]:.3f}, y={xy[missed][0, 1]:.3f}); scale the design down"
            )
        top = hit & (z == best[point])
        sel = np.zeros(len(xy), np.int64)
        sel[point[top]] = np.flatnonzero(top)
        vn = self.mesh.vertex_normals[self.mesh.faces[cand[sel]]]  # (n, 3, 3)
        normals = l0[sel, None] * vn[:, 0] + l1[sel, None] * vn[:, 1] + l2[sel, None] * vn[:, 2]
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        return np.column_stack([xy, best]), normals


def load_surface(spec: str) -> PolynomialSurface | MeshSurface:
    """``brooks`` (seed 000's platform), ``poly:c4,c3,c2,c1,c0`` (highest power first), or a mesh file."""
    if spec == "brooks":
        return PolynomialSurface(BROOKS_PLATFORM)
    if spec.startswith("poly:"):
        try:
            coeffs = tuple(float(c) for c in spec[5:].split(","))
        except ValueError:
            raise CurvsliceError(f"surface {spec!r}: coefficients must be numbers, e.g. poly:-0.002343,0,149.6") from None
        if not all(math.isfinite(c) for c in coeffs):
            raise CurvsliceError(f"surface {spec!r}: coefficients must be finite numbers")
        return PolynomialSurface(coeffs)
    path = Path(spec)
    if not path.is_file():
        raise CurvsliceError(f"surface {spec!r} is neither 'brooks', 'poly:…' nor a mesh file")
    mesh = trimesh.load(path, force="mesh")
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise CurvsliceError(f"{path}: no triangles found")
    return MeshSurface(mesh)


def drape(design: Design, surface: PolynomialSurface | MeshSurface, fill_lift: float = 0.0) -> list[DrapedPath]:
    """Project contours then fills onto the surface (seed 000 §4.11, §4.13); fills are raised by
    ``fill_lift`` mm along the normal (the seed used 0.2 mm to clear the contours)."""
    out = []
    for kind, paths in (("contour", design.contours), ("fill", design.fills)):
        for p in paths:
            pts, nrm = surface.project(p)
            out.append(DrapedPath(pts + (fill_lift * nrm if kind == "fill" else 0.0), nrm, kind))
    return out


def draped_robot_path(
    paths: list[DrapedPath],
    cell: Cell,
    *,
    print_speed: float = 10.0,
    travel_speed: float = 50.0,
    travel_lift: float = 5.0,
    bead_width: float = 0.8,
    bead_height: float = 0.4,
    filament_diameter: float = 1.75,
) -> RobotPath:
    """A robot path through all draped paths: lift ``travel_lift`` along the normal, travel,
    descend, then extrude along the path (E from the stadium bead model, :func:`flow.filament_length`)."""
    pos, nrm, speed, ext = [], [], [], []
    for p in paths:
        above = p.points[0] + travel_lift * p.normals[0]
        if pos:  # lift off the end of the previous path
            pos.append(pos[-1] + travel_lift * nrm[-1])
            nrm.append(nrm[-1])
            speed.append(travel_speed)
            ext.append(0.0)
        seg = np.linalg.norm(np.diff(p.points, axis=0), axis=1)
        pos += [above, *p.points]
        nrm += [p.normals[0], *p.normals]
        speed += [travel_speed, travel_speed, *([print_speed] * len(seg))]
        ext += [0.0, 0.0, *flow.filament_length(seg, bead_width, bead_height, filament_diameter)]
    if not pos:
        raise CurvsliceError("the design produced no printable paths")
    normals = np.asarray(nrm, float)
    n = len(pos)
    return RobotPath(
        positions=np.asarray(pos, float) + np.asarray(cell.offset, float),
        quaternions=tool_quaternions(normals, cell.orientation),
        speed=np.asarray(speed, float),
        extrusion=np.asarray(ext, float),
        tool=np.zeros(n, np.int32),
        layer=np.ones(n, np.int32),
        line=np.zeros(n, np.int32),
        home=np.zeros(n, bool),
    )

