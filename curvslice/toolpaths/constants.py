"""Every tuning constant of the tool-path stage, with what it measures and why it has its value.

Lengths are in path widths ``w`` (:attr:`ToolpathSettings.path_width`, the nozzle diameter by
default), areas in ``w²``, angles in radians. The user's parameters (width, step, feed, tilt,
thickness clamps) are :class:`~curvslice.toolpaths.plan.ToolpathSettings`; what is here is
internal. The thesis fixes only the pattern -- iso-contours of the geodesic boundary distance
joined into Fermat spirals (§3.5.1, after Zhao et al., SIGGRAPH 2016, its ref. [2]) -- and the
1 mm re-sampling (§3.5.2); it names the medial-axis gaps of such spirals as a known limitation
(§3.7) and varies the deposit through the extrusion (§3.6.3: a 0.8 d layer "realized by
controlling the feedrate"). Everything else is ours: the README section "Choices the thesis leaves
open" states the choices, and the values below were measured on the kitten (0.8 mm) and bunny
(1.0 mm) layers against the verifier's per-layer limits (coverage >= 95 %, overlap <= 5 %; README
"Status"). A pure numerical guard (``1e-9``, ``1e-300``) stays inline where it is used.

Several constants are tied to each other; the ties are stated where they matter:
``OPEN_GAP - 0.5`` (0.15 w) is the hairline that does not count as open everywhere (gap passes,
sliver widening, the fault count of a refit, the rise of an uncovered peak), and the widest bead
``BEAD_RANGE[1]`` is ``2·THIN_REGION``, the widest region printed by one ridge pass.
"""

import numpy as np

# ----------------------------------------------------------------------------- layer (plan.layer_paths)

#: Holes of a layer narrower than this many widths (perimeter < π·BRIDGE_HOLE·w) are closed by a
#: fan before the distance field: every hole is a source of the boundary distance, and the
#: trimmed voxel layers carry many pin-holes one or two voxels (about a width) across that broke
#: the spirals into fragments (bunny). Three widths covers those with a margin; a bead bridges them.
BRIDGE_HOLE = 3.0
#: A layer mesh whose mean edge is longer than this many widths is subdivided once (1 → 4
#: triangles): the heat method's time step is the squared edge (its distance smooths over about
#: an edge) and the contours are straight within a triangle, so passes a width apart need edges
#: of half a width or less. The kitten's layers at 0.8 mm voxels (w = 1 mm) have mean edges of
#: 0.67-0.80 w and are subdivided.
SUBDIVIDE_EDGE = 0.5

# ----------------------------------------------------------------------------- rings (rings.py)

#: Level of the outermost contour: a little under the half width at which the bead's edge would
#: lie exactly on the boundary, so the bead still reaches a jagged layer boundary (the contour
#: smooths its voxel notches) and absorbs the distance field's error.
FIRST_LEVEL = 0.45
#: :func:`~curvslice.toolpaths.rings.contour_gap` within this of 1 is the measure's own error (a
#: flat square measures 0.995, a flat disc 1.007, where the true value is 1): the distance is left
#: unscaled. Voxel-built layers measure 0.95-0.99, outside it.
GAP_NOISE = 0.01
#: :func:`~curvslice.toolpaths.rings.contour_gap` measures the outermost this many levels: they
#: hold most of a layer's passes, and all levels cost too much on large layers (kitten layer 89:
#: 0.9520 over 5 levels vs 0.9521 over all; the bunny stage stays under 60 s).
GAP_LEVELS = 5
#: Spacing (widths) at which contours and passes are sampled to measure distances to them
#: (:func:`~curvslice.toolpaths.rings.contour_gap`, the thin-wall branches, the gap passes): the
#: nearest sample lies at most ``√(d² + (step/2)²) - d`` farther than the polyline, 0.0025 w at
#: d = 0.5 w, far below the 0.15 w hairline.
DENSE_STEP = 0.1
#: A ring around a peak of the distance that rises less than this many widths above its level is
#: dropped: along a ridge such peaks are islands of the distance field's noise, and the ring would
#: lay two passes less than half a width apart (more overlap than the gap it would fill).
ISLAND_RISE = 0.25
#: A peak left above its last ring gets one more contour (at the mid level) when it rises more than
#: this many widths above what that ring's bead covers (its level + half a width): less leaves a
#: strip at most 0.15 w beyond the bead, the hairline (``OPEN_GAP - 0.5``) that never counts as open.
PEAK_RISE = 0.15
#: A region that no ring bounds and whose distance peaks below this many widths -- narrower than
#: half a width -- gets one pass along its centre line instead of a loop: a loop's sides would lie
#: on top of each other.
SLIVER_TOP = 0.25
#: The centre line of a thin region averages its points in bins of this many widths along its main
#: axis: finer than half a bead would follow the voxel noise, coarser would cut its bends.
CENTRE_BIN = 0.5

#: :func:`~curvslice.toolpaths.rings.split_pinches`: two points of one ring are its two sides across
#: a pinch only when more than this many widths apart along it; nearer, they are the legs of a corner
#: (legs a width long, closer than the ~0.9 w pinch reach only at a spike sharper than 53°, itself a
#: peninsula).
PINCH_ALONG = 2.0
#: ... and a pinch is cut out only where its sides run close over at least this many widths: a centre
#: line's round caps meet the loops closed across its ends, which a shorter pinch does not repay (with
#: every ring cut, 1 w against 2 w: cow 0.8 layer 110 9.7 vs 8.2 %, kitten 0.8 layer 89 3.1 vs 2.9 %);
#: 3 w left most of the gain (rocker-arm 0.8 layer 82: 4.9 vs 2.6 %, layer 125: 3.8 vs 2.1 %).
PINCH_LENGTH = 2.0

# ----------------------------------------------------------------------------- Fermat spirals (spirals.py)

#: Rings shorter than this many widths (about 1.3 w across) are printed as one short bead along
#: their diameter: a loop that small would lay its bead over itself all round. (Keeping broad lone
#: rings as loops helped rocker-arm 0.8 layer 98 but failed the needle's tip and fertility 0.8 layer
#: 133 on overlap: measured and dropped.)
DOT_RING = 4.0
#: A ring is round, and its inside reaches as far as the distance rises above it, when its
#: isoperimetric ratio 4π·area / length² is at least this (a disc 1, a strip of aspect 1:5 0.44);
#: an elongated ring reaches half its mean breadth, whatever one bulge rises to
#: (:attr:`~curvslice.toolpaths.rings.Ring.rise`). Which loops are thin is no constant: it follows
#: from the layer thickness (:func:`~curvslice.toolpaths.rings.thin_rise`).
ROUND_RING = 0.5
#: A lone ring (a spiral of one ring) rising less than this many widths is a thin loop whatever the
#: layer thickness (the rule of :func:`~curvslice.toolpaths.rings.thin_rise` at the default
#: thickness 0.8 w): where layers are thinner, the fitted beads of its two sides still overlap when
#: they lie closer than 0.6 w (bunny 1.0 mm layer 84, thickness 0.43 w: 9.6 % overlap as a loop).
THIN_LOOP = 0.3
#: Cut of a Fermat spiral (§3.5.1; Zhao et al. 2016): each ring of a chain of three or more opens
#: over ``length / CUT_SHARE``, clipped to ``CUT_RANGE`` widths (two-ring chains open over the
#: smaller). The links in and out of the spiral cross the rings there and lie
#: ``(g/2)·2w/√(4w² + g²)`` apart for a cut ``g``: 0.71 w at g = 2 w, 0.83 w at 3 w, so long rings
#: (from 18 w) open wider and their links overlap less; a wider cut would leave a visible notch
#: (README "Choices the thesis leaves open", "Spiral cut").
CUT_RANGE = (2.0, 3.0)
CUT_SHARE = 6.0
#: A root spiral's cut line (:meth:`~curvslice.toolpaths.spirals._Builder.cut_line`) where the one
#: nearest to the start meets a ring at a corner: the innermost ring's points this many widths apart
#: are tried as its start (a quarter of the narrowest cut, ``CUT_RANGE[0]``: the cut line's points on
#: the rings move about as far, a fraction of the straight stretch the corners leave between them).
CUT_STEP = 0.5
#: A child spiral is spliced into its host ring at the host point nearest to it or, where that
#: leaves no room (a cut away from the walk's ends and two cuts from other splices), at shifts of
#: ±SPLICE_SHIFT, ±2·SPLICE_SHIFT, ... up to ±SPLICE_SHIFTS·SPLICE_SHIFT widths (±4 w): half-width
#: steps are a quarter of the shortest cut, and ±4 w is two cuts either way.
SPLICE_SHIFT = 0.5
SPLICE_SHIFTS = 8
#: A child whose nearest point lies more than this many widths from its host ring is printed as a
#: piece of its own (a jump) instead of spliced: nested rings lie a width apart, and a longer link
#: would cross surface that other passes print.
SPLICE_REACH = 3.0

# ----------------------------------------------------------------------------- passes (passes.py)

#: A connected region whose largest boundary distance is below this many widths (narrower than
#: ``2·THIN_REGION`` widths) is printed as one pass along its ridge with the bead as wide as the
#: region: a loop there would lay its two sides less than a width apart, a centre pass of one width
#: would leave both edges open (the §3.7 medial-axis gap; bunny layers over 5 % overlap 57 → 24).
THIN_REGION = 0.8
#: Narrowest bead of such a pass, in widths: a bead much narrower than the nozzle is not laid
#: reliably by flow alone, so a thinner region is over-filled rather than skipped.
BEAD_MIN = 0.5
#: A thin region whose ridge is shorter than this many widths is a blob (about as long as it is
#: wide, under 1.6 w), left to the contours, which ring or dot it.
WALL_LENGTH = 2.0
#: Rounds of ridge passes through the branches of a thin region that earlier ridges leave open (a
#: Y or a comb takes one round per level of branching; what a third round leaves is left to the
#: gap passes).
BRANCH_ROUNDS = 3
#: The ridge of a thin region is a shortest path over edges of cost ``length / d²``, the mean
#: ``d`` of an edge floored at this many widths, so edges along the boundary (``d = 0``) stay finite
#: but cost 100 times an edge at half a width.
RIDGE_FLOOR = 0.05
#: A ridge pass's bead is twice the largest distance ``d`` within this many widths of each of its
#: points: the edge path runs beside the true ridge by up to half a bead.
RIDGE_REACH = 0.5
#: Vertices of a thin region more than this many widths beyond the edge of the ridge passes' beads
#: are left for a further ridge (a branch); nearer ones are the bead's own fringe.
BRANCH_MARGIN = 0.25
#: A surface point more than ``OPEN_GAP - 0.5`` (0.15) widths beyond the edge of every bead is
#: open: with beads of one width, ``OPEN_GAP`` widths from every path. A strip between two beads
#: is then open only when wider than 0.3 w: a narrower hairline would take a bead of at least
#: ``BEAD_MIN`` (0.5 w) and overlap its neighbours by more than it fills.
OPEN_GAP = 0.65
#: A patch of open vertices gets a gap pass when it has at least this many vertices and its sliver --
#: its longest path plus the hairline (``OPEN_GAP - 0.5``) the patch leaves out along the beads -- is at
#: least GAP_PASS_LENGTH widths: down to the tips of a layer that its outermost contour cuts short,
#: not the single open vertices of a bead's ragged edge.
GAP_PASS_VERTICES = 3
GAP_PASS_LENGTH = 0.5
#: Passes whose ends lie closer than this many widths are joined into one
#: (:func:`~curvslice.toolpaths.passes.join_touching`): half the narrowest bead, so their caps would
#: overlap by more than half of it, while the joining link stays within the cap it replaces.
JOIN_GAP = 0.5 * BEAD_MIN
#: A segment of a pass leaves its layer when a point along it lies farther than this many widths from the
#: layer (its closest point): a straight link between rings across a fold or a notch of the layer, laid through the air
#: (:func:`~curvslice.toolpaths.passes.split_off_layer`). A link's chord over a layer curved to a radius of
#: two widths sags by 0.3 w over its longest, 3 w.
OFF_LAYER = 0.5
#: :func:`~curvslice.toolpaths.passes.uncross`: two segments cross when they come within
#: ``CROSS_GAP`` widths of each other at inner points, more than ``CROSS_ANGLE`` apart (neighbouring
#: passes that touch at a shallow angle are not a crossing); candidate pairs lie within the
#: ``CROSS_PERCENTILE`` percentile of segment lengths, the few longer links (ring to ring, into a
#: spliced child) are checked against everything near them; at most ``UNCROSS_ROUNDS`` rounds (each
#: shortens the path, so it ends; the bound only caps a pathological case).
CROSS_GAP = 0.01
CROSS_ANGLE = float(np.radians(15.0))
CROSS_PERCENTILE = 99.0
UNCROSS_ROUNDS = 100

# ----------------------------------------------------------------------------- beads (beads.py)

#: Bead widths the extruder lays by flow alone, in widths (narrowest, widest): the width is set
#: through the extrusion, the lever the thesis uses for the layer thickness (§3.6.3); the widest is
#: the widest region a ridge pass prints alone (README "Bead widths": 0.5-1.6 path widths).
BEAD_RANGE = (BEAD_MIN, 2.0 * THIN_REGION)
#: :func:`~curvslice.toolpaths.beads.fit_beads`: spacing of the fitted pass points and of the
#: boundary samples (widths; a tenth of a bead resolves its caps and corners); surface area per
#: lattice sample (w²: about 0.14 w apart, seven across a strip of one width, so the farthest
#: sample lies near the strip's edge); half-window of the running max / min / mean in pass points
#: (±0.3 w, under a bead: the bead follows its strip without the samples' noise; the layer normal
#: averages over twice as many).
FIT_STEP = 0.1
FIT_SAMPLE = 0.02
FIT_HALF = 3
#: Added to each side of a fitted strip (widths): even the lattice's farthest sample falls short of
#: the strip's edge. (:func:`~curvslice.toolpaths.beads.fill_slivers` keeps none: two beads it widens meet
#: at the halfway line between them, where a margin either side left a hairline 0.02 w wide along every
#: pair of passes it widened -- bunny 1.0 layer 44: 95.5 -> 95.9 % without it.)
FIT_MARGIN = 0.01
#: A fitted pass moves at most this many widths sideways onto its strip: passes lie about a width
#: apart, so a larger shift would take over a neighbour's strip. Also what a kept pass may shift to
#: take over a dropped one's samples (:func:`~curvslice.toolpaths.beads.needed_pieces`).
MAX_SHIFT = 0.5
#: Pieces shorter than this many widths are dropped when the other beads already cover them more
#: than they alone do: the slivers and dots of tiny layers, where every bead is at least as wide
#: as the layer is thick (README "Which passes to print").
REDUNDANT_LENGTH = 4.0
#: Share of a layer that a short gap pass must cover on its own to be worth its jump, and that a
#: refit may lose before the take-over is undone: the share the per-layer coverage measure can
#: notice with its 10,000 samples (tip passes covering less had added ~20 % pieces and jumps for
#: almost no coverage: kitten 359 → 441 pieces).
MINOR_SHARE = 0.005
#: :func:`~curvslice.toolpaths.beads.fill_slivers` widens a bead towards the bead of any other pass:
#: another piece, or the same piece more than this many beads (at least widths) away along it --
#: a spiral's next ring, not the bead's own continuation.
SAME_PASS_BEADS = 2.0
#: :func:`~curvslice.toolpaths.beads.trim_seams`: the chord between a loop's two ends, in beads, at
#: which their round caps cover as much surface twice (the lens where they meet) as they leave open
#: (the wedges beside it). On a strip of bead ``b``, ends ``d`` apart: the caps' two half-discs,
#: ``π b²/4``, fill the strip between the ends, ``d·b``, less the open wedges plus the lens, so the two
#: are equal at ``d = (π/4)·b`` -- where the caps' material is exactly what the strip between them
#: takes (a bead apart, the caps touch and leave ``(1 - π/4)·b²`` open; at 0.6 b the lens is 0.19 b²
#: larger than the wedges).
SEAM_CHORD = float(np.pi / 4.0)
#: :func:`~curvslice.toolpaths.beads.trim_ends`: a bead lies ahead of a pass end when it lies within this
#: angle (rad) of the end's direction; beside it (a parallel pass, 90°) trimming the end would not help.
AHEAD_ANGLE = float(np.pi / 3.0)
#: How deep (in its beads) a pass end's round cap may run into the bead ahead of it: where a cap of
#: radius r ends h from a straight bead side, moving it on opens b·dh of the strip behind and covers
#: 2·sqrt(r² − h²)·dh twice, so open + twice-covered area is least at h = (√3/2)·r: the cap runs
#: (1 − √3/2)·r = 0.067 b in (:func:`~curvslice.toolpaths.beads.trim_ends`; cf. ``SEAM_CHORD``).
END_DEPTH = float((1.0 - np.sqrt(3.0) / 2.0) / 2.0)

# ----------------------------------------------------------------------------- re-sampling (resampling.py)

#: Sharp corners (turn above this angle) are kept as samples when re-sampling at the 1 mm step
#: (§3.5.2): a chord with its ends half a step from a corner of turn θ passes ``(step/2)·sin(θ/2)``
#: from it: 0.13 mm at 30° and 1 mm, under the 0.15 w hairline at the default width (1 mm).
CORNER_ANGLE = np.radians(30.0)
#: Re-sampling of the fitted passes: a bead width change counts this many times its size as path
#: length, so a cap or a narrowing keeps its samples and is not averaged away over a 1 mm step
#: (small layers lost 2-4 % coverage there).
WIDTH_WEIGHT = 5.0
#: Re-sampling of the fitted passes: a radian of turn counts as this many widths of path length, so
#: a bend keeps its samples and the 1 mm chords do not cut the corners of wavy passes (half a width:
#: 16 % fewer samples than one width for 0.2 % of coverage on kitten layer 89, keeping the bunny's
#: stage under 60 s).
TURN_WEIGHT = 0.5

# ----------------------------------------------------------------------------- orientation (plan.py)

#: Final guard on the orientation's angle to the layer normal, after the low-pass (§3.5.2): the
#: smoothing may tilt a sample past ``ToolpathSettings.max_tilt``; under 90° it never points into
#: the printed side (no sample of the kitten or bunny does).
HARD_TILT = float(np.radians(85.0))
#: The closest point under a sample on the earlier layers (Eq. 3.3) is searched on the triangles
#: of this many nearest centroids per layer (the verifier recomputes it exactly); the vertices'
#: thickness, only the floor of the bead width, uses ``FLOOR_CANDIDATES``.
THICKNESS_CANDIDATES = 12
FLOOR_CANDIDATES = 3
