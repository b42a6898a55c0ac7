"""Bed levelling from a probe grid (seed 004, Huygens §1.2.3, §2.5): height map, Z correction, tilt.

A probe grid (CSV rows ``x,y,z``, mm, any order) must cover a rectangular lattice (spacings may
differ per axis and be non-uniform). Heights between probes are bilinear (seed 004 Eq. 1-2):
on the cell [x0, x1] × [y0, y1] with t = (x − x0)/(x1 − x0), u = (y − y0)/(y1 − y0),

    h = (1 − t)(1 − u) z00 + t(1 − u) z10 + (1 − t) u z01 + t u z11,

evaluated directly at each point — the seed instead tabulated integer coordinates into a stitched
matrix and indexed it with ``round(y − 17.5)``, which shifted rows by one and, through Python's
round-half-even, jumped between neighbours at every .5. The tilt is the exact gradient of the
same patch, turned into a unit surface normal and a normalised quaternion. The RAPID probing
routine (seed 004 Appendix 9) measures the grid with ``SearchL`` and writes the CSV itself.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from curvslice.cell.cells import quaternion_multiply, tool_quaternions
from curvslice.errors import CurvsliceError
from curvslice.robot_path import RobotPath
from curvslice.validate import check_budget, read_text


@dataclass(frozen=True)
class HeightMap:
    """Probed bed heights on a lattice: ``z[j, i]`` is the height at (``xs[i]``, ``ys[j]``), mm."""

    xs: np.ndarray  # (nx,) increasing
    ys: np.ndarray  # (ny,) increasing
    z: np.ndarray  # (ny, nx)

    def _cells(self, x: np.ndarray, y: np.ndarray, outside: str):
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        out = (x < self.xs[0]) | (x > self.xs[-1]) | (y < self.ys[0]) | (y > self.ys[-1])
        if outside == "error" and np.any(out):
            k = int(np.argmax(out.ravel()))
            raise CurvsliceError(
                f"point ({x.ravel()[k]:.3f}, {y.ravel()[k]:.3f}) lies outside the probed area "
                f"[{self.xs[0]:g}..{self.xs[-1]:g}] x [{self.ys[0]:g}..{self.ys[-1]:g}]"
            )
        xc = np.clip(x, self.xs[0], self.xs[-1])
        yc = np.clip(y, self.ys[0], self.ys[-1])
        i = np.clip(np.searchsorted(self.xs, xc, side="right") - 1, 0, len(self.xs) - 2)
        j = np.clip(np.searchsorted(self.ys, yc, side="right") - 1, 0, len(self.ys) - 2)
        wx = self.xs[i + 1] - self.xs[i]
        wy = self.ys[j + 1] - self.ys[j]
        t = (xc - self.xs[i]) / wx
        u = (yc - self.ys[j]) / wy
        corners = (self.z[j, i], self.z[j, i + 1], self.z[j + 1, i], self.z[j + 1, i + 1])
        return t, u, wx, wy, corners

    def height(self, x, y, outside: str = "clamp") -> np.ndarray:
        """Bilinear height at (x, y). Outside the probes: ``"clamp"`` to the nearest edge, or ``"error"``."""
        t, u, _, _, (z00, z10, z01, z11) = self._cells(x, y, outside)
        return (1 - t) * (1 - u) * z00 + t * (1 - u) * z10 + (1 - t) * u * z01 + t * u * z11

    def normal(self, x, y, outside: str = "clamp") -> np.ndarray:
        """Unit upward normal (…, 3) of the bilinear surface: (−∂h/∂x, −∂h/∂y, 1) normalised."""
        t, u, wx, wy, (z00, z10, z01, z11) = self._cells(x, y, outside)
        dhdx = ((1 - u) * (z10 - z00) + u * (z11 - z01)) / wx
        dhdy = ((1 - t) * (z01 - z00) + t * (z11 - z10)) / wy
        n = np.stack([-dhdx, -dhdy, np.ones_like(dhdx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


#: Probe coordinates closer than this (mm) are the same lattice line: a probing robot repeats
#: positions to about 0.01 mm, and a probed x,y carries that jitter.
LATTICE_TOLERANCE = 0.01
#: Most probe points a grid may have (a 100 x 100 grid takes hours to probe already).
MAX_PROBES = 10_000


def _lattice_lines(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct lattice coordinates (the mean of each cluster within :data:`LATTICE_TOLERANCE`) and
    the index of each value's line."""
    order = np.argsort(values, kind="stable")
    label = np.empty(len(values), np.intp)
    label[order] = np.concatenate([[0], np.cumsum(np.diff(values[order]) > LATTICE_TOLERANCE)])
    lines = np.bincount(label, weights=values) / np.bincount(label)
    return lines, label


def heightmap_from_points(points: np.ndarray, source: str = "probe grid") -> HeightMap:
    """A :class:`HeightMap` from (N, 3) probe points that cover a rectangular lattice exactly once
    (x and y within :data:`LATTICE_TOLERANCE` of their lattice line)."""
    pts = np.asarray(points, float)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.isfinite(pts).all():
        raise CurvsliceError(f"{source}: expected finite rows of x, y, z")
    check_budget(f"{source}: probe points", len(pts), MAX_PROBES, "probe a coarser grid")
    xs, xi = _lattice_lines(pts[:, 0])
    ys, yi = _lattice_lines(pts[:, 1])
    if len(xs) < 2 or len(ys) < 2:
        raise CurvsliceError(f"{source}: needs at least 2 distinct x and 2 distinct y values")
    count = np.zeros((len(ys), len(xs)), int)
    np.add.at(count, (yi.ravel(), xi.ravel()), 1)
    if np.any(count != 1):
        j, i = np.argwhere(count != 1)[0]
        what = "missing" if count[j, i] == 0 else "probed more than once"
        raise CurvsliceError(f"{source}: grid point ({xs[i]:g}, {ys[j]:g}) is {what}; probes must form a full lattice")
    z = np.empty((len(ys), len(xs)))
    z[yi.ravel(), xi.ravel()] = pts[:, 2]
    return HeightMap(xs, ys, z)


def read_probe_csv(path: str | Path) -> HeightMap:
    """Read ``x,y,z`` rows (a header line and ``#`` comments are allowed)."""
    path = Path(path)
    if not path.is_file():
        raise CurvsliceError(f"probe file {path} does not exist")
    rows = []
    for lineno, line in enumerate(read_text(path, "probe CSV").splitlines(), start=1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = [p.strip() for p in text.replace(";", ",").split(",")]
        try:
            rows.append([float(p) for p in parts])
        except ValueError:
            if rows:  # only the first line may be a header
                raise CurvsliceError(f"{path}, line {lineno}: expected numbers x,y,z, got {text!r}") from None
            continue
        if len(parts) != 3:
            raise CurvsliceError(f"{path}, line {lineno}: expected 3 values x,y,z, got {len(parts)}")
    return heightmap_from_points(np.asarray(rows, float).reshape(-1, 3), str(path))


def write_probe_csv(path: str | Path, hmap: HeightMap) -> None:
    """Write the map as ``x,y,z`` rows (the format :func:`read_probe_csv` reads)."""
    X, Y = np.meshgrid(hmap.xs, hmap.ys)
    rows = [f"{float(x)!r},{float(y)!r},{float(z)!r}" for x, y, z in zip(X.ravel(), Y.ravel(), hmap.z.ravel())]
    Path(path).write_text("x,y,z\n" + "\n".join(rows) + "\n")


def level_path(robot: RobotPath, hmap: HeightMap, *, reference: float = 0.0, tilt: bool = False,
               outside: str = "clamp") -> RobotPath:
    """Apply the bed map to a robot path: z += h(x, y) − ``reference``; with ``tilt`` the tool is
    also turned by the minimal rotation from +Z to the bed normal (seed 004 §2.5.2, Eq. 7)."""
    x, y = robot.positions[:, 0], robot.positions[:, 1]
    positions = robot.positions.copy()
    positions[:, 2] += hmap.height(x, y, outside) - reference
    quats = robot.quaternions
    if tilt:
        turn = tool_quaternions(hmap.normal(x, y, outside), (1.0, 0.0, 0.0, 0.0))
        quats = quaternion_multiply(turn, quats)
        quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    return dataclasses.replace(robot, positions=positions, quaternions=quats)
