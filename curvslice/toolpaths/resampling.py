"""Re-sampling of passes at the path step (thesis §3.5.2) and extrusion per segment (volume
conservation, :func:`curvslice.flow.filament_length`)."""

from __future__ import annotations

import numpy as np

from curvslice.flow import filament_length
from curvslice.toolpaths.constants import CORNER_ANGLE
from curvslice.toolpaths.stacked import run_labels, run_offsets


def resample(polyline: np.ndarray, step: float, value_weight: float = 0.0, turn_weight: float = 0.0) -> np.ndarray:
    """Uniform re-sampling at spacing ≤ ``step`` (thesis §3.5.2: 1 mm) keeping sharp corners.

    Columns after the first three (x, y, z) are per-vertex values interpolated along the way.
    With ``value_weight`` > 0 the spacing is uniform in ``√(ds² + (value_weight·dv)²)`` instead of
    the arclength ``ds``, so where a value (a bead width) changes, samples come closer and its
    profile survives the linear interpolation between them. ``turn_weight`` adds that much length
    per radian the path turns (below the kept corners), so bends keep their samples."""
    p = np.asarray(polyline, np.float64)
    seg = np.linalg.norm(np.diff(p[:, :3], axis=0), axis=1)
    p = p[np.r_[True, seg > 1e-9]]
    if len(p) < 2:
        return p[:1].copy()
    d = np.diff(p[:, :3], axis=0)
    u = d / np.linalg.norm(d, axis=1, keepdims=True)
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", u[:-1], u[1:]), -1, 1))
    keep = np.r_[0, np.nonzero(turn > CORNER_ANGLE)[0] + 1, len(p) - 1]
    bend = np.r_[0.0, np.where(turn > CORNER_ANGLE, 0.0, turn), 0.0]
    cum = np.r_[0.0, np.cumsum(np.linalg.norm(np.c_[d, value_weight * np.diff(p[:, 3:], axis=0)], axis=1)
                               + turn_weight * 0.5 * (bend[:-1] + bend[1:]))]
    # every run between kept corners in n equal steps (the corners themselves are knots of cum)
    start, span = cum[keep[:-1]], cum[keep[1:]] - cum[keep[:-1]]
    n = np.maximum(np.ceil(span / step - 1e-9), 1).astype(np.int64)
    run = run_labels(n)
    s = np.r_[start[run] + span[run] * run_offsets(n) / n[run], cum[-1]]
    return np.column_stack([np.interp(s, cum, p[:, i]) for i in range(p.shape[1])])


def extrusion_amounts(positions: np.ndarray, path_id: np.ndarray, thickness: np.ndarray, width,
                      filament_diameter: float) -> np.ndarray:
    """Filament length per segment (0 at each piece's first sample), thickness and bead width
    (a number or one per sample) averaged on it; a bead is never narrower than it is high."""
    pos = np.asarray(positions, np.float64)
    seg = np.r_[0.0, np.linalg.norm(np.diff(pos, axis=0), axis=1)]
    h = np.r_[thickness[0], 0.5 * (thickness[1:] + thickness[:-1])]
    b = np.broadcast_to(np.asarray(width, np.float64), h.shape)
    b = np.r_[b[0], 0.5 * (b[1:] + b[:-1])]
    e = filament_length(seg, np.maximum(b, h), h, filament_diameter)
    first = np.r_[True, path_id[1:] != path_id[:-1]]
    e[first] = 0.0
    return e

