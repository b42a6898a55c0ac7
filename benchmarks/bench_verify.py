"""The verify table (issue 18): every shared model at its standard settings, and the kitten at other
voxel sizes and path widths, sliced to the tool-paths and re-checked by every ``curvslice verify``
check; ``curvslice bench --verify-only`` runs only this and writes its section of RESULTS.md.

Per run: missed voxels beside the authors' C++ on the same model and voxel (DESIGN.md,
:data:`benchmarks.paper.AUTHORS_CPP`), where the missed voxels lie (connected pieces, their height,
whether they touch ∂H̄ or the platform), min coverage and max overlap with the layers outside the
95 / 5 % limits, every failed check with its layers, and the verifier's inside test (generalized winding
number by solid angles, Barill et al. 2018) cross-checked on every layer vertex against the signed
distance the trimming uses (:class:`curvslice.trimming.SolidDistance`: its sign is a second, independent
winding number, the signed crossings of a +z ray): the vertices farther than the verifier's tolerance from
∂H on which the two disagree are counted -- any fails the run -- and the verifier's ray parity says which
is right (parity is exact only where ∂H does not cross itself: winding number 2 is even).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Standard settings (issue 18): the bunny at 1.0 mm (the thesis's voxel count), the others at 0.8 mm.
STANDARD = (("bunny", 1.0), ("kitten", 0.8), ("fertility", 0.8), ("rocker-arm", 0.8), ("fandisk", 0.8),
            ("cheburashka", 0.8), ("cow", 0.8), ("homer", 0.8))
#: The kitten at coarser voxels, and at the narrowest and widest path widths a user may choose (voxel widths).
VARIANTS = (("kitten", 1.0, None), ("kitten", 1.6, None), ("kitten", 2.0, None),
            ("kitten", 0.8, 0.6), ("kitten", 0.8, 1.5))
SECTION = "## Verify at standard settings"


@dataclass(frozen=True)
class Case:
    """One run: a model at a voxel size (mm) and a path width in voxel widths (None: the default)."""

    model: str
    voxel: float
    path_width_w: float | None = None

    @property
    def title(self) -> str:
        return f"{self.model} @{self.voxel:g} mm" + (f", path {self.path_width_w:g} w" if self.path_width_w else "")

    @property
    def folder(self) -> str:
        return f"{self.model}_{self.voxel:g}" + (f"_pw{self.path_width_w:g}" if self.path_width_w else "")


def cases(models: tuple[str, ...] | None = None) -> list[Case]:
    """The standard cases then the kitten variants (only ``models`` when given)."""
    found = [Case(m, v) for m, v in STANDARD] + [Case(m, v, p) for m, v, p in VARIANTS]
    return [c for c in found if models is None or c.model in models]


def missed_voxels(outdir: Path) -> dict[str, object]:
    """Missed voxels (occupied, G = 0) of ``field.npz`` and where they are: connected pieces (26-
    neighbourhood), each with its size, height span (mm above the platform), how many of its voxels
    touch ∂H̄ (a face neighbour outside the occupied set), the layers of the printed voxels around it,
    and why it was missed: the earliest layer that could have supported it (an AM-stable neighbour,
    Constraint 1) and how deep it then already lay inside that layer's front C(layers ≤ s ∪ T)
    (Constraint 2 forbids ε or more: shadowed before it could be supported)."""
    from scipy import ndimage
    from scipy.spatial import ConvexHull

    from curvslice.verify.field import _asn_offsets

    with np.load(outdir / "field.npz", allow_pickle=False) as z:
        occupied, growing = z["occupied"], z["growing"].astype(np.int64)
        origin, w = np.asarray(z["origin"], float), float(z["voxel_size"])
        platform = np.asarray(z["platform_vertices"], float) if "platform_vertices" in z.files else np.zeros((0, 3))
    missed = occupied & (growing == 0)
    out: dict[str, object] = {"voxels": int(occupied.sum()), "layers": int(growing.max()), "missed": int(missed.sum()),
                              "pieces": []}
    if not missed.any():
        return out
    labels, count = ndimage.label(missed, structure=np.ones((3, 3, 3), bool))
    outer = ~ndimage.binary_erosion(np.pad(occupied, 1), structure=ndimage.generate_binary_structure(3, 1))[1:-1, 1:-1, 1:-1]
    ring = ndimage.binary_dilation(missed, structure=np.ones((3, 3, 3), bool)) & ~missed & (growing > 0)
    never = np.iinfo(np.int64).max
    pad = np.pad(np.where(growing > 0, growing, never), 1, constant_values=never)
    fronts: dict[int, ConvexHull] = {}
    pieces = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        piece = labels[sl] == k
        ijk = np.argwhere(piece) + [s.start for s in sl]
        z_mm = origin[2] + w * ijk[:, 2]
        around = growing[ndimage.binary_dilation(labels == k, structure=np.ones((3, 3, 3), bool)) & ring]
        support = np.min([pad[tuple((ijk + 1 + d).T)] for d in _asn_offsets()], axis=0)
        depths = []
        for s in np.unique(support[support < never]):
            if s not in fronts:
                fronts[s] = ConvexHull(np.vstack([platform, origin + w * np.argwhere((growing > 0) & (growing <= s))]))
            x = origin + w * ijk[support == s]
            depths.append(-(x @ fronts[s].equations[:, :3].T + fronts[s].equations[:, 3]).max(axis=1) / w)
        depth = np.concatenate(depths) if depths else np.zeros(0)
        pieces.append({"size": int(piece.sum()), "z_mm": [round(float(z_mm.min()), 1), round(float(z_mm.max()), 1)],
                       "on_surface": int(outer[tuple(ijk.T)].sum()),
                       "on_platform": bool(z_mm.min() - w / 2 <= 1e-6 * w),
                       "layers_around": [int(around.min()), int(around.max())] if len(around) else [],
                       "first_support": int(support.min()) if (support < never).any() else None,
                       "unsupported": int((support == never).sum()),
                       "depth_w": [round(float(depth.min()), 2), round(float(depth.max()), 2)] if len(depth) else []})
    out["pieces"] = sorted(pieces, key=lambda p: -p["size"])
    return out


def inside_cross_check(outdir: Path) -> dict[str, object]:
    """The verifier's inside test (winding number ≥ ½) against the trimming's signed distance on every
    layer vertex: vertices, disagreements farther than the verifier's tolerance from ∂H (and their
    layers), the largest such distance (voxel widths), and those where the ray parity sides with the
    trimming."""
    import trimesh

    from curvslice.trimming import SolidDistance
    from curvslice.verify.layers import TOLERANCE, inside_by_ray_parity, winding_numbers

    with np.load(outdir / "field.npz", allow_pickle=False) as z:
        w = float(z["voxel_size"])
    solid = trimesh.load(outdir / "solid.stl", force="mesh")
    meshes = [trimesh.load(p, force="mesh", process=False) for p in sorted((outdir / "layers").glob("layer_*.ply"))]
    numbers = [k + 1 for k, m in enumerate(meshes) if len(m.vertices)]
    verts = np.concatenate([m.vertices for m in meshes if len(m.vertices)] or [np.zeros((0, 3))])
    layer = np.repeat(numbers, [len(m.vertices) for m in meshes if len(m.vertices)])
    if not len(verts):
        return {"vertices": 0, "disagree": 0, "layers": [], "max_w": 0.0, "winding_alone": 0, "winding_alone_layers": []}
    winding = winding_numbers(solid, verts) > 0.5
    signed, _ = SolidDistance.of(solid)(verts)
    differ = (winding != (signed < 0)) & (np.abs(signed) > TOLERANCE * w)
    # a third test says which is right (off a self-crossing ∂H, where parity is exact)
    parity = inside_by_ray_parity(solid, verts[differ]) if differ.any() else np.zeros(0, bool)
    alone = parity != winding[differ]  # the winding number against both other tests
    return {"vertices": int(len(verts)), "disagree": int(differ.sum()), "layers": sorted({int(k) for k in layer[differ]}),
            "max_w": round(float(np.abs(signed[differ]).max() / w), 3) if differ.any() else 0.0,
            "winding_alone": int(alone.sum()), "winding_alone_layers": sorted({int(k) for k in layer[differ][alone]})}


_PERCENT = re.compile(r"(min|max) ([0-9.]+)% \(layer (\d+)\)")


def run_case(case: Case, model: Path, workdir: Path, quiet: bool = False, reuse: bool = False) -> dict[str, object]:
    """Slice ``model`` to the tool-paths in ``workdir/<case>`` (replaced), verify it and return the
    record, also written to ``workdir/<case>.json``; with ``reuse``, a record already there is returned
    instead (an interrupted table resumes where it stopped)."""
    saved = workdir / f"{case.folder}.json"
    if reuse and saved.is_file():
        return {**json.loads(saved.read_text()), "reused": True}
    record = _run(case, model, workdir, quiet)
    record.update(finished=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
                  load=[round(x, 1) for x in os.getloadavg()])
    saved.write_text(json.dumps(record, indent=1) + "\n")
    return record


def _run(case: Case, model: Path, workdir: Path, quiet: bool) -> dict[str, object]:
    from curvslice.cli import main
    from curvslice.verify import verify_outdir

    out = workdir / case.folder
    shutil.rmtree(out, ignore_errors=True)
    workdir.mkdir(parents=True, exist_ok=True)
    argv = ["slice", str(model), "--voxel", f"{case.voxel:g}", "--stages", "toolpaths", "--no-verify", "--quiet",
            "--out", str(out)]
    if case.path_width_w:
        argv += ["--path-width", f"{case.path_width_w * case.voxel:.6g}"]
    record: dict[str, object] = {"model": case.model, "voxel_mm": case.voxel, "path_width_w": case.path_width_w,
                                 "title": case.title, "command": "curvslice " + " ".join(argv[:1] + [model.name] + argv[2:])}
    if not quiet:
        print(f"{case.title}: slicing", flush=True)
    t0 = time.perf_counter()
    try:
        code = main(argv)
        error = None if code == 0 else f"curvslice slice exited {code}"
    except Exception as exc:  # a crash is a row of the table, not the end of the run
        error = f"{type(exc).__name__}: {str(exc)[:200]}"
    record["slice_s"] = round(time.perf_counter() - t0, 1)
    if error:
        record.update(crashed=error, passed=False)
        return record
    report = json.loads((out / "report.json").read_text())
    record["path_width_mm"] = (report.get("toolpaths") or {}).get("path_width_mm")
    t0 = time.perf_counter()
    checks = verify_outdir(out)
    record["verify_s"] = round(time.perf_counter() - t0, 1)
    record["failed"] = [{"check": f"{c.stage}/{c.name}", "value": c.value, "detail": c.detail, "layers": list(c.layers)}
                        for c in checks if not c.passed]
    for c in checks:
        if c.stage == "toolpaths" and c.name in ("coverage", "overlap") and (m := _PERCENT.search(c.value)):
            record[c.name] = {"percent": float(m.group(2)), "layer": int(m.group(3)), "failing": list(c.layers)}
    record["field"] = missed_voxels(out)
    t0 = time.perf_counter()
    record["inside"] = inside_cross_check(out)
    record["cross_check_s"] = round(time.perf_counter() - t0, 1)
    record["passed"] = not record["failed"] and record["inside"]["disagree"] == 0
    if not quiet:
        print(f"  {'PASS' if record['passed'] else 'FAIL'}: " + "; ".join(f"{f['check']} {f['value']}" for f in record["failed"]),
              flush=True)
    return record


def authors_missed(model: str, voxel: float) -> int | None:
    """Missed voxels of the authors' C++ (pg-sp-gcfa) on this model and voxel, if measured."""
    from benchmarks.paper import AUTHORS_CPP

    ref = AUTHORS_CPP.get((model, voxel, "pg-sp-gcfa"))
    return None if ref is None else ref["missed"]


def _where(field: dict) -> str:
    pieces = field.get("pieces") or []
    if not pieces:
        return "–"
    text = []
    for p in pieces[:3]:
        around = p["layers_around"]
        depth = p.get("depth_w") or []
        text.append(f"{p['size']} at z {p['z_mm'][0]:g}–{p['z_mm'][1]:g} mm ({p['on_surface']} on ∂H̄"
                    + (", on the platform" if p["on_platform"] else "")
                    + (f", between layers {around[0]}–{around[1]}" if around else "")
                    + (f"; first supportable at layer {p['first_support']}, then already {depth[0]:g}–{depth[1]:g} w "
                       "inside the front" if depth else "")
                    + (f"; {p['unsupported']} with no printed neighbour" if p.get("unsupported") else "") + ")")
    return "; ".join(text) + (f"; +{len(pieces) - 3} pieces" if len(pieces) > 3 else "")


def markdown(records: list[dict], header: dict[str, object]) -> str:
    """The RESULTS.md section: one row per run, then every failed check with its layers."""
    lines = [SECTION, "",
             f"Refresh with `{header['command']}` (slices into a scratch folder, then `curvslice verify` on it). "
             f"Run on commit {header['commit']} ({header['date']}); load average {header['load']}"
             + (f"; {sum(bool(r.get('reused')) for r in records)} of {len(records)} runs were recorded by an earlier "
                "run of the same command (`--reuse`)" if any(r.get("reused") for r in records) else "")
             + (f"; the runs finished {min(done)} – {max(done)}, {header.get('jobs', 1)} at a time, load average "
                f"{min(loads):g}–{max(loads):g} (their seconds are wall times on a shared 2-core machine: upper bounds)"
                if (done := [r["finished"] for r in records if r.get("finished")])
                and (loads := [r["load"][0] for r in records if r.get("load")]) else "")
             + ". Standard settings: "
             "the bunny at 1.0 mm, the others at 0.8 mm, default path width (voxel / 0.8); then the kitten at 1.0 / "
             "1.6 / 2.0 mm and at path widths 0.6 and 1.5 voxel widths. 'C++' = the authors' code on the same model and "
             "voxel (DESIGN.md; – where not measured). Coverage and overlap per layer (limits 95 % / 5 %); 'inside test "
             "vs trimming' = layer vertices farther than 0.05 w from ∂H on which the verifier's winding number (solid "
             "angles) and the sign of the trimming's signed distance (winding number of a +z ray) disagree.", "",
             "| run | voxels | layers | missed (C++) | min coverage (layer) | max overlap (layer) | layers failing "
             "coverage / overlap | other failed checks | inside test vs trimming | slice / verify s | result |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        if "crashed" in r:
            lines.append(f"| {r['title']} | – | – | – | – | – | – | crashed: {r['crashed']} | – | {r['slice_s']} / – | **FAIL** |")
            continue
        f, ref = r["field"], authors_missed(r["model"], r["voxel_mm"])
        cov, ovl = r.get("coverage"), r.get("overlap")
        missed = f"{f['missed']} ({'–' if ref is None else ref})" + (" **above C++**" if ref is not None and f["missed"] > ref else "")
        other = [x for x in r["failed"] if x["check"] not in ("toolpaths/coverage", "toolpaths/overlap")]
        inside = r["inside"]
        lines.append(
            f"| {r['title']} | {f['voxels']:,} | {f['layers']} | {missed} "
            f"| {cov['percent']:.1f} % ({cov['layer']}) | {ovl['percent']:.1f} % ({ovl['layer']}) "
            f"| {len(cov['failing'])} / {len(ovl['failing'])} "
            f"| {'; '.join(x['check'] + ': ' + x['value'] for x in other) or '–'} "
            f"| {inside['disagree']} of {inside['vertices']:,}"
            + (f" ({inside['winding_alone']} with the ray parity against the verifier)" if inside["disagree"] else "")
            + " "
            f"| {r['slice_s']:g} / {r['verify_s'] + r['cross_check_s']:g} | {'PASS' if r['passed'] else '**FAIL**'} |")
    lines += ["", "Failed checks and their layers:", ""]
    for r in records:
        if "crashed" in r:
            lines.append(f"- {r['title']}: crashed — {r['crashed']}")
        for x in r.get("failed", []):
            layers = f" — layers {', '.join(map(str, x['layers']))}" if x["layers"] else ""
            lines.append(f"- {r['title']}: {x['check']} {x['value']}{layers}")
        if r.get("inside", {}).get("disagree"):
            i = r["inside"]
            lines.append(f"- {r['title']}: the verifier's winding number and the trimming's sign differ on {i['disagree']} vertices up to "
                         f"{i['max_w']} w off ∂H (layers {', '.join(map(str, i['layers'][:20]))}); the ray parity sides "
                         f"with the winding number on {i['disagree'] - i['winding_alone']}"
                         + (f", against it on {i['winding_alone']} (layers {', '.join(map(str, i['winding_alone_layers']))})"
                            if i["winding_alone"] else ""))
    if not any(r.get("failed") or "crashed" in r or r.get("inside", {}).get("disagree") for r in records):
        lines.append("- none")
    lines += ["", "Where the missed voxels are and why (largest connected pieces; 'between layers' = the layers of the "
              "printed voxels around a piece; 'first supportable' = the earliest layer with an AM-stable neighbour, "
              "Constraint 1, and 'inside the front' = the depth of its voxels inside C(layers ≤ that one ∪ T) then: "
              "at ε = 1 w or more, Constraint 2 forbids them — shadowed before support reached them):", ""]
    lines += [f"- {r['title']}: {r['field']['missed']} missed — {_where(r['field'])}" for r in records
              if "field" in r and r["field"]["missed"]] or ["- none missed"]
    return "\n".join(lines) + "\n"


def splice(results_md: Path, section: str, heading: str = SECTION) -> None:
    """Replace the section under ``heading`` (default: the verify table's) of ``results_md`` (from its heading
    to the next ``## ``) or add it before the list of what is not implemented; creates the file when absent."""
    text = results_md.read_text() if results_md.exists() else ""
    start = text.find(heading)
    if start >= 0:
        end = text.find("\n## ", start + len(heading))
        text = text[:start] + section + ("\n" + text[end + 1:] if end >= 0 else "")
    else:
        anchor = text.find("## Not yet implemented")
        text = (text[:anchor] + section + "\n" + text[anchor:]) if anchor >= 0 else text + ("\n" if text else "") + section
    results_md.write_text(text)
