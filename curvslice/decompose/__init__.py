"""RoboFDM: decomposition of a model into planar, support-free parts printed in sequence (thesis ch. 2).

:func:`decompose` runs the three phases of §2.4 on an *analysis copy* of the model (simplified by
manifold3d to about the thesis's 10k facets, with one Laplacian smoothing step for the shape
analysis), records every plane cut, and replays the cuts exactly on the full-resolution model, so
the parts are cut from the full mesh and their union is the model. :func:`write_decomposition`
writes the output folder (one mesh per part, ``parts.json`` and ``report.json``).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
import trimesh

from curvslice.decompose.constraints import constraint_one, faces_up
from curvslice.decompose.fine_tuning import (Settings, coarse_parts, fine_decomposition, merge_regions, part_risk,
                                              replay)
from curvslice.decompose.parts import Plane, cross_section, part_pose, plane_frame, to_manifold, to_trimesh
from curvslice.decompose.preview import plot_parts
from curvslice.decompose.risky import (FIRST_LAYER_MM, PLATFORM_CONTACT_MM, SUPPORT_FREE_MM2, UNDERSIDE_MM,
                                      lowest_plane, platform_layer_mask, risky_faces, underside_mask)
from curvslice.decompose.sequence import breadth_first_order, extruder_aware_order, plan_sequence
from curvslice.decompose.shape_analysis import coarse_decomposition


@dataclass
class Part:
    """One part of the decomposition (full resolution)."""

    index: int
    mesh: trimesh.Trimesh
    base: Plane  # base plane; build direction = base.normal
    parent: int | None
    section: shapely.MultiPolygon
    risky_area: float  # mm², Eq. 2.1 beyond the base plane and the platform's first layer
    base_centre: np.ndarray
    risky_area_analysis: float = 0.0  # the same on the analysis copy the search ran on
    risky_underside: float = 0.0  # mm², the part of risky_area on the model's underside (UNDERSIDE_MM)


@dataclass
class Decomposition:
    parts: list[Part]  # in printing sequence (parents before children)
    root_direction: np.ndarray
    alpha_max: float
    coarse_patches: int
    k: int
    timings: dict[str, float] = field(default_factory=dict)
    analysis_faces: int = 0
    model_volume: float = 0.0
    workcell: str | None = None  # whose extruder every part clears the platform with (Settings.workcell)
    #: per part in sequence: nozzle positions (of those sampled) where the extruder meets earlier parts
    extruder_blocked: list[tuple[int, int]] = field(default_factory=list)
    #: layer height the parts were cut for (Settings.layer_height): the platform's first layer
    layer_height: float = 1.0

    def constraint_one_violations(self) -> list[tuple[int, int]]:
        pairs = constraint_one([p.base for p in self.parts], [p.section for p in self.parts])
        return [(self.parts[i].index, self.parts[j].index) for i, j in pairs]

    def constraint_two_violations(self) -> list[int]:
        return [p.index for p in self.parts[1:] if not faces_up(p.base.normal, self.root_direction)]


def analysis_copy(mesh: trimesh.Trimesh, tolerance: float) -> trimesh.Trimesh:
    """The model simplified by manifold3d within ``tolerance`` mm (a subset of its vertices)."""
    out = to_trimesh(to_manifold(mesh).simplify(tolerance))
    out.merge_vertices()
    return out


def decompose(mesh: trimesh.Trimesh, alpha_max_deg: float = 45.0, root: int | None = None,
              analysis_tolerance: float = 0.3, settings: Settings | None = None) -> Decomposition:
    """Phases I-III of §2.4 on an analysis copy, then the cuts replayed on ``mesh``."""
    s = settings or Settings()
    s.alpha_max = np.radians(alpha_max_deg)
    t = {"start": time.perf_counter()}
    full = to_manifold(mesh)
    simple = analysis_copy(mesh, analysis_tolerance)
    smooth = simple.copy()
    trimesh.smoothing.filter_laplacian(smooth, iterations=1)  # §2.4.1: one Laplacian step
    t["analysis_copy"] = time.perf_counter()
    coarse = coarse_decomposition(smooth)
    coarse.mesh = simple  # same faces: labels and planes carry over to the unsmoothed copy
    t["phase1"] = time.perf_counter()
    seq = plan_sequence(coarse, s.alpha_max, root)
    t["phase2"] = time.perf_counter()
    solid = to_manifold(simple)
    pieces, cuts = coarse_parts(solid, coarse, seq, s)
    cuts = merge_regions(pieces, cuts, seq.order, s)
    cuts = fine_decomposition(pieces, cuts, seq.root_direction, solid.volume(), s)
    t["phase3"] = time.perf_counter()
    solids = replay(full, seq.root, cuts)
    parts = []
    for i, sol in solids.items():
        m = to_trimesh(sol)
        base = lowest_plane(m.vertices, seq.root_direction) if i == seq.root else next(c.plane for c in cuts if c.new == i)
        root = i == seq.root
        sec = cross_section(sol, base, PLATFORM_CONTACT_MM if root else 1e-3)
        centre = base.frame() @ np.r_[np.asarray(sec.centroid.coords[0]) if not sec.is_empty else np.zeros(2), 0, 1]
        parts.append(Part(i, m, base, pieces[i].parent, sec, 0.0, centre[:3], part_risk(pieces[i], s.alpha_max)))
    platform = min(float((p.mesh.vertices @ seq.root_direction).min()) for p in parts)
    for p in parts:  # faces within the platform's first layer are printed on it, whichever part they are in
        risky = risky_faces(p.mesh, p.base, s.alpha_max) & ~platform_layer_mask(p.mesh, seq.root_direction, platform,
                                                                                s.layer_height)
        p.risky_area = float(p.mesh.area_faces[risky].sum())
        p.risky_underside = float(p.mesh.area_faces[risky & underside_mask(p.mesh, seq.root_direction, platform)].sum())
    t["replay"] = time.perf_counter()
    parent = {p.index: p.parent for p in parts}
    blocked: dict[int, tuple[int, int]] = {}
    if s.workcell is None:
        order = breadth_first_order(seq.root, parent)
    else:
        from curvslice.workcell import load_workcell

        order, blocked = extruder_aware_order(seq.root, parent, {p.index: p.mesh for p in parts},
                                              {p.index: p.base.normal for p in parts}, load_workcell(s.workcell))
    t["order"] = time.perf_counter()
    parts.sort(key=lambda p: order.index(p.index))
    names = ["analysis_copy", "phase1", "phase2", "phase3", "replay", "order"]
    prev = t["start"]
    timings = {}
    for n in names:
        timings[n] = t[n] - prev
        prev = t[n]
    timings["total"] = t["order"] - t["start"]
    return Decomposition(parts, seq.root_direction, s.alpha_max, len(coarse.areas), coarse.k, timings, len(simple.faces),
                         float(full.volume()), s.workcell, [blocked[p.index] for p in parts] if blocked else [],
                         s.layer_height)


def write_decomposition(dec: Decomposition, folder: Path, source: str, model: trimesh.Trimesh) -> dict:
    """``part_XX.stl`` per part, ``parts.json`` (planes, directions, sequence, poses, risky areas),
    the placed input ``solid.stl`` (for ``curvslice verify``), ``parts.png`` and ``report.json``;
    returns the report."""
    folder = Path(folder)
    model.export(folder / "solid.stl")
    root_frame = plane_frame(dec.root_direction, dec.parts[0].base_centre)
    parts = []
    for seq_no, p in enumerate(dec.parts):
        name = f"part_{seq_no:02d}.stl"
        p.mesh.export(folder / name)
        parts.append({
            "file": name,
            "id": p.index,
            "sequence": seq_no,
            "parent": next((k for k, q in enumerate(dec.parts) if q.index == p.parent), None),
            "base_plane": {"normal": p.base.normal.tolist(), "offset_mm": p.base.offset},
            "build_direction": p.base.normal.tolist(),
            "base_centre_mm": p.base_centre.tolist(),
            "base_section_area_mm2": float(p.section.area),
            "volume_mm3": float(p.mesh.volume),
            "risky_area_mm2": p.risky_area,
            "risky_area_analysis_mm2": p.risky_area_analysis,
            "risky_underside_mm2": p.risky_underside,
            "support_free": p.risky_area <= SUPPORT_FREE_MM2,
            "T_P_E": part_pose(p.base, p.base_centre, root_frame).tolist(),
        })
    one, two = dec.constraint_one_violations(), dec.constraint_two_violations()
    report = {
        "stage": "decompose",
        "source": source,
        "alpha_max_deg": float(np.degrees(dec.alpha_max)),
        "platform_clearance_workcell": dec.workcell,
        "extruder_blocked_positions": [list(b) for b in dec.extruder_blocked],
        "root_direction": dec.root_direction.tolist(),
        "parts": len(parts),
        "coarse_patches": dec.coarse_patches,
        "gaussians": dec.k,
        "analysis_faces": dec.analysis_faces,
        "risky_area_mm2": [q["risky_area_mm2"] for q in parts],
        "risky_area_analysis_mm2": [q["risky_area_analysis_mm2"] for q in parts],
        "risky_underside_mm2": [q["risky_underside_mm2"] for q in parts],
        "underside_mm": UNDERSIDE_MM,
        "platform_layer_mm": dec.layer_height,
        "support_free_mm2": SUPPORT_FREE_MM2,
        "support_free_parts": [q["sequence"] for q in parts if q["support_free"]],
        "constraint_one_violations": [list(v) for v in one],
        "constraint_two_violations": two,
        "volume_model_mm3": dec.model_volume,
        "volume_parts_mm3": float(sum(q["volume_mm3"] for q in parts)),
        "timings_s": dec.timings,
    }
    (folder / "parts.json").write_text(json.dumps({"root_direction": dec.root_direction.tolist(),
                                                   "alpha_max_deg": report["alpha_max_deg"],
                                                   "first_layer_mm": FIRST_LAYER_MM, "underside_mm": UNDERSIDE_MM,
                                                   "platform_layer_mm": dec.layer_height,
                                                   "support_free_mm2": SUPPORT_FREE_MM2, "parts": parts}, indent=1))
    (folder / "report.json").write_text(json.dumps(report, indent=1))
    plot_parts(dec.parts, folder / "parts.png", f"{Path(source).stem}: {len(parts)} parts, sequence 0..{len(parts) - 1}")
    return report
