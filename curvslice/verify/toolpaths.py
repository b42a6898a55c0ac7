"""Re-check of the tool-path stage from ``toolpaths.npz``, ``toolpaths.gcode`` and ``layers/``.

Recomputed here without the tool-path code (thesis §3.3.2 "surface covering", §3.5.2):
coverage (share of each layer's area within half a bead width of its path), overlap (share of
the area within half a bead width of two passes of the path), with each segment's bead width the
one its extrusion deposits: the stadium section ``h·(b − h) + π h²/4`` (h the segment's
thickness) of the filament volume ``E·π d²/4`` spread over the segment's length, solved for ``b``
(d from the G-code header; a path's first sample takes its first segment's width), orientation continuity (consecutive
samples of one piece within 10°), orientation validity (unit, on the unprinted side of the
layer), samples lying on their layer, printed segments following it (no chord farther than half a width from
the layer: a bead across a gap wider than itself, or through the layers below), printed beads touching the solid (a bead laid across a hole
or beside the part, its centre line more than half its width outside H: generalized winding number of ∂H
at points along every extruding segment, as the layers' check),
extrusion sanity and the G-code agreeing with the arrays.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from curvslice.verify import Check, layer_list
from curvslice.verify.layers import TOLERANCE, closest_on, winding_numbers

STAGE = "toolpaths"
COVERAGE_MIN = 0.95
OVERLAP_MAX = 0.05
CONTINUITY_MIN = 0.99
MAX_STEP_ANGLE = np.radians(10.0)
#: Spacing (path widths) of the points along printed segments tested for lying inside H.
INSIDE_SPACING = 0.5
#: Farthest (path widths) a printed segment's chord may pass from its layer, at a quarter, half and three quarters
#: of it: farther, its bead crosses a gap in the layer wider than itself, or cuts through the layers below.
CHORD_OFF = 0.5
_HEADER = re.compile(r"^;\s*(path_width|filament_diameter)\s*=\s*([-+0-9.eE]+)")
_MOVE = re.compile(r"^(G0|G1)\s")
_NUM = re.compile(r"(nX|nY|nZ|[XYZEF])([-+]?[0-9.]+)")


def _gcode_arrays(path: Path) -> tuple[dict[str, float], np.ndarray, np.ndarray, np.ndarray]:
    """Path width and filament diameter from the header, and positions, normals, E increments."""
    header, rows, e_prev = {}, [], 0.0
    state = {"X": 0.0, "Y": 0.0, "Z": 0.0, "nX": 0.0, "nY": 0.0, "nZ": 1.0, "E": 0.0}
    for line in path.read_text().splitlines():
        head = _HEADER.match(line)
        if head:
            header[head.group(1)] = float(head.group(2))
        if not _MOVE.match(line):
            continue
        state.update({k: float(v) for k, v in _NUM.findall(line.split(";")[0])})
        inc = 0.0 if line.startswith("G0") else state["E"] - e_prev
        e_prev = state["E"]
        rows.append([state[k] for k in ("X", "Y", "Z", "nX", "nY", "nZ")] + [inc])
    arr = np.asarray(rows, float).reshape(-1, 7)
    return header, arr[:, :3], arr[:, 3:6], arr[:, 6]


def _densify(positions: np.ndarray, path: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every ≤ ``spacing`` along each piece, with a key = piece offset + arclength, and
    the sample ending the segment each point lies on (a sample itself for the samples)."""
    seg = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    same = path[1:] == path[:-1]
    arclen = np.r_[0.0, np.cumsum(np.where(same, seg, 0.0))]
    key = arclen + np.cumsum(np.r_[0, ~same]) * 1e7
    n = np.where(same, np.maximum(np.ceil(seg / spacing), 1), 0).astype(int)
    i = np.repeat(np.arange(len(seg)), n)
    u = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / np.maximum(n[i], 1)
    pts = np.vstack([positions[i] + u[:, None] * (positions[i + 1] - positions[i]), positions])
    keys = np.r_[key[i] + u * (key[i + 1] - key[i]), key]
    return pts, keys, np.r_[i + 1, np.arange(len(positions))]


def bead_widths(positions: np.ndarray, path: np.ndarray, extrusion: np.ndarray, thickness: np.ndarray,
                filament_diameter: float) -> np.ndarray:
    """Bead width deposited on the segment ending at each sample, from its extrusion (stadium
    section of the segment's mean thickness); a path's first sample gets its first segment's."""
    seg = np.r_[0.0, np.linalg.norm(np.diff(positions, axis=0), axis=1)]
    h = np.r_[thickness[:1], 0.5 * (thickness[1:] + thickness[:-1])]
    with np.errstate(all="ignore"):
        area = extrusion * np.pi * filament_diameter**2 / 4 / seg
        b = (area - np.pi * h**2 / 4) / h + h
    first = np.r_[True, path[1:] != path[:-1]]
    b[first | ~(seg > 1e-9)] = np.nan
    starts = np.nonzero(first[:-1] & ~first[1:])[0]
    b[starts] = b[starts + 1]
    return b


def layer_cover(mesh: trimesh.Trimesh, positions: np.ndarray, path: np.ndarray, width: float,
                seed: int = 0, max_samples: int = 100000, bead: np.ndarray | None = None) -> tuple[float, float]:
    """(coverage, overlap) of one layer, by area-weighted random samples of the surface: one per
    0.02 w², and never fewer than 10,000, so the standard error of a share near the 5 % limits
    stays about 0.2 % even on a layer of a few mm² (500 samples gave 1 %, and decided layers by chance).

    ``bead`` is the bead width of the segment ending at each sample (default: ``width``); a
    surface sample is covered by the path points within half their bead width, and overlapped
    when those points are more than twice the larger of ``width`` and their widest bead apart
    along the path (two passes, not one bead's own breadth).
    """
    if mesh.area <= 0:
        return 1.0, 0.0
    count = int(min(max(mesh.area / (0.02 * width * width), 10000), max_samples))
    pts, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    if len(positions) == 0:
        return 0.0, 0.0
    bead = np.full(len(positions), width) if bead is None else np.where(np.isfinite(bead), np.maximum(bead, 0.0), width)
    dense, keys, sample = _densify(positions, path, 0.1 * width)
    dense_bead = bead[sample]
    pairs = cKDTree(pts).sparse_distance_matrix(cKDTree(dense), 0.5 * float(dense_bead.max()), output_type="coo_matrix")
    inside = pairs.data <= 0.5 * dense_bead[pairs.col]
    rows, cols = pairs.row[inside], pairs.col[inside]
    covered = np.zeros(count, bool)
    covered[rows] = True
    if len(rows) == 0:
        return 0.0, 0.0
    order = np.argsort(rows, kind="stable")
    r, k, b = rows[order], keys[cols[order]], dense_bead[cols[order]]
    starts = np.r_[0, np.nonzero(np.diff(r))[0] + 1]
    spread = np.maximum.reduceat(k, starts) - np.minimum.reduceat(k, starts)
    reach = 2.0 * np.maximum(np.maximum.reduceat(b, starts), width)
    return float(covered.mean()), float(np.mean(np.isin(np.arange(count), r[starts][spread > reach])))


def segments_outside(solid: trimesh.Trimesh, positions: np.ndarray, path: np.ndarray, extrusion: np.ndarray,
                     width: float, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Printed segments whose centre line leaves the solid H: points every ``INSIDE_SPACING`` widths
    along each extruding segment (:func:`_densify`; the samples themselves are checked on their layers)
    with a generalized winding number of ∂H below ½ and farther than
    :data:`~curvslice.verify.layers.TOLERANCE` voxel widths from ∂H. Returns the index of the sample
    ending each such segment and how far its farthest point lies outside (mm)."""
    if len(positions) < 2 or not len(solid.faces):
        return np.zeros(0, np.int64), np.zeros(0)
    pts, _, end = _densify(positions, path, INSIDE_SPACING * width)
    inner = np.arange(len(pts)) < len(pts) - len(positions)  # (_densify appends the samples themselves)
    keep = inner & (extrusion[end] > 0)
    pts, i = pts[keep], end[keep] - 1  # i: the sample starting each point's segment
    if not len(pts):
        return np.zeros(0, np.int64), np.zeros(0)
    doubt = winding_numbers(solid, pts) < 0.5
    off = np.zeros(len(pts))
    if doubt.any():
        off[doubt] = closest_on(solid, pts[doubt])[1]
    bad = off > TOLERANCE * voxel
    if not bad.any():
        return np.zeros(0, np.int64), np.zeros(0)
    which, first = np.unique(i[bad], return_inverse=True)
    far = np.zeros(len(which))
    np.maximum.at(far, first, off[bad])
    return which + 1, far


def checks(outdir: Path) -> list[Check] | None:
    outdir = Path(outdir)
    npz_path = outdir / "toolpaths.npz"
    if not npz_path.exists():
        return None
    data = np.load(npz_path)
    pos, nrm, layer, path = data["positions"], data["normals"], data["layer"], data["path"]
    extrusion = data["extrusion"]
    results: list[Check] = []

    def add(name: str, passed: bool, value: str, detail: str = "", layers: tuple[int, ...] = ()) -> None:
        results.append(Check(STAGE, name, bool(passed), value, detail, layers))

    gcode_path = outdir / "toolpaths.gcode"
    header: dict[str, float] = {}
    if gcode_path.exists():
        header, g_pos, g_nrm, g_ext = _gcode_arrays(gcode_path)
        same_len = len(g_pos) == len(pos)
        err = float(np.abs(g_pos - pos).max()) if same_len and len(pos) else np.inf if not same_len else 0.0
        add("gcode matches npz", same_len and err <= 1e-3 and np.allclose(g_ext, extrusion, atol=1e-5),
            f"{len(g_pos)} moves, max |Δp| {err:.1e} mm", "" if same_len else f"npz has {len(pos)} samples")
    else:
        add("gcode present", False, "missing", "toolpaths.gcode not written")
    width = header.get("path_width", 1.0)
    bead = bead_widths(pos, path, extrusion, data["thickness"], header.get("filament_diameter", 1.75))

    first = np.r_[True, path[1:] != path[:-1]]
    seg = np.r_[0.0, np.linalg.norm(np.diff(pos, axis=0), axis=1)]
    add("extrusion", bool(np.all(extrusion >= 0) and np.all(extrusion[first] == 0) and np.all(extrusion[~first & (seg > 1e-6)] > 0)),
        f"E total {extrusion.sum():.1f} mm", "E ≥ 0, 0 on travels, > 0 on printed segments")

    norm_len = np.linalg.norm(nrm, axis=1)
    same = ~first[1:]
    cosang = np.einsum("ij,ij->i", nrm[1:], nrm[:-1]) / np.maximum(norm_len[1:] * norm_len[:-1], 1e-300)
    steps = np.arccos(np.clip(cosang, -1, 1))[same]
    share = float(np.mean(steps <= MAX_STEP_ANGLE + 1e-9)) if len(steps) else 1.0
    add("orientation continuity", share >= CONTINUITY_MIN, f"{100 * share:.2f}% of steps ≤ 10°",
        f"max step {np.degrees(steps.max()) if len(steps) else 0:.1f}°")

    layer_files = sorted((outdir / "layers").glob("layer_*.ply"))
    coverage, overlap, on_surface, facing, chord_off = [], [], [], [], []
    # printed segments long enough to pass farther than CHORD_OFF from their layer (each end lies on it)
    long = np.flatnonzero(~first[1:] & (extrusion[1:] > 0) & (seg[1:] > 2.0 * CHORD_OFF * width))
    for number, lf in enumerate(layer_files, start=1):
        mesh = trimesh.load(lf, process=False, force="mesh")
        mask = layer == number
        cov, ovl = layer_cover(mesh, pos[mask], path[mask], width, seed=number, bead=bead[mask])
        coverage.append(cov)
        overlap.append(ovl)
        if mask.any() and len(mesh.faces):
            closest, dist, face = closest_on(mesh, pos[mask])
            on_surface.append(float(dist.max()))
            mine = long[layer[long] == number]
            if len(mine):
                u = np.array([0.25, 0.5, 0.75])[None, :, None]
                probe = (pos[mine, None] + u * (pos[mine + 1] - pos[mine])[:, None]).reshape(-1, 3)
                off = closest_on(mesh, probe)[1].reshape(-1, 3).max(axis=1)
                chord_off += [(float(d), number) for d in off]
            # the layer normal at the closest point, interpolated from the vertex normals (a sliver
            # triangle of the contoured layer may be flipped; the surface around it is not)
            with np.errstate(all="ignore"):
                bary = trimesh.triangles.points_to_barycentric(mesh.triangles[face], closest)
            bary[~np.isfinite(bary).all(axis=1)] = 1.0 / 3.0  # degenerate triangle: its vertices' mean
            normal = np.einsum("ij,ijk->ik", bary, mesh.vertex_normals[mesh.faces[face]])
            facing.append(np.einsum("ij,ij->i", nrm[mask], normal))
    if layer_files:
        cov = np.asarray(coverage)
        ovl = np.asarray(overlap)
        worst = int(np.argmin(cov)) + 1
        low, high = np.flatnonzero(cov < COVERAGE_MIN) + 1, np.flatnonzero(ovl > OVERLAP_MAX) + 1
        add("coverage", bool(cov.min() >= COVERAGE_MIN), f"min {100 * cov.min():.1f}% (layer {worst}), mean {100 * cov.mean():.1f}%",
            f"{len(low)} of {len(cov)} layers below {100 * COVERAGE_MIN:.0f}%" + (f": layers {layer_list(low)}" if len(low) else ""), tuple(low))
        add("overlap", bool(ovl.max() <= OVERLAP_MAX), f"max {100 * ovl.max():.1f}% (layer {int(np.argmax(ovl)) + 1}), mean {100 * ovl.mean():.1f}%",
            f"{len(high)} layers above {100 * OVERLAP_MAX:.0f}%" + (f": layers {layer_list(high)}" if len(high) else ""), tuple(high))
    else:
        add("layers present", False, "no layers/layer_*.ply", "coverage cannot be checked")
    if facing:
        dots = np.concatenate(facing)
        unit = bool(np.all(np.abs(norm_len - 1) < 1e-6))
        add("orientation validity", unit and bool(np.all(dots > 0)),
            f"{int(np.sum(dots <= 0))} samples point into printed side", "unit length, t·n > 0 with n the layer normal at the closest point")
        add("samples on layers", max(on_surface) <= 0.05 * width, f"max off-surface {max(on_surface):.3f} mm",
            "distance to the layer ≤ 5% of the path width")
        leave = [(d, number) for d, number in chord_off if d > (CHORD_OFF + 0.05) * width]
        where = np.unique([number for _, number in leave]).astype(int)
        add("printed segments follow their layer", not leave, f"{len(leave)} segments leave it",
            f"of {len(chord_off)} printed segments longer than {2 * CHORD_OFF:g} w, their chords within {CHORD_OFF:g} w "
            f"(+0.05) of the layer at ¼, ½, ¾" + (f"; max {max(leave)[0] / width:.2f} w, on layers {layer_list(where)}" if leave else ""),
            tuple(where))
    solid_path, field_path = outdir / "solid.stl", outdir / "field.npz"
    if solid_path.exists() and field_path.exists():
        with np.load(field_path) as f:
            voxel = float(f["voxel_size"])
        ends, far = segments_outside(trimesh.load(solid_path, force="mesh"), pos, path, extrusion, width, voxel)
        half = 0.5 * np.where(np.isfinite(bead[ends]), bead[ends], width)
        loose = far > half  # the centre more than half the bead outside: the whole bead lies beyond the part
        where = np.unique(layer[ends[loose]])
        add("printed segments inside H", not loose.any(), f"{int(loose.sum())} beads wholly outside H",
            (f"farthest {far[loose].max():.2f} mm outside, on layers {layer_list(where)}; " if loose.any() else "")
            + f"{int((~loose).sum())} more segments' centre lines leave H by less than half their bead"
            + (f" (max {far[~loose].max():.2f} mm)" if (~loose).any() else "")
            + f"; points every {INSIDE_SPACING:g} w along every extruding segment, inside by the winding number "
            f"or within {TOLERANCE} voxel of ∂H", tuple(where))
    return results
