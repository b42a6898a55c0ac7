"""Domain types shared by the planar cell tools and the program writers.

A :class:`RobotPath` is what :mod:`curvslice.cell` produces (from G-code, a draped design or a
levelled path) and what :mod:`curvslice.exporters` turns into RAPID, V+ or URScript; an
:class:`Event` is a non-motion command carried along with it. Keeping them here lets the cell
tools and the writers import them without importing each other upwards.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Event:
    """A non-motion command, happening before move ``index`` (the count of moves read so far)."""

    index: int
    line: int
    code: str
    params: dict[str, float]
    text: str


@dataclass
class RobotPath:
    """A Cartesian tool path in the robot's (work-object) frame, ready for a program writer.

    Row i is the straight move *to* ``positions[i]``; ``quaternions`` (w, x, y, z, unit) give the
    tool orientation there; ``speed`` is the TCP speed of the move (mm/s); ``extrusion`` the
    filament (mm) fed on it, negative for a retraction. ``events`` (dwell, temperatures, fans …)
    happen before the move ``event.index``.
    """

    positions: np.ndarray  # (N, 3) mm
    quaternions: np.ndarray  # (N, 4) w, x, y, z
    speed: np.ndarray  # (N,) mm/s
    extrusion: np.ndarray  # (N,) mm filament
    tool: np.ndarray  # (N,) int extruder index
    layer: np.ndarray  # (N,) int layer number (1-based)
    line: np.ndarray  # (N,) int source line (0 = none)
    home: np.ndarray  # (N,) bool: a homing move (joint move allowed)
    events: list[Event] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def extruding(self) -> np.ndarray:
        """(N,) bool: material is deposited on the move."""
        return self.extrusion > 0

    @property
    def retracted(self) -> np.ndarray:
        """(N,) bool: filament is retracted after the move (a negative E until the next positive E)."""
        sign = np.sign(self.extrusion)
        idx = np.maximum.accumulate(np.where(sign != 0, np.arange(len(sign)), -1))
        return np.where(idx >= 0, sign[np.maximum(idx, 0)] < 0, False)

    def events_at(self) -> dict[int, list[Event]]:
        """Events grouped by the move index they precede (index N = after the last move)."""
        grouped: dict[int, list[Event]] = {}
        for ev in self.events:
            grouped.setdefault(ev.index, []).append(ev)
        return grouped
