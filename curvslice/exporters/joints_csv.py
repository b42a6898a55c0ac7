"""``joints.csv``: the planned joint trajectory beside its waypoints (§3.5.3), one row per waypoint.

Columns: ``layer, path, index, t, x, y, z, nx, ny, nz, q1 … q6, segment, extruding`` — the
waypoint's layer and path id and its row in ``toolpaths.npz``, the time (s), the deposition point
(mm) and the realized tool orientation in the model frame (the tool-path's unless the waypoint
needed a bounded axis deviation, see :func:`curvslice.ladder.deviate_axes`), the joint angles (rad), the motion segment (a new
value starts a new smooth motion after a disconnection, Fig. 3.11b) and whether the extruder runs
while moving to the row (0/1).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from curvslice.errors import CurvsliceError
from curvslice.validate import require_finite

COLUMNS = ("layer", "path", "index", "t", "x", "y", "z", "nx", "ny", "nz",
           "q1", "q2", "q3", "q4", "q5", "q6", "segment", "extruding")


def write_joints_csv(
    path: Path,
    *,
    layer: np.ndarray,
    path_id: np.ndarray,
    index: np.ndarray,
    t: np.ndarray,
    positions: np.ndarray,
    normals: np.ndarray,
    q: np.ndarray,
    segment: np.ndarray,
    extruding: np.ndarray,
) -> None:
    """Write the rows (N of each array; positions/normals/q with 3/3/6 columns)."""
    require_finite(f"joints CSV writer ({Path(path).name})", t=t, positions=positions, normals=normals, q=q)
    ints = np.column_stack([layer, path_id, index, segment, np.asarray(extruding, bool)]).astype(np.int64).tolist()
    floats = np.column_stack([t, positions, normals, q]).astype(float).tolist()  # Python floats: repr round-trips
    with open(path, "w") as f:
        f.write(",".join(COLUMNS) + "\n")
        f.writelines(f"{i[0]},{i[1]},{i[2]}," + ",".join(map(repr, v)) + f",{i[3]},{i[4]}\n"
                     for i, v in zip(ints, floats))


def read_joints_csv(path: Path) -> dict[str, np.ndarray]:
    """Read ``joints.csv`` back: ``layer, path, index, t, positions, normals, q, segment, extruding``."""
    path = Path(path)
    with open(path) as f:
        header = f.readline().strip().split(",")
    if tuple(header) != COLUMNS:
        raise CurvsliceError(f"{path}: unexpected header (want {','.join(COLUMNS)})")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.shape[0] == 0:
        data = np.zeros((0, len(COLUMNS)))
    return {
        "layer": data[:, 0].astype(np.int32),
        "path": data[:, 1].astype(np.int32),
        "index": data[:, 2].astype(np.int64),
        "t": data[:, 3],
        "positions": data[:, 4:7],
        "normals": data[:, 7:10],
        "q": data[:, 10:16],
        "segment": data[:, 16].astype(np.int64),
        "extruding": data[:, 17].astype(bool),
    }


def write_robot_outputs(outdir: Path, cell, family: str, toolpaths: dict[str, np.ndarray], motion) -> list[Path]:
    """The robot stage's files: ``joints.csv``, the controller programs (URScript for the UR
    family, RAPID modules for ABB arms, split so a controller can load them) and ``workcell.json``.

    ``cell`` is a :class:`curvslice.workcell.Workcell`, ``motion`` a
    :class:`curvslice.motion.PrintMotion` over the rows of ``toolpaths``.
    """
    from curvslice.exporters.rapid import write_rapid_joints
    from curvslice.exporters.urscript import write_urscript_joints
    from curvslice.workcell import save_workcell

    outdir = Path(outdir)
    idx = motion.index
    write_joints_csv(
        outdir / "joints.csv",
        layer=np.asarray(toolpaths["layer"])[idx],
        path_id=np.asarray(toolpaths["path"])[idx],
        index=idx,
        t=motion.t,
        positions=np.asarray(toolpaths["positions"])[idx],
        normals=motion.normals,
        q=motion.q,
        segment=motion.segment,
        extruding=motion.extruding,
    )
    save_workcell(cell, outdir / "workcell.json")
    paths = [outdir / "joints.csv", outdir / "workcell.json"]
    if len(motion.q):
        writer = write_urscript_joints if family == "ur" else write_rapid_joints
        paths += writer(outdir, motion.q, motion.t, segment=motion.segment, extruding=motion.extruding)
    return paths
