"""Continuous tool-paths on a curved working surface: connected Fermat spirals (thesis §3.5.1).

Per layer (thesis §3.3.2 "surface covering", §3.5.1, Fig. 3.9), one module per step:

1. the geodesic distance ``d`` from the layer boundary (:mod:`curvslice.geodesic`), scaled so
   that its contours lie a width apart in 3D (:func:`contour_gap`);
2. :mod:`~curvslice.toolpaths.rings`: iso-contours ("rings") of ``d`` at ``(k + 0.45)·w`` for
   path width ``w``, extracted on the mesh as closed polylines with the higher side on their left;
   every band between consecutive levels is split into connected *band components*, which gives
   the exact contour tree: a ring bounds one component below and one above;
3. :mod:`~curvslice.toolpaths.spirals`: connected Fermat spirals (Zhao et al., SIGGRAPH 2016, the
   thesis's ref. [2]): a chain of nested rings is cut (2-3 widths) near a common cut line and
   rerouted into one in-and-out spiral (inwards on rings 0, 2, 4, ..., outwards on 1, 3, 5, ...,
   both ends next to each other on the outer ring); where the contour tree branches, each child
   spiral is spliced into the ring that hosts it through a gap, so a connected region is one
   continuous piece unless a splice has no room (then the child becomes its own piece, counted
   as a jump);
4. :mod:`~curvslice.toolpaths.passes` and :mod:`~curvslice.toolpaths.beads`: every pass centred
   in the strip of surface nearest to it, with a bead as wide as that strip (:func:`fit_beads`:
   the passes tile the layer despite uneven spacing), ridge passes of thin walls
   (:func:`thin_passes`), gap passes where the widest beads still leave surface open
   (:func:`gap_passes`), redundant slivers dropped (:func:`needed_pieces`), beads widened over
   what the fit leaves past tips and corners (:func:`fill_slivers`), a loop's ends trimmed where
   their caps meet head-on (:func:`trim_seams`), self-crossings removed (:func:`uncross`);
5. :mod:`~curvslice.toolpaths.resampling`: re-sampling at ``step`` (1 mm in the thesis, §3.5.2),
   keeping sharp corners, bends and the bead width profile;
6. extrusion per segment from length × bead width × local layer thickness (volume
   conservation, :func:`curvslice.flow.filament_length`): a segment lays the mean of its ends'
   beads, or the width of an end wider than both its neighbours, short of the other passes' beads
   (:func:`extrusion_amounts`).

:mod:`~curvslice.toolpaths.plan` runs these per layer (:func:`layer_paths`) and over all layers
with orientations and thickness (:func:`plan_toolpaths`; each layer's spiral starts nearest the
part's seam point, or where the previous layer ended: :data:`START_RULES`), and writes the files
(:func:`save_toolpaths`); every tuning constant is in :mod:`~curvslice.toolpaths.constants`.
"""

from curvslice.toolpaths.beads import fill_slivers, fit_beads, needed_pieces, surface_samples, trim_seams
from curvslice.toolpaths.passes import gap_passes, thin_passes, uncross
from curvslice.toolpaths.plan import (START_RULES, LayerPaths, ToolpathSettings, Toolpaths, bridge_small_holes,
                                      clean_surface, layer_paths, plan_toolpaths, save_toolpaths)
from curvslice.toolpaths.resampling import extrusion_amounts, resample
from curvslice.toolpaths.rings import Bands, Ring, contour_gap, contour_rings, peak_rings, prune_islands

__all__ = ["START_RULES", "Bands", "LayerPaths", "Ring", "ToolpathSettings", "Toolpaths", "bridge_small_holes", "clean_surface",
           "contour_gap", "contour_rings", "extrusion_amounts", "fill_slivers", "fit_beads", "gap_passes",
           "layer_paths", "needed_pieces", "peak_rings", "plan_toolpaths", "prune_islands", "resample",
           "save_toolpaths", "surface_samples", "thin_passes", "trim_seams", "uncross"]
