"""Re-check of a RoboFDM decomposition folder (thesis ch. 2) from its files alone.

- the parts' union equals the model (``solid.stl``) within 0.1 % of its volume, and the parts do
  not overlap (their volumes add up to the union's);
- each part's risky area (Eq. 2.1, faces within the first layer above the base plane excluded,
  ``first_layer_mm`` of parts.json, and faces within one layer over the platform, where the first
  layer is deposited on it, ``platform_layer_mm``) recomputed from its mesh equals the reported
  one, so does its share on the model's underside (faces reaching no higher than ``underside_mm``
  over the lowest point of all parts), and whether every part is support-free (risky area ≤
  :data:`SUPPORT_FREE_MM2`) or its remainder is reported (the acceptance of issue 17: "risky area 0
  beyond its base plane, or the remainder reported per part"): a part whose report claims less
  than its recomputed area fails, and the check lists the remainder per part;
- Constraint I: the base faces (faces of a part on its base plane) of two parts never cross on a
  stretch of the planes' common line — found by cutting each base face's triangles with the other
  plane (trimesh), not by the polygon code that made the decomposition; sections that merely end
  on each other's plane (cuts meeting at a junction) touch without crossing;
- Constraint II: every base plane faces up along the root's build direction;
- when the parts were printed (``layers/``, ``toolpaths.npz`` with ``part``): every layer is planar,
  parallel to its part's base plane at a multiple of the layer height above it and inside its part,
  the layers of each part follow each other in the sequence, and every sample's nozzle axis is its
  part's build direction (coverage, overlap and the G-code are re-checked by ``verify.toolpaths``).
"""

from __future__ import annotations

import json
from pathlib import Path

import manifold3d
import numpy as np
import trimesh

from curvslice.decompose.parts import plane_frame  # the frame convention of parts.json's T_P_E
from curvslice.verify import Check

STAGE = "decompose"
VOLUME_TOL = 1e-3
SUPPORT_FREE_MM2 = 1.0
ROOT_CONTACT_MM = 0.5  # the root's faces this close to its platform plane stand on the platform
LINE_TOL = 0.1  # mm of shared common line that counts as an intersection
SIDE_MM = 0.05  # a section crosses a plane when it reaches this far past it on both sides


def _base_faces(mesh: trimesh.Trimesh, normal: np.ndarray, offset: float, root: bool) -> np.ndarray:
    h = mesh.vertices @ normal - offset
    near = np.all(np.abs(h[mesh.faces]) <= (ROOT_CONTACT_MM if root else 1e-2), axis=1)
    return near if root else near & (mesh.face_normals @ normal < -0.999)


def _overlap(a: list[tuple[float, float]], b: list[tuple[float, float]]) -> list[tuple[float, float]]:
    return [(max(a0, b0), min(a1, b1)) for a0, a1 in a for b0, b1 in b if min(a1, b1) > max(a0, b0)]


def _intervals(mesh: trimesh.Trimesh, faces: np.ndarray, n: np.ndarray, c: float, point: np.ndarray,
               direction: np.ndarray) -> list[tuple[float, float]]:
    """Parameter intervals along the common line where the base faces ``faces`` extend to both sides
    of the other plane (``n·x = c`` moved by ±:data:`SIDE_MM`): a section that only ends on the other
    plane — two cuts meeting at a junction — touches it but does not cross it."""
    return _overlap(_cut(mesh, faces, n, c + SIDE_MM, point, direction), _cut(mesh, faces, n, c - SIDE_MM, point, direction))


def _cut(mesh: trimesh.Trimesh, faces: np.ndarray, n: np.ndarray, c: float, point: np.ndarray,
         direction: np.ndarray) -> list[tuple[float, float]]:
    if not faces.any():
        return []
    sub = mesh.submesh([np.flatnonzero(faces)], append=True)
    segs = trimesh.intersections.mesh_plane(sub, n, n * c)
    if len(segs) == 0:
        return []
    t = np.sort((segs - point) @ direction, axis=1)
    t = t[np.argsort(t[:, 0])]
    out: list[list[float]] = []
    for a, b in t:
        if out and a <= out[-1][1] + 1e-6:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def checks(outdir: Path) -> list[Check] | None:
    outdir = Path(outdir)
    if not (outdir / "parts.json").exists():
        return None
    spec = json.loads((outdir / "parts.json").read_text())
    alpha = np.radians(spec["alpha_max_deg"])
    first_layer = float(spec.get("first_layer_mm", ROOT_CONTACT_MM))
    root_dir = np.asarray(spec["root_direction"], float)
    parts = spec["parts"]
    meshes = [trimesh.load(outdir / p["file"], force="mesh") for p in parts]
    results: list[Check] = []
    if (outdir / "solid.stl").exists():
        model = trimesh.load(outdir / "solid.stl", force="mesh")
        solids = [manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(m.vertices, np.float32),
                                                      tri_verts=np.asarray(m.faces, np.uint32))) for m in meshes]
        union = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add).volume()
        total = sum(s.volume() for s in solids)
        err = abs(union - model.volume) / model.volume
        results.append(Check(STAGE, "union equals model", err <= VOLUME_TOL, f"{100 * err:.4f} %",
                             f"union {union:.1f} mm³ vs model {model.volume:.1f} mm³"))
        over = (total - union) / model.volume
        results.append(Check(STAGE, "parts do not overlap", over <= VOLUME_TOL, f"{100 * over:.4f} %"))
    else:
        results.append(Check(STAGE, "union equals model", False, "missing", "solid.stl is not in the folder"))
    risky, under, mismatch = [], [], []
    underside = spec.get("underside_mm")
    platform_layer = float(spec.get("platform_layer_mm", 0.0))
    low = min(float((m.vertices @ root_dir).min()) for m in meshes)
    for k, (p, m) in enumerate(zip(parts, meshes)):
        n, c = np.asarray(p["base_plane"]["normal"], float), float(p["base_plane"]["offset_mm"])
        first = np.all(np.abs((m.vertices @ n - c)[m.faces]) <= first_layer, axis=1)
        on_platform = (m.vertices @ root_dir - low)[m.faces].max(axis=1) <= platform_layer
        bad = (m.face_normals @ n + np.sin(alpha) < 0) & ~first & ~on_platform
        area = float(m.area_faces[bad].sum())
        risky.append(area)
        wrong = abs(area - p["risky_area_mm2"]) > 1e-3 * max(1.0, area)
        if underside is not None:  # the share on the model's underside, faces no higher than underside_mm
            low_face = (m.vertices @ root_dir - low)[m.faces].max(axis=1) <= underside
            under.append(float(m.area_faces[bad & low_face].sum()))
            told = p.get("risky_underside_mm2")
            wrong |= told is None or abs(under[-1] - told) > 1e-3 * max(1.0, under[-1])
        if wrong:
            mismatch.append(k)
    results.append(Check(STAGE, "risky area per part", not mismatch, ", ".join(f"{a:.1f}" for a in risky) + " mm²",
                         f"reported differs for parts {mismatch}" if mismatch else "recomputed = reported"))
    # support-free, or the remainder reported: a part may hang only as much as parts.json says
    claimed = [float(p.get("risky_area_mm2", 0.0)) for p in parts]
    understated = [k for k, (a, r) in enumerate(zip(risky, claimed))
                   if a > SUPPORT_FREE_MM2 and r < a - 1e-3 * max(1.0, a)]
    remainder = [k for k, a in enumerate(risky) if a > SUPPORT_FREE_MM2]
    where = [f"part {k}: {risky[k]:.1f}" + (f" ({under[k]:.1f} underside, {risky[k] - under[k]:.1f} elsewhere)"
                                            if under else "") for k in remainder]
    value = (f"{len(risky) - len(remainder)} of {len(risky)} free; remainder (mm²) " + "; ".join(where)
             if remainder else f"all {len(risky)} free")
    floor = (f"; faces within {platform_layer:g} mm of the platform stand on it, underside = "
             f"≤ {underside:g} mm over it") if under else ""
    results.append(Check(STAGE, "every part support-free or remainder reported", not understated, value,
                         (f"parts {understated} report less than recomputed" if understated else "remainder = report")
                         + f" (≤ {SUPPORT_FREE_MM2} mm² counts as free){floor}"))
    planes = [(np.asarray(p["base_plane"]["normal"], float), float(p["base_plane"]["offset_mm"])) for p in parts]
    crossing = []
    for i in range(len(parts)):
        for j in range(i + 1, len(parts)):
            (ni, ci), (nj, cj) = planes[i], planes[j]
            d = np.cross(ni, nj)
            if np.linalg.norm(d) < 1e-6:
                continue  # parallel base planes: sections can only meet if coplanar (not re-checked)
            d /= np.linalg.norm(d)
            point = np.linalg.lstsq(np.vstack([ni, nj]), np.array([ci, cj]), rcond=None)[0]
            a = _intervals(meshes[i], _base_faces(meshes[i], ni, ci, i == 0), nj, cj, point, d)
            b = _intervals(meshes[j], _base_faces(meshes[j], nj, cj, j == 0), ni, ci, point, d)
            if any(min(a1, b1) - max(a0, b0) > LINE_TOL for a0, a1 in a for b0, b1 in b):
                crossing.append((i, j))
    results.append(Check(STAGE, "Constraint I (base sections apart)", not crossing, f"{len(crossing)} pairs",
                         str(crossing) if crossing else ""))
    down = [k for k, (n, _) in enumerate(planes[1:], start=1) if n @ root_dir <= 0]
    results.append(Check(STAGE, "Constraint II (base planes face up)", not down, f"{len(down)} parts",
                         str(down) if down else ""))
    if (outdir / "toolpaths.npz").exists() and (outdir / "layers").is_dir():
        results += _printed(outdir, spec, meshes)
    return results


def _printed(outdir: Path, spec: dict, meshes: list[trimesh.Trimesh]) -> list[Check]:
    report = json.loads((outdir / "report.json").read_text())
    h = float(report["layers"]["layer_height_mm"])
    counts = report["layers"]["per_part"]
    files = sorted((outdir / "layers").glob("layer_*.ply"))
    root = spec["parts"][0]
    # E in model coordinates: z = the root's build direction, origin = its base centre; T_P^E maps P into E
    E = plane_frame(np.asarray(root["build_direction"], float), np.asarray(root["base_centre_mm"], float))
    owner = np.repeat(np.arange(len(counts)), counts)
    off_plane, heights, outside = [], [], []
    for number, f in enumerate(files, start=1):
        k = int(owner[number - 1]) if number <= len(owner) else -1
        layer = trimesh.load(f, force="mesh", process=False)
        if k < 0 or not len(layer.vertices):
            continue
        P = np.asarray(spec["parts"][k]["T_P_E"], float)
        z = (layer.vertices - P[:3, 3]) @ P[:3, 2]  # height above the base plane, along the build direction
        off_plane.append(float(np.ptp(z)))
        heights.append((k, float(z.mean())))
        model = (layer.vertices @ E[:3, :3].T) + E[:3, 3]  # E -> model coordinates
        d = trimesh.proximity.signed_distance(meshes[k], model[:: max(1, len(model) // 200)])
        outside.append(float(-d.min()))  # signed_distance is positive inside
    # each part's layers rise from its base plane by at most one layer height at a time
    steps = [z - (heights[i - 1][1] if i and heights[i - 1][0] == k else 0.0) for i, (k, z) in enumerate(heights)]
    out = [Check(STAGE, "planar layers", len(files) == sum(counts) and max(off_plane, default=0) <= 1e-3
                 and 0 < min(steps, default=h) and max(steps, default=0) <= h + 1e-3,
                 f"{len(files)} layers, flat within {max(off_plane, default=0):.1e} mm",
                 f"rising {min(steps, default=0):.2f}-{max(steps, default=0):.2f} mm a layer (height {h:g} mm) from each "
                 f"base plane; report counts {sum(counts)}")]
    out.append(Check(STAGE, "layers inside their parts", max(outside, default=0) <= 0.05,
                     f"max {max(outside, default=0):.3f} mm outside", "sampled vertices, signed distance to the part"))
    with np.load(outdir / "toolpaths.npz") as z:
        part, normals, layer = z["part"], z["normals"], z["layer"]
    axes = np.array([np.asarray(p["T_P_E"], float)[:3, 2] for p in spec["parts"]])
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", normals, axes[part]), -1, 1)))
    in_order = bool(np.all(np.diff(part) >= 0)) and bool(np.all(owner[layer - 1] == part))
    out.append(Check(STAGE, "nozzle along each part's direction", len(angle) > 0 and angle.max() <= 1e-3 and in_order,
                     f"max {angle.max() if len(angle) else 0:.1e}°", "parts printed in sequence order, each on its own layers"
                     if in_order else "samples out of sequence order or on another part's layer"))
    return out

