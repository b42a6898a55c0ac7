"""Extended G-code with tool orientations (thesis appendix, "Extended G-code File Format").

Every deposition sample is one line ``G1 X Y Z nX nY nZ E F`` in the model frame (mm), where
``(nX, nY, nZ)`` is the unit tool orientation (from the deposited point towards the nozzle) and
``E`` the *absolute* filament position (``M82``). The first sample of each continuous extrusion
piece is reached by a ``G0`` travel (no extrusion). ``;LAYER:n`` and ``;PATH:id`` comments carry
the layer and piece ids, and the header lists every parameter as ``; key = value``, so
:func:`read_gcode6` restores the arrays the writer was given.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from curvslice.exporters import fixed
from curvslice.validate import require_finite

_WORD = re.compile(r"(nX|nY|nZ|[XYZEF])\s*([-+]?(?:\d+\.?\d*|\.\d+))")  # no exponents: X10E5 is X10 E5
_MARK = re.compile(r"^;\s*(LAYER|PATH)\s*:\s*(-?\d+)")
_HEADER = re.compile(r"^;\s*([A-Za-z_][\w.]*)\s*=\s*(.*?)\s*$")


def write_gcode6(
    path: Path,
    positions: np.ndarray,
    normals: np.ndarray,
    extrusion: np.ndarray,
    feed: np.ndarray,
    path_id: np.ndarray,
    layer: np.ndarray,
    header: dict[str, object] | None = None,
) -> None:
    """Write samples as extended G-code (absolute E, a G0 travel before each new ``path_id``).

    ``extrusion[i]`` is the filament length deposited on the segment ending at sample ``i``; it
    must be 0 at the first sample of a piece (that sample is reached by travel).
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    ext = np.asarray(extrusion, dtype=np.float64).ravel()
    fee = np.asarray(feed, dtype=np.float64).ravel()
    pid = np.asarray(path_id).astype(np.int64).ravel()
    lay = np.asarray(layer).astype(np.int64).ravel()
    require_finite(f"extended G-code writer ({Path(path).name})", positions=pos, normals=nrm, extrusion=ext, feed=fee)
    n = len(pos)
    if not all(len(a) == n for a in (nrm, ext, fee, pid, lay)):
        raise ValueError("write_gcode6: positions, normals, extrusion, feed, path_id and layer differ in length")
    starts = np.ones(n, bool)
    starts[1:] = pid[1:] != pid[:-1]
    if np.any(np.abs(ext[starts]) > 0):
        raise ValueError("write_gcode6: extrusion must be 0 at the first sample of each path (a travel)")
    e_abs = np.cumsum(ext)
    lines = ["; curvslice extended G-code (thesis appendix): G1 X Y Z nX nY nZ E F",
             "; model frame, mm; nX nY nZ = unit tool orientation towards the nozzle; absolute E"]
    lines += [f"; {key} = {value}" for key, value in (header or {}).items()]
    lines += ["M82", "G92 E0"]
    new_layer = np.ones(n, bool)
    new_layer[1:] = lay[1:] != lay[:-1]
    for i in range(n):
        if new_layer[i]:
            lines.append(f";LAYER:{lay[i]}")
        x, y, z = (fixed(v, 4) for v in pos[i])
        nx, ny, nz = (fixed(v, 6) for v in nrm[i])
        if starts[i]:
            lines.append(f";PATH:{pid[i]}")
            lines.append(f"G0 X{x} Y{y} Z{z} nX{nx} nY{ny} nZ{nz} F{fixed(fee[i], 3)}")
        else:
            lines.append(f"G1 X{x} Y{y} Z{z} nX{nx} nY{ny} nZ{nz} E{fixed(e_abs[i], 6)} F{fixed(fee[i], 3)}")
    Path(path).write_text("\n".join(lines) + "\n")


def read_gcode6_header(path: Path) -> dict[str, str]:
    """The ``; key = value`` parameter lines of an extended G-code header, as strings."""
    found: dict[str, str] = {}
    with Path(path).open() as fh:
        for line in fh:
            if not line.startswith(";"):
                if line.strip() and not line.startswith(("M", "G92")):
                    break
                continue
            match = _HEADER.match(line)
            if match:
                found[match.group(1)] = match.group(2)
    return found


def read_gcode6(path: Path) -> dict[str, np.ndarray]:
    """Parse extended G-code back into the writer's arrays.

    Returns ``positions`` (N,3), ``normals`` (N,3, normalised; +Z where a line has none),
    ``extrusion`` (per-segment increments recovered from absolute E, honouring ``G92 E``),
    ``feed`` (modal F), ``path_id`` (from ``;PATH:`` comments, else a new id at every G0) and
    ``layer`` (from ``;LAYER:`` comments, else 0).
    """
    rows: list[tuple[float, ...]] = []
    state = {"X": 0.0, "Y": 0.0, "Z": 0.0, "nX": 0.0, "nY": 0.0, "nZ": 1.0, "E": 0.0, "F": 0.0}
    layer, marked_path, path_counter, e_prev = 0, None, -1, 0.0
    with Path(path).open() as fh:
        for raw in fh:
            line = raw.strip()
            if line.startswith(";"):
                mark = _MARK.match(line)
                if mark and mark.group(1) == "LAYER":
                    layer = int(mark.group(2))
                elif mark:
                    marked_path = int(mark.group(2))
                continue
            code = line.split(";", 1)[0].split()
            if not code:
                continue
            if code[0] == "G92":
                words = dict(_WORD.findall(line))
                if "E" in words:
                    state["E"] = e_prev = float(words["E"])
                continue
            if code[0] not in ("G0", "G1", "G00", "G01"):
                continue
            words = dict(_WORD.findall(line.split(";", 1)[0][len(code[0]):]))
            for key, value in words.items():
                state[key] = float(value)
            if not ({"X", "Y", "Z"} & words.keys()):
                e_prev = state["E"]  # a pure extruder or feed move (retraction, priming)
                continue
            travel = code[0] in ("G0", "G00")
            if travel:
                path_counter = marked_path if marked_path is not None else path_counter + 1
                marked_path = None
            increment = 0.0 if travel else state["E"] - e_prev
            e_prev = state["E"]
            rows.append((state["X"], state["Y"], state["Z"], state["nX"], state["nY"], state["nZ"],
                         increment, state["F"], float(max(path_counter, 0)), float(layer)))
    data = np.asarray(rows, dtype=np.float64).reshape(-1, 10)
    normals = data[:, 3:6]
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.where(length > 0, normals / np.where(length > 0, length, 1.0), [0.0, 0.0, 1.0])
    return {
        "positions": data[:, 0:3].copy(),
        "normals": normals,
        "extrusion": data[:, 6].copy(),
        "feed": data[:, 7].copy(),
        "path_id": data[:, 8].astype(np.int64),
        "layer": data[:, 9].astype(np.int64),
    }
