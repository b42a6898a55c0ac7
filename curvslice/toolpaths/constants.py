"""Tuning constants of the tool-path stage, in path widths unless said otherwise (thesis §3.5.1)."""

import numpy as np

#: Rings shorter than this many path widths are printed as one short bead along their diameter.
DOT_RING = 4.0
#: A lone ring whose inside is narrower than this many widths (:attr:`Ring.breadth`) is printed as
#: one pass along its centre line: its region, ``2·FIRST_LEVEL`` widths wider, takes one bead of at most
#: ``BEAD_RANGE[1]`` widths, while its two sides would lie closer than a bead.
THIN_RING = 0.6
#: A mesh vertex more than ``OPEN_GAP - 0.5`` path widths beyond the edge of every bead is open (a
#: gap): with beads of one width, this many widths from every path; hairlines do not count.
OPEN_GAP = 0.65
#: Level of the outermost contour in path widths: a little under half a width, so the bead still
#: reaches a jagged layer boundary (the contour smooths its notches) and the distance field's error.
FIRST_LEVEL = 0.45
#: Final guard on the orientation's angle to the layer normal, after smoothing (radians).
HARD_TILT = float(np.radians(85.0))
#: Holes of a layer narrower than this many path widths (perimeter < π·BRIDGE_HOLE·w) are bridged.
BRIDGE_HOLE = 3.0
#: Sharp corners (turn above this angle, radians) are kept as samples when re-sampling.
CORNER_ANGLE = np.radians(30.0)
#: A connected region whose largest boundary distance is below this many path widths (narrower
#: than 2·THIN_REGION widths) is printed as one pass along its ridge with the bead as wide as the region
#: (a loop there would lay its two sides less than a width apart, a centre pass of one width
#: would leave both edges open).
THIN_REGION = 0.8
#: Narrowest bead of such a pass, in path widths (a thinner region is over-filled, not skipped).
BEAD_MIN = 0.5
#: A thin region whose ridge is shorter than this many widths is a blob, left to the contours.
WALL_LENGTH = 2.0
#: Rounds of ridge passes through the branches of a thin region that earlier ridges leave open.
BRANCH_ROUNDS = 3
#: Bead widths the extruder lays by flow alone, in path widths (narrowest, widest): see :func:`fit_beads`.
BEAD_RANGE = (BEAD_MIN, 2.0 * THIN_REGION)
#: :func:`fit_beads`: spacing of the fitted pass points and of the boundary samples (widths), surface
#: area per lattice sample (widths²), half-window of the running max / min / mean in pass points
#: (the normal uses twice as many).
FIT_STEP = 0.1
FIT_SAMPLE = 0.02
FIT_HALF = 3
#: Pieces shorter than this many widths are dropped when the other beads already cover them.
REDUNDANT_LENGTH = 4.0
#: Share of a layer that a short gap pass must cover on its own to be worth its jump.
MINOR_SHARE = 0.005
#: Re-sampling of the fitted passes: a bead width change counts this many times its size as path
#: length, so a cap or a narrowing is not averaged away over a 1 mm step (:func:`resample`).
WIDTH_WEIGHT = 5.0
#: Added to each side of a fitted strip (widths): the lattice samples still fall short of its edge.
FIT_MARGIN = 0.01
#: Re-sampling of the fitted passes: a radian of turn counts as this many widths of path length,
#: so a bend keeps its samples and the 1 mm chords do not cut the corners of wavy passes.
TURN_WEIGHT = 0.5
#: Cut of a Fermat spiral (thesis §3.5.1; Zhao et al. 2016): each ring of a chain of three or more
#: opens over ``length / CUT_SHARE``, between ``CUT_RANGE`` widths; the links in and out of the
#: spiral cross the rings there, ``(g/2)·2w/√(4w² + g²)`` apart (0.71 w at g = 2 w, 0.83 w at 3 w).
CUT_RANGE = (2.0, 3.0)
CUT_SHARE = 6.0
#: :func:`contour_gap` within this of 1 is the measure's own error (a flat square 0.995, a flat
#: disc 1.007): the distance is left as it is.
GAP_NOISE = 0.01
GAP_LEVELS = 5
