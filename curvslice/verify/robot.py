"""Re-check of the robot stage from ``joints.csv``, ``workcell.json``, ``toolpaths.npz``, the
robot programs and ``layers/`` (thesis §2.5 Eq. 2.3, §3.5.3, §4.3.1).

Independent of the planner: poses come from pinocchio's FK on the robot's URDF (not the analytic
IK) and Eq. 2.3 is inverted here; collisions are tested with fcl on every body pair (without the
planner's bounding-box shortcut), the printed part being the union of the earlier layers.
"""

from __future__ import annotations

import json
from pathlib import Path

import fcl
import numpy as np
import trimesh

from curvslice.collision import CollisionScene
from curvslice.exporters.joints_csv import read_joints_csv
from curvslice.exporters.rapid import read_rapid_joints
from curvslice.exporters.urscript import read_urscript_joints
from curvslice.kinematics import fk_reference, ik, load_robot
from curvslice.ladder import tilted_axes
from curvslice.verify import Check
from curvslice.workcell import deposition_frames, rotation_samples, workcell_from_dict
from curvslice.working_surfaces import load_layers

STAGE = "robot"
POSITION_TOL = 1e-3  # mm (1e-6 m)
AXIS_TOL = 1e-6  # rad


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0))


def _layer_meshes(outdir: Path) -> list[trimesh.Trimesh]:
    """The layers the planner carried: exactly as saved (``layers/layers.npz``), else the PLY files. The
    PLY vertices differ by up to ~2 µm, which flips a grazing contact (fertility 0.8: the heater block
    against the part at one row, free on the saved layers and on the planner's, in contact on the PLY)."""
    if (outdir / "layers" / "layers.npz").exists():
        return load_layers(outdir)
    return [trimesh.load(p, force="mesh") for p in sorted((outdir / "layers").glob("layer_*.ply"))]


def checks(outdir: Path) -> list[Check] | None:
    csv = outdir / "joints.csv"
    if not csv.exists():
        return None
    out: list[Check] = []
    rows = read_joints_csv(csv)
    spec = json.loads((outdir / "workcell.json").read_text())
    cell = workcell_from_dict(spec, "workcell.json")
    robot = load_robot(cell.robot)
    q, t, seg = rows["q"], rows["t"], rows["segment"]
    n = len(q)

    # Eq. 2.3 inverted with pinocchio's flange poses: nozzle tip and axis in the model frame
    platform_in_base = fk_reference(robot, q) @ cell.platform_mount
    nozzle_in_model = np.linalg.inv(platform_in_base) @ cell.nozzle
    tip, axis = nozzle_in_model[:, :3, 3], nozzle_in_model[:, :3, 2]
    tp = np.load(outdir / "toolpaths.npz") if (outdir / "toolpaths.npz").exists() else None
    want_pos, want_axis = rows["positions"], rows["normals"]
    if tp is not None:
        want_pos = tp["positions"][rows["index"]]
        planned = tp["normals"][rows["index"]]
        planned = planned / np.linalg.norm(planned, axis=1, keepdims=True)
        dev = np.degrees(_angle(want_axis / np.linalg.norm(want_axis, axis=1, keepdims=True), planned)) if n else np.zeros(0)
        bound = float(spec.get("max_axis_deviation_deg", 0.0))
        moved = int((dev > np.degrees(AXIS_TOL)).sum())
        top = float(dev.max()) if n else 0.0
        out.append(Check(STAGE, "axis deviation within bound", top <= bound + 1e-6,
                         f"{moved} rows, max {top:.2f} deg",
                         f"realized axis (joints.csv) vs tool-path axis, bound {bound:g} deg (workcell.json)"))
        out.append(_realized_check(outdir, robot, cell, tp, rows["index"]))
    pos_err = np.linalg.norm(tip - want_pos, axis=1).max() if n else 0.0
    ax_err = _angle(axis, want_axis).max() if n else 0.0
    out.append(Check(STAGE, "FK reproduces waypoint position", pos_err <= POSITION_TOL, f"{pos_err:.2e} mm",
                     f"pinocchio FK of every row vs its waypoint (tol {POSITION_TOL} mm)"))
    out.append(Check(STAGE, "FK reproduces nozzle axis", ax_err <= AXIS_TOL, f"{ax_err:.2e} rad",
                     f"realized tool orientation (joints.csv) vs nozzle axis (tol {AXIS_TOL} rad)"))

    lo, hi = cell.limits(robot)
    excess = float(np.maximum(q - hi, lo - q).max()) if n else -1.0
    out.append(Check(STAGE, "joint limits", excess <= 1e-9, f"{max(excess, 0.0):.2e} rad",
                     "largest excursion beyond the URDF/workcell limits"))

    steps = np.diff(t)
    out.append(Check(STAGE, "time increases", bool((steps > 0).all()) if n > 1 else True,
                     f"min step {steps.min():.4f} s" if n > 1 else "-"))
    inside = seg[1:] == seg[:-1]
    speed = np.abs(np.diff(q, axis=0)).max(axis=1) / np.where(steps > 0, steps, np.nan) if n > 1 else np.zeros(0)
    top = float(np.nanmax(speed[inside])) if inside.any() else 0.0
    out.append(Check(STAGE, "joint speed within segments", top <= cell.max_joint_speed * (1 + 1e-6),
                     f"{top:.4f} rad/s", f"max ‖Δq‖∞/Δt inside motion segments, ξ = {cell.max_joint_speed} rad/s"))
    acc, jerk = _local_derivatives(q, t, seg)
    for name, value, bound in (("acceleration", acc, cell.max_joint_acceleration), ("jerk", jerk, cell.max_joint_jerk)):
        ratio = np.abs(value) / np.asarray(bound, float)
        over = int((ratio > 1 + 1e-6).any(axis=1).sum())
        top = np.abs(value).max(axis=0) if n else np.zeros(6)
        unit = "rad/s²" if name == "acceleration" else "rad/s³"
        out.append(Check(STAGE, f"joint {name} within limits", over == 0,
                         f"{over} rows over; max {', '.join(f'{v:.3g}' for v in top)} {unit}",
                         f"Eq. 4.7-4.10 at every row inside its segment vs the workcell's "
                         f"{', '.join(f'{v:g}' for v in bound)} {unit}"))
    out.append(_move_check(q, t, seg, cell, robot))
    max_step = float(np.abs(np.diff(q, axis=0))[inside].max()) if inside.any() else 0.0
    out.append(Check(STAGE, "max joint step in a segment", True, f"{max_step:.4f} rad",
                     f"{int(seg.max()) + 1 if n else 0} motion segments"))

    out.append(_collision_check(outdir, robot, cell, rows))
    out.extend(_program_checks(outdir, rows))
    return out


def _move_check(q: np.ndarray, t: np.ndarray, seg: np.ndarray, cell, robot) -> Check:
    """Every move between segments (those between the robot stage's blocks of layers too) lasts at
    least Ruckig's time-optimal jerk-limited duration from the state the segment ends in to the state
    the next starts in (q, q̇, q̈ by Eq. 4.7-4.10 at those rows, solved here): the segments need not
    end at rest, the move must still be one the arm can make."""
    from curvslice.time_scaling import Limits, state_to_state

    moves = np.flatnonzero(seg[1:] != seg[:-1])
    if not len(moves):
        return Check(STAGE, "moves between segments within the limits", True, "no move")
    vel, acc, _ = _local_derivatives(q, t, seg, orders=(1, 2, 3))
    limits = Limits.of(robot, cell)
    need = np.array([max(state_to_state(q[i], vel[i], acc[i], q[i + 1], vel[i + 1], acc[i + 1], limits), cell.min_step_time)
                     for i in moves])
    took = t[moves + 1] - t[moves]
    short = took < need * (1 - 1e-6) - 1e-9
    return Check(STAGE, "moves between segments within the limits", not short.any(),
                 f"{int(short.sum())} of {len(moves)} moves too short; shortest margin {float((took - need).min()):.3g} s",
                 "Δt of each move vs Ruckig's state-to-state duration (ξ, a_max, j_max) from the end state of its "
                 "segment to the start state of the next (Eq. 4.7-4.10)")


def _local_derivatives(q: np.ndarray, t: np.ndarray, seg: np.ndarray, orders: tuple[int, ...] = (2, 3)
                       ) -> tuple[np.ndarray, ...]:
    """The ``orders``-th derivatives (n, 6) (default q̈ and q⃛) at every row from the degree-4
    polynomial through the 5 nearest rows of its segment (centred where it can be; all of a shorter
    segment's rows), Eq. 4.7-4.10: the polynomial's coefficients are solved for directly (independent
    of the planner's operators)."""
    n = len(q)
    out = {r: np.zeros((n, 6)) for r in (1, 2, 3)}
    if n == 0:
        return tuple(out[r] for r in orders)
    change = np.flatnonzero(seg[1:] != seg[:-1]) + 1
    starts, ends = np.r_[0, change], np.r_[change, n]
    first = np.repeat(starts, ends - starts)
    length = np.repeat(ends - starts, ends - starts)
    for k in range(2, 6):
        rows = np.flatnonzero(np.minimum(length, 5) == k)
        if len(rows) == 0 or k <= min(orders):
            continue
        lo = np.clip(rows - 2, first[rows], first[rows] + length[rows] - k)
        idx = lo[:, None] + np.arange(k)
        h = (t[idx[:, -1]] - t[idx[:, 0]]) / (k - 1)
        tau = (t[idx] - t[rows, None]) / h[:, None]
        coef = np.linalg.solve(tau[..., None] ** np.arange(k), q[idx])  # (rows, k, 6)
        for r, factor in ((1, 1), (2, 2), (3, 6)):
            if k > r:
                out[r][rows] = factor * coef[:, r] / h[:, None] ** r
    return tuple(out[r] for r in orders)


def _platform_vertices(outdir: Path) -> np.ndarray | None:
    if (outdir / "field.npz").exists():
        with np.load(outdir / "field.npz") as field:
            if "platform_vertices" in field:
                return field["platform_vertices"]
    return None


def _collision_check(outdir: Path, robot, cell, rows: dict[str, np.ndarray]) -> Check:
    platform = _platform_vertices(outdir)
    scene = CollisionScene(robot, cell, platform)
    meshes = _layer_meshes(outdir)
    hits: list[str] = []
    count = 0
    for value in np.unique(rows["layer"]):
        scene.for_layer(meshes, int(value))  # carry the union of the earlier layers
        for i in np.flatnonzero(rows["layer"] == value):
            pairs = scene.colliding_pairs(rows["q"][i])
            if pairs:
                count += 1
                if len(hits) < 3:
                    hits.append(f"row {i}: {pairs[0][0]}-{pairs[0][1]}")
    return Check(STAGE, "no collision at any row", count == 0, f"{count} rows",
                 "; ".join(hits) if hits else "fcl on all pairs; part = union of earlier layers")


def _realized_check(outdir: Path, robot, cell, tp, index: np.ndarray) -> Check:
    """Every tool-path sample has a joint row, or is listed in report.json (``robot.layers[].
    skipped_rows``, with its reason) and re-confirmed here (:func:`confirm_unreachable`)."""
    total = len(tp["positions"])
    missing = np.setdiff1d(np.arange(total), np.unique(index))
    covered = total - len(missing)
    if not len(missing):
        return Check(STAGE, "waypoints realized", True, f"{covered}/{total}", "every tool-path sample has a joint row")
    report = json.loads((outdir / "report.json").read_text()) if (outdir / "report.json").exists() else {}
    listed = {int(e["row"]) for layer in (report.get("robot") or {}).get("layers", [])
              for e in layer.get("skipped_rows", []) if e.get("reason")}
    unlisted = [int(r) for r in missing if int(r) not in listed]
    if unlisted:
        return Check(STAGE, "waypoints realized", False, f"{covered}/{total}",
                     f"{len(unlisted)} rows without a joint row are not listed with a reason in report.json "
                     f"robot.layers[].skipped_rows (e.g. {unlisted[:5]})")
    platform = _platform_vertices(outdir)
    confirmed = confirm_unreachable(robot, cell, platform, _layer_meshes(outdir), tp, missing)
    detail = (f"{len(missing)} listed in report.json with a reason, {int(confirmed.sum())} confirmed unreachable: "
              f"fcl at {cell.rotations} rotations x {len(_sample_axes(cell, np.array([0.0, 0.0, 1.0])))} axes "
              f"(tilts up to {np.degrees(cell.max_axis_deviation):g} deg)")
    if not confirmed.all():
        detail += f"; not confirmed: rows {missing[~confirmed][:5].tolist()}"
    return Check(STAGE, "waypoints realized", bool(confirmed.all()), f"{covered}/{total}", detail)


def _sample_axes(cell, axis: np.ndarray) -> np.ndarray:
    """The planned unit axis and its tilts the workcell allows: rings of ``axis_deviation_step`` up
    to ``max_axis_deviation``, 8 azimuths each (the bound the planner's deviation search respects)."""
    axis = axis / np.linalg.norm(axis)
    rings = np.arange(1, int(np.floor(cell.max_axis_deviation / cell.axis_deviation_step + 1e-9)) + 1) \
        * cell.axis_deviation_step if cell.axis_deviation_step > 0 else np.zeros(0)
    out = [axis[None]] + [tilted_axes(axis, a) for a in rings]
    axes = np.vstack(out)
    return axes[axes[:, 2] > -1 + 1e-9]


def confirm_unreachable(robot, cell, platform: np.ndarray | None, meshes: list[trimesh.Trimesh], tp,
                        missing: np.ndarray) -> np.ndarray:
    """(len(missing),) bool: no sampled pose of the tool-path rows ``missing`` (``tp``: toolpaths.npz
    arrays; ``meshes``: the layers, ``platform``: its vertices) is usable, re-derived from the geometry
    (the report is not trusted): at its planned axis and every tilt of :func:`_sample_axes`, at each
    of the workcell's rotations θ about the nozzle axis (Eq. 4.3), either fcl finds a static body
    (extruder, obstacle) in contact with the platform or the earlier layers at the platform pose that
    nozzle frame fixes (T_B^P = T_B^N (T_P^N)⁻¹: then every IK branch has that contact), or every IK
    solution inside the joint limits has a colliding pair (fcl on all pairs)."""
    scene = CollisionScene(robot, cell, platform)
    lo, hi = cell.limits(robot)
    request = fcl.CollisionRequest()
    out = np.zeros(len(missing), bool)
    layer = np.asarray(tp["layer"])
    for value in np.unique(layer[missing]):
        scene.for_layer(meshes, int(value))
        pairs = [(c.obj, s.obj) for c in scene.carried for s in scene.static]
        for i in np.flatnonzero(layer[missing] == value):
            r = missing[i]
            axes = _sample_axes(cell, np.asarray(tp["normals"][r], float))
            frames = deposition_frames(np.repeat(tp["positions"][r][None], len(axes), 0), axes,
                                       rotation_samples(cell.rotations)).reshape(-1, 4, 4)
            held = cell.nozzle @ np.linalg.inv(frames)  # platform pose in the base frame per sample
            free = False
            for k, T in enumerate(held):
                for c in scene.carried:
                    c.obj.setTransform(fcl.Transform(T[:3, :3], T[:3, 3]))
                if any(fcl.collide(a, b, request, fcl.CollisionResult()) for a, b in pairs):
                    continue
                q, ok = ik(robot, (T @ np.linalg.inv(cell.platform_mount))[None])
                q, ok = q[0], ok[0]
                q = lo + (q - lo) % (2 * np.pi)  # the same pose's smallest representative above the limit
                ok &= (q <= hi + 1e-9).all(axis=1)
                if any(not scene.colliding_pairs(qq) for qq in q[ok]):
                    free = True
                    break
            out[i] = not free
    return out


def _program_checks(outdir: Path, rows: dict[str, np.ndarray]) -> list[Check]:
    found = []
    scripts = sorted(outdir.glob("curvslice_[0-9]*.script"))
    if scripts:
        found.append(("URScript", read_urscript_joints(scripts)))
    main = outdir / "curvslice_main.mod"
    if main.exists():
        found.append(("RAPID", read_rapid_joints([main, *sorted(outdir.glob("curvslice_mod*.mod"))])))
    out = []
    for name, prog in found:
        same = len(prog["q"]) == len(rows["q"])
        dq = float(np.abs(prog["q"] - rows["q"]).max()) if same else np.inf
        dt = float(np.abs((prog["t"] - prog["t"][0]) - (rows["t"] - rows["t"][0])).max()) if same else np.inf
        ok = same and dq < 1e-6 and dt < 1e-6 and np.array_equal(prog["extruding"], rows["extruding"])
        out.append(Check(STAGE, f"{name} program matches joints.csv", ok,
                         f"Δq {dq:.1e} rad, Δt {dt:.1e} s" if same else f"{len(prog['q'])} vs {len(rows['q'])} rows"))
    return out
