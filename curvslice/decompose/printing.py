"""Printing a RoboFDM decomposition: planar layers per part, one program for the sequence (thesis §2.3.2, §2.5).

Each part is printed in planar layers parallel to its base plane, "in the same way as conventional
FDM" (§2.5), while the robot holds the platform so that the part's build direction is the
nozzle's. Nothing here is a second slicer: in the part frame P (origin at the centre of the base
cross-section, z along the build direction, the base plane at z = 0) the part is voxelized
(:func:`curvslice.voxelize.voxelize`, whose row k = 0 sits on z = 0), given the *planar* growing
field G = voxel row + 1, and the working-surface stage (:func:`extract_working_surfaces`) turns G
into flat layers z = l·h trimmed by the part (on a grid half the voxel where the voxel's keeps too
little of a thin section: :func:`print_part`); the tool-path stage (:func:`plan_toolpaths`) plans
them, standing layer 1 on z = 0 -- the platform for the root, the parent's cut face otherwise.
The nozzle axis is the build direction on every sample (a planar part needs no tilt). Samples
and layers are then mapped into the platform frame E (origin at the centre of the root's base,
z along the root's build direction) by the part's pose T_P^E of Eq. 2.3, so that one tool-path
file, in printing order, drives the whole sequence; T_E^B follows from the fixed nozzle pose T_N^B
when the robot is planned on it.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import trimesh

from curvslice.decompose.constraints import platform_clearance
from curvslice.decompose.parts import plane_frame
from curvslice.toolpaths import ToolpathSettings, Toolpaths, plan_toolpaths, save_toolpaths
from curvslice.voxelize import voxelize
from curvslice.working_surfaces import extract_working_surfaces, write_layers
from curvslice.workcell import load_workcell

#: A part's planar layers must keep this share of every exact plane section, else they are contoured
#: on a grid twice as fine (:func:`print_part`). Measured on the bunny at 2 mm (10 parts): the least
#: kept per part is 0.75-0.99 on eight parts, 0.35 and 0.50 on the two whose one-vertex islands left
#: their top layers uncovered (89.5 %); the whole print keeps 99.5 % of the section area. A thin top
#: on the grid's axes is kept (a 1 mm strip along x: 0.9).
SECTION_KEPT = 0.6


@dataclass
class PartPrint:
    """One part's planar layers and tool-paths in its own frame P, and its pose T_P^E."""

    sequence: int
    pose: np.ndarray  # T_P^E (4x4)
    layers: list[trimesh.Trimesh]
    toolpaths: Toolpaths
    seconds: dict[str, float]
    contour_mm: float  # grid the layers were contoured on (the voxel, or half of it: print_part)


def planar_layers(mesh: trimesh.Trimesh, voxel: float, layer_height: float) -> list[trimesh.Trimesh]:
    """Flat layers z = l·``layer_height`` of a solid standing on z = 0, by the working-surface stage on
    the planar growing field G = voxel row + 1 (the layer index of conventional slicing; a top layer
    the part does not reach is lowered by the stage's fallback). G is linear in z, but its
    continuation past the voxels and the trimming by the solid leave boundary vertices up to a fifth
    of a voxel off the plane: every vertex is put back on its layer's plane z = (g - ½)·w."""
    grid = voxelize(mesh, voxel)
    rows = np.arange(1, grid.shape[2] + 1, dtype=np.int32)
    growing = np.where(grid.occupied, rows[None, None, :], 0).astype(np.int32)
    layers = extract_working_surfaces(growing, grid.origin, voxel, mesh, layer_height=layer_height,
                                      occupied=grid.occupied)
    for m in layers:
        m.vertices[:, 2] = (m.metadata["isovalue"] - 0.5) * voxel
    return layers


def section_kept(mesh: trimesh.Trimesh, layers: list[trimesh.Trimesh]) -> float:
    """The smallest share of the exact plane section of ``mesh`` (in P) that a planar layer covers: the
    layers are contoured on the voxel grid and trimmed by the solid between grid vertices, so where a
    section is narrower than about two voxels (a part's thin top) only the stars of the grid vertices
    inside it are kept (bunny at 2 mm, part 6's top layer: 6.7 of 13.5 mm², three one-vertex islands)."""
    kept = 1.0
    for m in layers:
        section = mesh.section([0.0, 0.0, 1.0], [0.0, 0.0, float(m.vertices[:, 2].mean())])
        exact = section.to_2D()[0].area if section is not None else 0.0
        if exact > 0:
            kept = min(kept, float(m.area) / exact)
    return kept


def print_part(mesh_in_p: trimesh.Trimesh, pose: np.ndarray, sequence: int, voxel: float, layer_height: float,
               settings: ToolpathSettings) -> PartPrint:
    """Planar layers and tool-paths of one part given in its frame P (base plane z = 0). A part whose
    layers keep less than :data:`SECTION_KEPT` of some exact section (:func:`section_kept`) is contoured
    again on a grid half the voxel (the layer height unchanged): a one-vertex island has no inside for
    the tool-path stage's boundary distance, and gets no pass (bunny 2 mm: 89.5 % coverage)."""
    t0 = time.perf_counter()
    contour = voxel
    layers = [m for m in planar_layers(mesh_in_p, voxel, layer_height) if len(m.faces)]
    if section_kept(mesh_in_p, layers) < SECTION_KEPT:
        contour = voxel / 2
        layers = [m for m in planar_layers(mesh_in_p, contour, layer_height) if len(m.faces)]
    t1 = time.perf_counter()
    tp = plan_toolpaths(layers, settings)
    tp.normals = np.tile([0.0, 0.0, 1.0], (len(tp.positions), 1))  # planar FDM: the nozzle along the build direction
    return PartPrint(sequence, pose, layers, tp, {"layers": t1 - t0, "toolpaths": time.perf_counter() - t1}, contour)


def in_platform_frame(prints: list[PartPrint], settings: ToolpathSettings) -> tuple[list[trimesh.Trimesh], Toolpaths,
                                                                                   np.ndarray]:
    """All parts' layers and samples in the platform frame E, in printing order: layers numbered on
    across the sequence, path ids kept distinct; also each sample's part (sequence number)."""
    layers, arrays, part, rows, layer_base, path_base = [], [], [], [], 0, 0
    for pp in prints:
        rows += [row | {"layer": int(row["layer"]) + layer_base, "part": pp.sequence} for row in pp.toolpaths.layers]
        T, tp = pp.pose, pp.toolpaths
        for m in pp.layers:
            moved = m.copy()
            moved.apply_transform(T)
            moved.metadata.update(m.metadata, part=pp.sequence)
            layers.append(moved)
        arrays.append(replace(tp, positions=tp.positions @ T[:3, :3].T + T[:3, 3], normals=tp.normals @ T[:3, :3].T,
                              layer=tp.layer + layer_base, path=tp.path + path_base))
        part.append(np.full(len(tp.positions), pp.sequence, np.int32))
        layer_base += len(pp.layers)
        path_base += int(tp.path.max()) + 1 if len(tp.path) else 0
    cat = {k: np.concatenate([getattr(a, k) for a in arrays]) for k in
           ("positions", "normals", "layer", "path", "extrusion", "thickness", "feed", "bead")}
    seconds = {s: sum(pp.toolpaths.seconds[s] for pp in prints) for s in ("spirals", "orientation")}
    return layers, Toolpaths(**cat, layers=rows, seconds=seconds), np.concatenate(part)


def print_decomposition(folder: Path, voxel: float = 1.0, layer_height: float | None = None,
                        path_width: float | None = None, meshes: list[trimesh.Trimesh] | None = None,
                        workcell: str = "ur3") -> dict:
    """Plan every part of a ``curvslice decompose`` folder (``parts.json``) and write ``layers/``,
    ``toolpaths.npz`` (plus ``part`` per sample) and ``toolpaths.gcode`` for the whole sequence in
    the platform frame E; adds the sections ``layers`` and ``toolpaths`` (and those stages) to the
    folder's ``report.json`` and returns them. ``meshes`` are
    the parts in printing order as cut (closed by construction); by default they are read from the
    folder's STL files, where a part touching itself may come back with non-manifold edges. Each
    part's lowest sample over the platform is reported beside the :func:`platform_clearance` its
    tilt needs in ``workcell`` (the thesis's UR3 cell by default)."""
    folder = Path(folder)
    spec = json.loads((folder / "parts.json").read_text())
    h = layer_height or voxel
    settings = ToolpathSettings(path_width=path_width or voxel / 0.8)
    root = spec["parts"][0]
    root_frame = plane_frame(np.asarray(root["build_direction"], float), np.asarray(root["base_centre_mm"], float))
    prints = []
    for k, p in enumerate(spec["parts"]):
        P = plane_frame(np.asarray(p["build_direction"], float), np.asarray(p["base_centre_mm"], float))
        pose = np.asarray(p["T_P_E"], float)
        assert np.allclose(np.linalg.inv(root_frame) @ P, pose, atol=1e-6), "T_P_E must map P into E (Eq. 2.3)"
        mesh = meshes[k].copy() if meshes is not None else trimesh.load(folder / p["file"], force="mesh")
        mesh.apply_transform(np.linalg.inv(P))
        mesh.vertices[:, 2] = np.maximum(mesh.vertices[:, 2], 0.0)  # the cut's round-off below z = 0
        prints.append(print_part(mesh, pose, p["sequence"], voxel, h, settings))
    layers, tp, part = in_platform_frame(prints, settings)
    write_layers(folder, layers)
    save_toolpaths(folder, tp, settings)
    with np.load(folder / "toolpaths.npz") as z:
        arrays = {k: z[k] for k in z.files}
    np.savez_compressed(folder / "toolpaths.npz", **arrays, part=part)
    cell = load_workcell(workcell)
    per_part = []
    for pp in prints:
        tilt = float(np.arccos(np.clip(pp.pose[2, 2], -1.0, 1.0)))
        lowest = tp.positions[part == pp.sequence, 2]
        per_part.append({"part": pp.sequence, "layers": len(pp.layers), "samples": len(pp.toolpaths.positions),
                         "pieces": int(len(np.unique(pp.toolpaths.path))), "tilt_deg": round(np.degrees(tilt), 2), "contour_mm": pp.contour_mm,
                         "lowest_sample_mm": round(float(lowest.min()), 3) if len(lowest) else None,
                         "clearance_mm": round(platform_clearance(cell, tilt), 3),
                         "layers_s": round(pp.seconds["layers"], 3), "toolpaths_s": round(pp.seconds["toolpaths"], 3)})
    blocked = [q["part"] for q in per_part if q["lowest_sample_mm"] is not None and q["lowest_sample_mm"] < q["clearance_mm"]]
    sections = {
        "layers": {"count": len(layers), "layer_height_mm": h, "voxel_mm": voxel, "planar": True,
                   "per_part": [q["layers"] for q in per_part],
                   "timings_s": {"layers": round(sum(q["layers_s"] for q in per_part), 3)}},
        "toolpaths": {"path_width_mm": settings.path_width, "samples": len(tp.positions),
                      "pieces": int(len(np.unique(tp.path))), "filament_mm": round(float(tp.extrusion.sum()), 3),
                      "per_part": per_part, "per_layer": tp.layers, "workcell": cell.name,
                      "platform_clearance_short": blocked,
                      "spirals_s": round(tp.seconds["spirals"], 3), "orientation_s": round(tp.seconds["orientation"], 3),
                      "timings_s": {"toolpaths": round(sum(q["toolpaths_s"] for q in per_part), 3)}},
    }
    report = json.loads((folder / "report.json").read_text())
    report.update(sections, stages=["layers", "toolpaths"])
    (folder / "report.json").write_text(json.dumps(report, indent=1))
    return sections


def plan_robot(folder: Path, robot: str, quiet: bool = True, parts: list[int] | None = None) -> dict:
    """The robot stage of `curvslice slice` (:func:`curvslice.pipeline.run_robot`) on a printed
    decomposition folder: one joint trajectory and one program for the whole sequence, each layer
    checked against the workcell's platform and the layers printed before it (all parts in the platform
    frame E, where the platform top is z = 0). ``parts`` (sequence numbers) plans only those
    parts' samples -- every earlier layer still an obstacle -- and the files index the full
    ``toolpaths.npz``, so the verifier counts the other parts' samples as not realized. Writes
    ``joints.csv``, ``workcell.json`` and the controller programs, adds the ``robot`` section (with
    ``parts_planned``) and stage to ``report.json`` and returns it."""
    from curvslice.pipeline import (Context, FieldResult, LayersResult, Settings, ToolpathsResult, load_toolpaths,
                                    run_robot, save_robot)
    from curvslice.working_surfaces import load_layers

    folder = Path(folder)
    report = json.loads((folder / "report.json").read_text())
    spec = json.loads((folder / "parts.json").read_text())
    root = spec["parts"][0]
    solid = trimesh.load(folder / "solid.stl", force="mesh")
    solid.apply_transform(np.linalg.inv(plane_frame(np.asarray(root["build_direction"], float),
                                                    np.asarray(root["base_centre_mm"], float))))
    settings = Settings(robot=robot, voxel=float(report["layers"]["voxel_mm"]))
    full = load_toolpaths(folder, report["toolpaths"])
    with np.load(folder / "toolpaths.npz") as z:
        part = z["part"]
    planned = sorted(set(part.tolist())) if parts is None else sorted(set(parts))
    rows = np.flatnonzero(np.isin(part, planned))
    tp = replace(full, **{k: getattr(full, k)[rows] for k in
                          ("positions", "normals", "layer", "path", "extrusion", "thickness", "feed", "bead")})
    # the workcell's own platform disc (no platform_vertices), the one `curvslice verify` checks a folder without field.npz
    results = {"field": FieldResult(solid, None, None, None, None, {}),
               "layers": LayersResult(load_layers(folder), report["layers"]),
               "toolpaths": ToolpathsResult(tp, ToolpathSettings(path_width=report["toolpaths"]["path_width_mm"]), {})}
    robot_result = run_robot(Context(solid, settings, results, quiet=quiet))
    motion = robot_result.motion
    motion.index = rows[motion.index]  # back to the rows of the folder's toolpaths.npz
    for layer in motion.layers:
        for entry in layer["skipped_rows"]:
            entry["row"] = int(rows[entry["row"]])
    results["toolpaths"] = ToolpathsResult(full, results["toolpaths"].settings, {})
    save_robot(robot_result, folder, settings, results)
    robot_result.report.update(parts_planned=planned, waypoints_all_parts=len(part))
    report["robot"] = robot_result.report
    report["stages"] = [*report.get("stages", []), "robot"]
    (folder / "report.json").write_text(json.dumps(report, indent=1))
    return robot_result.report
