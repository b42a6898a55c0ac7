"""Adept V+ programs from a Cartesian tool path (seed 003, Heuser: "G-code → V+, Arduino").

The G-code is read twice (seed 003, "parsed twice, first to find all speeds"): the first pass
(:func:`speed_inventory`) lists every (extruder, speed) pair that extrudes and gives each a binary
pattern on the controller's output signals, which the Arduino sketch
(:mod:`curvslice.exporters.arduino`) decodes into a stepper speed; the second pass writes
``SPEED v MMPS ALWAYS``, ``MOVE TRANS(x,y,z,y,p,r)`` and ``SIGNAL`` lines. V+ runs ahead of the
robot (forward processing), so every signal change first waits for the motion
(``WAIT STATE(2) == 2``, as the seed did). Dwell (G4) becomes ``DELAY``; other machine events
become ``;`` comments.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from curvslice.cell.cells import VplusIO
from curvslice.errors import CurvsliceError
from curvslice.exporters import check_robot_path, compact, event_text, fixed, parse_event_text
from curvslice.robot_path import Event, RobotPath

_SPEED = re.compile(r"^\s*SPEED\s+([-+0-9.]+)\s+MMPS\s+ALWAYS", re.IGNORECASE)
_MOVE = re.compile(r"^\s*MOVES?\s+TRANS\(([^)]*)\)", re.IGNORECASE)
_SIGNAL = re.compile(r"^\s*SIGNAL\s+(.+)$", re.IGNORECASE)
_DELAY = re.compile(r"^\s*DELAY\s+([-+0-9.]+)", re.IGNORECASE)
_COMMENT = re.compile(r"^\s*;\s?(.*)$")

#: Speeds equal to this many decimals (mm/s) share one extruder pattern.
SPEED_DECIMALS = 3


def speed_inventory(path: RobotPath) -> list[tuple[int, float]]:
    """First pass: the distinct (extruder, speed mm/s) pairs of extruding moves, in order of use.

    Pattern k (1-based) of the returned list is signalled as the binary number k.
    """
    seen: dict[tuple[int, float], None] = {}
    for tool, speed in zip(path.tool[path.extruding], np.round(path.speed[path.extruding], SPEED_DECIMALS)):
        seen.setdefault((int(tool), float(speed)), None)
    return list(seen)


def signal_count(patterns: int, io: VplusIO) -> int:
    """Signals needed to tell ``patterns`` patterns and "off" apart; checks the cell's maximum."""
    bits = max(1, math.ceil(math.log2(patterns + 1)))
    allowed = min(io.max_signals, len(io.signals))
    if bits > allowed:
        raise CurvsliceError(
            f"{patterns} (extruder, speed) patterns need {bits} controller signals but the cell allows {allowed} "
            f"(raise vplus.max_signals / list more vplus.signals, or use fewer distinct speeds)"
        )
    return bits


def signal_line(code: int, signals: tuple[int, ...], bits: int) -> str:
    """``SIGNAL 1, -2, …``: output signals[b] on where bit b of ``code`` is set."""
    return "SIGNAL " + ", ".join(f"{s}" if (code >> b) & 1 else f"-{s}" for b, s in enumerate(signals[:bits]))


def zyz_degrees(quaternions: np.ndarray) -> np.ndarray:
    """V+ orientation (yaw, pitch, roll) in degrees: R = Rz(yaw) Ry(pitch) Rz(roll).

    At pitch 0 or 180° (gimbal lock) yaw is set to 0 and the whole turn goes to roll.
    """
    w, x, y, z = np.moveaxis(np.asarray(quaternions, float), -1, 0)
    r13 = 2 * (x * z + w * y)
    r23 = 2 * (y * z - w * x)
    r33 = 1 - 2 * (x * x + y * y)
    r31 = 2 * (x * z - w * y)
    r32 = 2 * (y * z + w * x)
    r21 = 2 * (x * y + w * z)
    r22 = 1 - 2 * (x * x + z * z)
    s = np.hypot(r13, r23)
    pitch = np.arctan2(s, r33)
    lock = s < 1e-9
    yaw = np.where(lock, 0.0, np.arctan2(r23, r13))
    # locked: R = Rz(roll) (pitch 0) or Ry(180°) Rz(roll) (pitch 180°); both have row 2 = [sin, cos, 0]
    roll = np.where(lock, np.arctan2(r21, r22), np.arctan2(r32, -r31))
    return np.degrees(np.stack([yaw, pitch, roll], axis=-1))


def zyz_quaternions(ypr_degrees: np.ndarray) -> np.ndarray:
    """Inverse of :func:`zyz_degrees`: unit quaternions (w, x, y, z) of Rz(yaw) Ry(pitch) Rz(roll)."""
    a, b, c = np.moveaxis(np.radians(np.asarray(ypr_degrees, float)), -1, 0)
    # product of the half-angle quaternions qz(a) qy(b) qz(c)
    cb, sb = np.cos(b / 2), np.sin(b / 2)
    return np.stack(
        [cb * np.cos((a + c) / 2), -sb * np.sin((a - c) / 2), sb * np.cos((a - c) / 2), cb * np.sin((a + c) / 2)],
        axis=-1,
    )


def write_vplus(
    path: Path, robot: RobotPath, patterns: list[tuple[int, float]], io: VplusIO, program: str = "curvslice"
) -> None:
    """Second pass: the V+ program. ``patterns`` comes from :func:`speed_inventory`."""
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9._]{0,14}", program):
        raise CurvsliceError(f"V+ program name {program!r}: use a letter then letters, digits, . or _ (≤ 15)")
    check_robot_path(robot, "V+ writer")
    bits = signal_count(len(patterns), io)
    code_of = {p: k for k, p in enumerate(patterns, start=1)}
    ypr = zyz_degrees(robot.quaternions)
    speeds = np.round(robot.speed, SPEED_DECIMALS)
    events = robot.events_at()
    lines = [f".PROGRAM {program}();"]
    speed, code = None, 0
    for i in range(len(robot) + 1):
        for ev in events.get(i, []):
            if ev.code == "G4":
                lines.append(f"    DELAY {fixed(ev.params['seconds'], 3)}")
            else:
                lines.append(f"    ; {event_text(ev)}")
        if i == len(robot):
            break
        if speeds[i] != speed:
            speed = speeds[i]
            lines.append(f"    SPEED {fixed(speed, SPEED_DECIMALS)} MMPS ALWAYS")
        want = code_of[(int(robot.tool[i]), float(speeds[i]))] if robot.extruding[i] else 0
        if want != code:
            code = want
            lines += ["    WAIT STATE(2) == 2", f"    {signal_line(code, io.signals, bits)}"]
        x, y, z = (fixed(v, 3) for v in robot.positions[i])
        yaw, pitch, roll = (compact(v, 3) for v in ypr[i])
        lines.append(f"    {io.motion} TRANS({x},{y},{z},{yaw},{pitch},{roll})")
    if code:
        lines += ["    WAIT STATE(2) == 2", f"    {signal_line(0, io.signals, bits)}"]
    lines.append(".END")
    Path(path).write_text("\n".join(lines) + "\n")


def read_vplus(path: Path, signals: tuple[int, ...] = VplusIO().signals) -> dict[str, object]:
    """Read a program of :func:`write_vplus`: ``positions`` (N,3), ``quaternions`` (N,4),
    ``speed`` (N,), ``pattern`` (N,) signal code while moving (0 = extruder off), ``events``."""
    pos, ypr, speed, pattern, events = [], [], [], [], []
    current_speed, code = 0.0, 0
    bit_of = {s: b for b, s in enumerate(signals)}
    for line in Path(path).read_text().splitlines():
        if m := _SPEED.match(line):
            current_speed = float(m[1])
        elif m := _MOVE.match(line):
            values = [float(v) for v in m[1].split(",")]
            pos.append(values[:3])
            ypr.append(values[3:6])
            speed.append(current_speed)
            pattern.append(code)
        elif m := _SIGNAL.match(line):
            for word in m[1].split(","):
                s = int(word)
                bit = bit_of[abs(s)]
                code = code | (1 << bit) if s > 0 else code & ~(1 << bit)
        elif m := _DELAY.match(line):
            events.append(Event(len(pos), 0, "G4", {"seconds": float(m[1])}, ""))
        elif (m := _COMMENT.match(line)) and (ev := parse_event_text(m[1], len(pos))):
            events.append(ev)
    return {
        "positions": np.asarray(pos, float).reshape(-1, 3),
        "quaternions": zyz_quaternions(np.asarray(ypr, float).reshape(-1, 3)),
        "speed": np.asarray(speed, float),
        "pattern": np.asarray(pattern, np.int64),
        "events": events,
    }
