"""Continuous tool-paths on curved working surfaces: connected Fermat spirals (thesis §3.5.1).

The stage by concern; the public names are re-exported here, so ``from curvslice.toolpaths
import X`` works for all of them.
"""

from curvslice.toolpaths.plan import (Bands, LayerPaths, Ring, ToolpathSettings, Toolpaths, bridge_small_holes,
                                      clean_surface, contour_gap, contour_rings, extrusion_amounts, fill_slivers,
                                      fit_beads, gap_passes, layer_paths, needed_pieces, peak_rings, plan_toolpaths,
                                      prune_islands, resample, save_toolpaths, surface_samples, thin_passes, uncross)

__all__ = ["Bands", "LayerPaths", "Ring", "ToolpathSettings", "Toolpaths", "bridge_small_holes", "clean_surface",
           "contour_gap", "contour_rings", "extrusion_amounts", "fill_slivers", "fit_beads", "gap_passes",
           "layer_paths", "needed_pieces", "peak_rings", "plan_toolpaths", "prune_islands", "resample",
           "save_toolpaths", "surface_samples", "thin_passes", "uncross"]
