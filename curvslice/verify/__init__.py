"""Independent re-checks of every artefact in a slice folder (``curvslice verify OUTDIR``).

Each stage has a module here exposing ``checks(outdir: Path) -> list[Check] | None`` that
recomputes its properties from the written files alone, without calling the code that made them
(returning ``None`` when that stage's artefacts are absent). :func:`verify_outdir` first requires
every artefact that ``report.json`` says was written (its ``stages``, and ``files`` when present):
a missing or unreadable one is a FAIL naming it, and its stage's re-check is not run on it. A
re-check that raises on a damaged file becomes a FAIL too: verify reports, it never crashes.
"""

from __future__ import annotations

import importlib
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from curvslice.errors import CurvsliceError

#: Stage checker modules of ``curvslice.verify``, in pipeline order.
STAGES = ("field", "layers", "toolpaths", "robot")
#: Checker of a `curvslice decompose` folder (RoboFDM, ch. 2).
STAGES += ("decompose",)

#: The files each stage writes (``layers/`` stands for ``layers/layer_0001.ply`` … up to the count in
#: report.json); the robot stage also writes its controller programs (see :func:`_programs`).
ARTEFACTS: dict[str, tuple[str, ...]] = {
    "field": ("field.npz", "solid.stl"),
    "layers": ("layers/",),
    "toolpaths": ("toolpaths.npz", "toolpaths.gcode"),
    "robot": ("joints.csv", "workcell.json"),
}


@dataclass(frozen=True)
class Check:
    """One verified property: ``passed`` is False on a violation; ``value`` is the measured figure;
    ``layers`` the numbers of the layers that violate it, for a per-layer check (else empty)."""

    stage: str
    name: str
    passed: bool
    value: str
    detail: str = ""
    layers: tuple[int, ...] = ()

    def __post_init__(self) -> None:  # numpy bools and numbers from the checkers -> JSON-ready types
        object.__setattr__(self, "passed", bool(self.passed))
        object.__setattr__(self, "value", str(self.value))
        object.__setattr__(self, "detail", str(self.detail))
        object.__setattr__(self, "layers", tuple(int(k) for k in self.layers))


def layer_list(numbers, most: int = 12) -> str:
    """``"3, 17, 97"`` (the first ``most`` layer numbers, then ``… (+n)``) for a check's detail."""
    numbers = [int(k) for k in numbers]
    return ", ".join(map(str, numbers[:most])) + (f", … (+{len(numbers) - most})" if len(numbers) > most else "")


def _load_error(path: Path) -> str | None:
    """Why the artefact ``path`` cannot be read (missing, truncated, not its format), else None."""
    if not path.is_file():
        return "missing"
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                for key in z.files:
                    z[key]  # reads and CRC-checks every array
        elif path.suffix in (".stl", ".ply"):
            mesh = trimesh.load(path, force="mesh", process=False)
            if not isinstance(mesh, trimesh.Trimesh):
                return "not a triangle mesh"
        elif path.suffix == ".json":
            json.loads(path.read_text(encoding="utf-8"))
        elif path.suffix == ".csv":
            from curvslice.exporters.joints_csv import read_joints_csv

            read_joints_csv(path)
        elif path.suffix == ".png":
            if path.read_bytes()[:8] != b"\x89PNG\r\n\x1a\n":
                return "not a PNG image"
        else:
            path.read_text(encoding="utf-8")
    except (OSError, ValueError, KeyError, IndexError, EOFError, zipfile.BadZipFile, CurvsliceError) as exc:
        return f"unreadable ({type(exc).__name__}: {str(exc)[:120]})"
    return None


def _programs(outdir: Path, robot: object) -> list[Check]:
    """The robot stage's controller programs: URScript (``*.script``) or RAPID (``*.mod``) when it planned rows."""
    if not isinstance(robot, dict) or not robot.get("rows"):
        return []
    files = sorted(outdir.glob("*.script")) + sorted(outdir.glob("*.mod"))
    bad = [f"{p.name} {err}" for p in files if (err := _load_error(p))]
    return [Check("artefacts", "robot programs", bool(files) and not bad, f"{len(files)} files",
                  "no *.script or *.mod program written" if not files else "; ".join(bad))]


def _gcode_orientations(outdir: Path) -> Check:
    """Every move of ``toolpaths.gcode`` carries the orientation and layer of its ``toolpaths.npz``
    sample (the G-code is what a printer runs: a flipped ``nZ`` on one line must not pass)."""
    from curvslice.exporters.gcode6 import read_gcode6

    g = read_gcode6(outdir / "toolpaths.gcode")
    with np.load(outdir / "toolpaths.npz", allow_pickle=False) as z:
        normals, layer = np.asarray(z["normals"], float), np.asarray(z["layer"])
    name = "toolpaths.gcode orientations = npz"
    if len(g["normals"]) != len(normals):
        return Check("artefacts", name, False, f"{len(g['normals'])} moves", f"toolpaths.npz has {len(normals)} samples")
    unit = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", unit, g["normals"]), -1.0, 1.0)))
    worst = int(np.argmax(angle)) if len(angle) else 0
    layers_differ = int(np.count_nonzero(g["layer"] != layer))
    passed = (not len(angle) or angle[worst] <= 0.01) and layers_differ == 0
    return Check("artefacts", name, passed, f"max {angle[worst] if len(angle) else 0.0:.3g}°",
                 "" if passed else f"move {worst}: {angle[worst]:.3g}° off; {layers_differ} moves on another layer")


def _field_matches_report(outdir: Path, summary: object) -> Check | None:
    """The voxel count of every layer in ``field.npz`` equals report.json's ``field.layer_sizes``: a
    voxel moved to the next or previous layer (which can keep support and accessibility valid)
    changes two of them. None when the report has no layer sizes."""
    sizes = summary.get("layer_sizes") if isinstance(summary, dict) else None
    if not isinstance(sizes, list):
        return None
    with np.load(outdir / "field.npz", allow_pickle=False) as z:
        counts = np.bincount(np.asarray(z["growing"]).ravel().clip(0).astype(np.int64))[1:].tolist()
    counts += [0] * (len(sizes) - len(counts))
    differ = [k + 1 for k, (a, b) in enumerate(zip(counts, sizes)) if a != b] + (
        [len(sizes) + 1] if len(counts) > len(sizes) else [])
    return Check("artefacts", "field.npz layer sizes = report.json", not differ, f"{len(sizes)} layers",
                 f"layers {differ[:6]} differ (npz {[counts[k - 1] for k in differ[:3] if k <= len(counts)]} vs "
                 f"report {[sizes[k - 1] for k in differ[:3] if k <= len(sizes)]})" if differ else "")


def artefact_checks(outdir: Path) -> tuple[list[Check], set[str]]:
    """Checks that every artefact report.json promises exists and loads; also the stages whose
    artefacts are missing or broken (their re-checks are skipped)."""
    outdir = Path(outdir)
    report_path = outdir / "report.json"
    error = _load_error(report_path)
    report = json.loads(report_path.read_text(encoding="utf-8")) if error is None else None
    if error is None and not (isinstance(report, dict) and isinstance(report.get("stages", []), list)):
        error = "not a curvslice report (no list of stages)"
    if error is not None:
        return [Check("artefacts", "report.json", False, error, "it lists the artefacts the folder must hold")], set()
    stages = [s for s in report.get("stages", []) if isinstance(s, str)]
    unknown = sorted(set(stages) - set(ARTEFACTS))
    results = [Check("artefacts", "report.json", not unknown, f"stages: {', '.join(stages) or 'none'}",
                     f"unknown stages {unknown}" if unknown else "")]
    broken: set[str] = set()
    for stage in (s for s in STAGES if s in stages):
        names = list(ARTEFACTS[stage])
        if "layers/" in names:
            names.remove("layers/")
            count = (report.get("layers") or {}).get("count") if isinstance(report.get("layers"), dict) else None
            if not isinstance(count, int) or count < 0:
                results.append(Check("artefacts", "layers/", False, "no layer count in report.json"))
                broken.add(stage)
                continue
            names += [f"layers/layer_{k:04d}.ply" for k in range(1, count + 1)]
        problems = [f"{name} {err}" for name in names if (err := _load_error(outdir / name))]
        results.append(Check("artefacts", f"{stage} files", not problems, f"{len(names) - len(problems)} of {len(names)}",
                             "; ".join(problems[:5]) + (f" (+{len(problems) - 5} more)" if len(problems) > 5 else "")))
        if problems:
            broken.add(stage)
    if "field" in stages and "field" not in broken and (found := _field_matches_report(outdir, report.get("field"))):
        results.append(found)
    if "toolpaths" in stages and "toolpaths" not in broken:
        results.append(_gcode_orientations(outdir))
    results += _programs(outdir, report.get("robot"))
    listed = report.get("files", [])
    if isinstance(listed, list) and listed:
        problems = [f"{name} {err}" for name in map(str, listed) if (err := _load_error(outdir / name))]
        results.append(Check("artefacts", "files listed in report.json", not problems, f"{len(listed) - len(problems)} "
                             f"of {len(listed)}", "; ".join(problems[:5])))
    return results, broken


def verify_outdir(outdir: str | Path) -> list[Check]:
    """The artefact checks, then every stage's re-checks whose artefacts exist and load in ``outdir``."""
    outdir = Path(outdir)
    if not outdir.is_dir():
        raise CurvsliceError(f"{outdir} is not a folder (give the output folder of `curvslice slice`)")
    if not any((outdir / name).exists() for name in ("report.json", "field.npz")):
        raise CurvsliceError(f"{outdir} holds no curvslice artefacts (no report.json or field.npz)")
    results, broken = artefact_checks(outdir)
    for stage in STAGES:
        if stage in broken:
            continue
        try:
            found = importlib.import_module(f"curvslice.verify.{stage}").checks(outdir)
        except ImportError:
            raise  # a missing package is not a damaged folder: the CLI names the package to install
        except Exception as exc:  # a damaged file the artefact check could not see: a FAIL, not a crash
            found = [Check(stage, "re-check ran", False, type(exc).__name__, str(exc)[:200])]
        results.extend(found or [])
    return results


def format_table(results: list[Check]) -> str:
    """A fixed-width table: stage, check, PASS/FAIL, measured value, detail."""
    rows = [("stage", "check", "result", "value", "detail")]
    rows += [(c.stage, c.name, "PASS" if c.passed else "FAIL", c.value, c.detail) for c in results]
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    lines = []
    for r in rows:
        lines.append("  ".join(r[i].ljust(widths[i]) for i in range(4)) + ("  " + r[4] if r[4] else ""))
    return "\n".join(lines)
