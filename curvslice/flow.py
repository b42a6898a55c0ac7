"""Flow models that turn nozzle motion into extruder motion and bead geometry.

Syringe (paste) extrusion after seed 003 (Heuser): volume conservation between plunger and
nozzle, stepper steps from the actuator's travel per step, strand width for a rectangular and a
rounded (stadium) strand cross-section, and scaffold pore size from the infill density.
Filament (FDM) extrusion after seed 004 (Huygens, Eqs. 4-6), with the bead modelled as the
stadium that slicers use instead of the seed's rectangle of nozzle width. All lengths in mm,
speeds in mm/s; works on scalars and numpy arrays alike.
"""

from __future__ import annotations

import numpy as np

from curvslice.errors import CurvsliceError

MM_PER_INCH = 25.4


def plunger_speed(nozzle_speed, r_nozzle, r_syringe):
    """Plunger speed = nozzle speed × r_nozzle² / r_syringe² (seed 003, volume extrusion)."""
    return np.asarray(nozzle_speed, dtype=float) * (np.asarray(r_nozzle, float) / np.asarray(r_syringe, float)) ** 2


def steps_per_second(speed, mm_per_step):
    """Stepper rate for a linear ``speed`` (mm/s): steps/s = mm/s × steps/mm (seed 003).

    For an actuator rated in inches per step pass ``in_per_step * MM_PER_INCH``.
    """
    if np.any(np.asarray(mm_per_step) <= 0):
        raise CurvsliceError("actuator travel per step must be positive")
    return np.asarray(speed, dtype=float) / np.asarray(mm_per_step, float)


def _strand_inputs(nozzle_diameter, layer_height):
    d = np.asarray(nozzle_diameter, dtype=float)
    h = np.asarray(layer_height, dtype=float)
    if np.any(d <= 0) or np.any(h <= 0):
        raise CurvsliceError("nozzle diameter and layer height must be positive")
    return np.pi * d**2 / 4, h


def strand_width_rectangle(nozzle_diameter, layer_height):
    """Strand width if the nozzle's circular section is squashed into a rectangle of the layer height.

    W = A₀ / H with A₀ = πR² (seed 003: W = πR / 2h for H = 2Rh).
    """
    area, h = _strand_inputs(nozzle_diameter, layer_height)
    return area / h


def strand_width_stadium(nozzle_diameter, layer_height):
    """Strand width for a rounded strand: a rectangle with half-discs of diameter H at both sides.

    W = (A₀ − πH²/4) / H + H (seed 003: W = ((π − πh²)/2h + 2h) R). Needs H ≤ nozzle diameter,
    otherwise the section would have to be narrower than tall.
    """
    area, h = _strand_inputs(nozzle_diameter, layer_height)
    if np.any(h > np.asarray(nozzle_diameter, float)):
        raise CurvsliceError("the stadium strand model needs a layer height no larger than the nozzle diameter")
    return (area - np.pi * h**2 / 4) / h + h


def pore_size(strand_width, infill_density):
    """Pore size p between strands of width s at infill density D = s / (s + p) (seed 003)."""
    dens = np.asarray(infill_density, dtype=float)
    if np.any(dens <= 0) or np.any(dens > 1):
        raise CurvsliceError("infill density must be in (0, 1]")
    return np.asarray(strand_width, float) * (1 - dens) / dens


def bead_area(width, height):
    """Cross-section of an FDM bead of ``width`` × ``height``: a stadium, h·(w − h) + π(h/2)².

    Replaces seed 004's rectangle ``D_n × h`` (Eq. 4), which over-estimates the bead by
    (1 − π/4)h² and ignores that beads are wider than the nozzle.
    """
    w = np.asarray(width, dtype=float)
    h = np.asarray(height, dtype=float)
    if np.any(h <= 0) or np.any(w < h):
        raise CurvsliceError("a bead needs a positive height no larger than its width")
    return h * (w - h) + np.pi * h**2 / 4


def filament_length(path_length, width, height, filament_diameter=1.75, flow_multiplier=1.0):
    """Filament (E, mm) for a bead of ``path_length``: volume conservation F·A = U·A_bead (seed 004 Eq. 4)."""
    return flow_multiplier * np.asarray(path_length, float) * bead_area(width, height) / (
        np.pi * np.asarray(filament_diameter, float) ** 2 / 4
    )


def feed_speed(head_speed, width, height, filament_diameter=1.75, flow_multiplier=1.0):
    """Filament feed speed (mm/s) for a print-head speed (mm/s): seed 004 Eq. 5 with the stadium bead."""
    return filament_length(head_speed, width, height, filament_diameter, flow_multiplier)
