"""Draping a 2D design onto a curved platform (seed 000): the platform vectors, DXF reading and
joining, overlap removal, robust fills, projection onto a polynomial and a mesh, export."""

from __future__ import annotations

import math

import ezdxf
import numpy as np
import pytest
import trimesh
from shapely.geometry import LineString, Point, Polygon
from shapely.ops import unary_union

from curvslice import cli
from curvslice.cell.cells import load_cell, tool_normals
from curvslice.cell.drape import (
    BROOKS_PLATFORM,
    MeshSurface,
    PolynomialSurface,
    centre_and_scale,
    design_from_paths,
    drape,
    draped_robot_path,
    join_paths,
    load_surface,
    read_dxf,
    remove_overlaps,
    resample,
    scanline_fill,
)
from curvslice.errors import CurvsliceError
from curvslice.exporters.gcode6 import read_gcode6
from curvslice.exporters.rapid import read_rapid
from curvslice.exporters.urscript import read_urscript


def make_dxf(path, text: bool = False) -> None:
    """Circles (two overlapping), a square overlapping the big circle, a 'D' from an arc and a line,
    a closed spline blob and an open spline stroke."""
    doc = ezdxf.new()
    msp = doc.modelspace()
    msp.add_circle((0, 0), 20)
    msp.add_circle((25, 0), 12)
    msp.add_lwpolyline([(-30, -30), (-5, -30), (-5, -10), (-30, -10)], close=True)
    msp.add_arc((0, 35), 8, -90, 90)
    msp.add_line((0, 43), (0, 27))
    blob = [(30 + 6 * math.cos(t), 30 + 4 * math.sin(t)) for t in np.linspace(0, 2 * math.pi, 9)[:-1]]
    msp.add_spline(fit_points=blob + [blob[0]])
    msp.add_spline(fit_points=[(-35, 20), (-25, 28), (-15, 18), (-5, 25)])
    if text:
        msp.add_text("hello", dxfattribs={"insert": (0, -40)})
    doc.saveas(path)


def test_brooks_platform_vectors():
    """Seed 000 Eq. 3-1: z(0) = 149.6, z(100) ≈ 122.861 with a −31.0° tangent."""
    s = PolynomialSurface(BROOKS_PLATFORM)
    assert float(s.height(0.0)) == pytest.approx(149.6, abs=1e-12)
    assert float(s.height(100.0)) == pytest.approx(122.861, abs=5e-4)
    assert round(math.degrees(math.atan(float(s.slope(100.0)))), 1) == -31.0
    pts, normals = s.project(np.array([[100.0, 0.0], [0.0, 0.0]]))
    assert math.degrees(math.acos(normals[0, 2])) == pytest.approx(31.0, abs=0.05)  # tilt of the nozzle axis
    assert np.allclose(normals[1], [0, 0, 1])


def test_resample_and_join():
    circle = np.c_[np.cos(np.linspace(0, 2 * np.pi, 2001)), np.sin(np.linspace(0, 2 * np.pi, 2001))] * 10
    pts = resample(circle, 0.2)
    steps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    assert steps.max() <= 0.2 + 1e-12 and np.ptp(steps) < 1e-3  # equal spacing, no short last piece
    assert np.abs(np.linalg.norm(pts, axis=1) - 10).max() < 1e-4
    # a square cut in four pieces, shuffled and partly reversed, ends off by 4 µm: one closed loop
    corners = np.array([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], float)
    pieces = [corners[i : i + 2].copy() for i in range(4)]
    pieces[1] = pieces[1][::-1]
    pieces[2][0] += 0.003
    pieces[3] = pieces[3][::-1]
    chains = join_paths([pieces[2], pieces[0], pieces[3], pieces[1]], tolerance=0.005)
    assert len(chains) == 1 and np.array_equal(chains[0][0], chains[0][-1]) and len(chains[0]) == 5
    assert Polygon(chains[0]).area == pytest.approx(100, abs=0.05)
    assert len(join_paths(pieces[:2] + [pieces[2] + 1.0], tolerance=0.005)) == 2


def test_centre_and_scale():
    paths = centre_and_scale([np.array([[10.0, 10], [30, 10], [30, 50]])], diameter=80)
    p = paths[0]
    assert np.allclose((p.min(axis=0) + p.max(axis=0)) / 2, 0)
    assert np.linalg.norm(p, axis=1).max() == pytest.approx(40)


def test_overlap_removal():
    disc = Point(0, 0).buffer(20, quad_segs=64)
    right = Point(25, 0).buffer(12, quad_segs=64)
    hole = Point(0, 0).buffer(8, quad_segs=64)
    loops = [np.asarray(g.exterior.coords) for g in (disc, right, hole)]
    regions = remove_overlaps(loops, "first")
    for i in range(len(regions)):
        for j in range(i + 1, len(regions)):
            assert regions[i].intersection(regions[j]).area < 1e-6
    assert unary_union(regions).area == pytest.approx(unary_union([disc, right]).area, rel=1e-9)
    assert len(regions) == 2  # the inner circle is covered by the disc drawn first
    evenodd = remove_overlaps(loops, "evenodd")
    assert not any(r.contains(Point(0, 0)) for r in evenodd)  # nested loop = hole


@pytest.mark.parametrize("angle", [0.0, 30.0, 90.0])
def test_fill_stays_inside_with_clearance(angle):
    region = Point(0, 0).buffer(20, quad_segs=64).difference(Point(5, 0).buffer(6, quad_segs=64))
    paths = scanline_fill(region, math.radians(angle), spacing=0.8, clearance=0.8, step=0.2)
    pts = np.vstack(paths)
    d = np.array([region.boundary.distance(Point(p)) for p in pts[::7]])
    assert d.min() >= 0.8 - 1e-4  # the shrunk region is a polygon: arcs within 0.1 µm
    assert all(region.contains(Point(p)) for p in pts[::7])
    for p in paths:  # no piece of a path, joints included, leaves the region
        assert region.buffer(1e-6).covers(LineString(p))
        assert np.linalg.norm(np.diff(p, axis=0), axis=1).max() <= 0.2 + 1e-9
    # scanlines are `spacing` apart: the fill covers the shrunk region's area ≈ length × spacing
    length = sum(LineString(p).length for p in paths)
    assert length * 0.8 == pytest.approx(region.buffer(-0.8).area, rel=0.05)


def test_fill_robust_to_tangents_and_self_crossing():
    # a diamond whose top and bottom vertices lie exactly on scanlines (tangent touches)
    diamond = Polygon([(0, -10.4), (10, 0), (0, 10.4), (-10, 0)])
    paths = scanline_fill(diamond, 0.0, spacing=0.8, clearance=0.0, step=0.5)
    assert all(diamond.buffer(1e-6).covers(LineString(p)) for p in paths if len(p) > 1)
    # a self-crossing bow-tie is made valid (two triangles), never filled across the gap
    bowtie = np.array([[0, 0], [20, 10], [20, 0], [0, 10], [0, 0]], float)
    regions = remove_overlaps([bowtie])
    assert sum(r.area for r in regions) == pytest.approx(100.0)
    for r in regions:
        for p in scanline_fill(r, 0.0, 0.5, 0.3, 0.2):
            assert r.buffer(1e-6).covers(LineString(p))


def test_dxf_reading_and_unsupported(tmp_path):
    make_dxf(tmp_path / "d.dxf")
    curves = read_dxf(tmp_path / "d.dxf")
    assert len(curves) == 7
    design = design_from_paths(curves, step=0.2)
    closed = [c for c in design.contours if np.array_equal(c[0], c[-1])]
    assert len(closed) == 5 and len(design.contours) == 6  # the D was joined; the open spline stays a stroke
    make_dxf(tmp_path / "t.dxf", text=True)
    with pytest.raises(CurvsliceError, match="unsupported DXF entities \\(TEXT\\)"):
        read_dxf(tmp_path / "t.dxf")
    assert len(read_dxf(tmp_path / "t.dxf", strict=False)) == 7


def heightfield_mesh(n: int = 81, size: float = 140.0) -> trimesh.Trimesh:
    """The Brooks platform triangulated on a grid (an independent mesh surface)."""
    g = np.linspace(-size / 2, size / 2, n)
    X, Y = np.meshgrid(g, g)
    Z = np.polyval(BROOKS_PLATFORM, np.hypot(X, Y))
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.vstack([np.c_[a, b, d], np.c_[a, d, c]])
    return trimesh.Trimesh(np.c_[X.ravel(), Y.ravel(), Z.ravel()], faces, process=False)


def test_projection_on_polynomial_and_mesh(tmp_path):
    make_dxf(tmp_path / "d.dxf")
    design = design_from_paths(read_dxf(tmp_path / "d.dxf"), diameter=120)
    poly = PolynomialSurface(BROOKS_PLATFORM)
    draped = drape(design, poly)
    pts = np.vstack([p.points for p in draped])
    nrm = np.vstack([p.normals for p in draped])
    r = np.hypot(pts[:, 0], pts[:, 1])
    assert np.abs(pts[:, 2] - np.polyval(BROOKS_PLATFORM, r)).max() <= 1e-6
    assert np.abs(np.linalg.norm(nrm, axis=1) - 1).max() < 1e-12
    h = 1e-5  # the normal is the gradient's normal, checked by finite differences
    gx = (np.polyval(BROOKS_PLATFORM, np.hypot(pts[:, 0] + h, pts[:, 1])) - np.polyval(BROOKS_PLATFORM, np.hypot(pts[:, 0] - h, pts[:, 1]))) / (2 * h)
    gy = (np.polyval(BROOKS_PLATFORM, np.hypot(pts[:, 0], pts[:, 1] + h)) - np.polyval(BROOKS_PLATFORM, np.hypot(pts[:, 0], pts[:, 1] - h))) / (2 * h)
    want = np.c_[-gx, -gy, np.ones(len(gx))]
    assert np.abs(nrm - want / np.linalg.norm(want, axis=1, keepdims=True)).max() < 1e-6
    kinds = [p.kind for p in draped]
    assert kinds == sorted(kinds)  # every contour before every fill
    # onto a mesh: each point lies in the plane of a triangle under it (independent brute force)
    mesh = heightfield_mesh()
    meshed = drape(design, MeshSurface(mesh))
    mp = np.vstack([p.points for p in meshed])
    mn = np.vstack([p.normals for p in meshed])
    sample = mp[:: max(1, len(mp) // 400)]
    tri = mesh.triangles
    plane_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    plane_n /= np.linalg.norm(plane_n, axis=1, keepdims=True)
    dist = np.abs(np.einsum("pfk,fk->pf", sample[:, None] - tri[None, :, 0], plane_n))
    bary_ok = _inside_xy(sample[:, :2], tri)
    assert np.where(bary_ok, dist, np.inf).min(axis=1).max() <= 1e-6
    assert np.abs(np.linalg.norm(mn, axis=1) - 1).max() < 1e-12
    _, exact = poly.project(mp[:, :2])
    assert np.degrees(np.arccos(np.clip((mn * exact).sum(axis=1), -1, 1))).max() < 1.0


def _inside_xy(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    a, b, c = tri[None, :, 0, :2], tri[None, :, 1, :2], tri[None, :, 2, :2]
    q = p[:, None]

    def cross(u, v, w):
        return (v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1]) - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0])

    s1, s2, s3 = cross(a, b, q), cross(b, c, q), cross(c, a, q)
    return ((s1 >= -1e-9) & (s2 >= -1e-9) & (s3 >= -1e-9)) | ((s1 <= 1e-9) & (s2 <= 1e-9) & (s3 <= 1e-9))


def test_mesh_outside_is_an_error():
    mesh = heightfield_mesh(n=11, size=20.0)
    with pytest.raises(CurvsliceError, match="fall outside the surface mesh"):
        MeshSurface(mesh).project(np.array([[0.0, 0.0], [30.0, 0.0]]))


def test_fill_lift_and_robot_path():
    design = design_from_paths([np.array([[0, 0], [20, 0], [20, 10], [0, 10], [0, 0]], float)], step=0.5)
    surface = load_surface("brooks")
    draped = drape(design, surface, fill_lift=0.2)
    for p in draped:
        on = surface.project(p.points[:, :2])[0]
        lift = np.einsum("ij,ij->i", p.points - on, p.normals)
        assert np.allclose(lift, 0.2 if p.kind == "fill" else 0.0, atol=1e-3)
    cell = load_cell("huygens-irb120")
    robot = draped_robot_path(draped, cell, print_speed=12.0)
    n = tool_normals(robot.quaternions, cell.orientation)
    assert np.allclose(np.linalg.norm(robot.quaternions, axis=1), 1.0)
    assert np.allclose(n[robot.extruding], np.vstack([p.normals[1:] for p in draped]))
    assert np.allclose(robot.speed[robot.extruding], 12.0)


def test_drape_cli_exports(tmp_path, monkeypatch):
    make_dxf(tmp_path / "design.dxf")
    monkeypatch.setattr(cli, "COMMANDS", ("convert", "drape"))
    out = tmp_path / "out"
    argv = ["drape", str(tmp_path / "design.dxf"), "--surface", "brooks", "--diameter", "100", "--cell", "ur5",
            "--fill-spacing", "1.6", "--to", "gcode6", "--to", "rapid", "--to", "urscript", "--out", str(out)]
    assert cli.main(argv) == 0
    data = np.load(out / "drape.npz")
    pts, nrm = data["points"], data["normals"]
    assert np.abs(pts[:, 2] - np.polyval(BROOKS_PLATFORM, np.hypot(pts[:, 0], pts[:, 1]))).max() <= 1e-6
    assert np.abs(np.linalg.norm(nrm, axis=1) - 1).max() < 1e-12
    g6 = read_gcode6(out / "design.gcode")
    printed = g6["extrusion"] > 0
    assert printed.sum() == len(pts) - len(np.unique(data["path"]))  # every segment of every path extrudes
    # the written samples are the draped points (4 decimals) with their surface normals (6 decimals)
    assert np.abs(g6["positions"][printed] - np.delete(pts, np.flatnonzero(np.diff(data["path"], prepend=-1)), axis=0)).max() <= 5e-5
    assert np.abs(g6["normals"][printed] - np.delete(nrm, np.flatnonzero(np.diff(data["path"], prepend=-1)), axis=0)).max() <= 2e-6
    rapid = read_rapid(sorted(out.glob("design_*.mod")))
    ur = read_urscript(sorted(out.glob("design_*.script")))
    assert len(rapid["positions"]) == len(ur["positions"]) == len(g6["positions"])
    assert np.abs(rapid["positions"] - g6["positions"]).max() <= 1e-3
    assert np.abs(ur["positions"] - g6["positions"]).max() <= 1e-3
