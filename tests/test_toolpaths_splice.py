"""Splices of sibling rings (curvslice.toolpaths.spirals): a lobe of a layer joined to another across a neck
narrower than the first level's band is not spliced through it, where the links in and out would run along
the neck side by side."""

from __future__ import annotations

import numpy as np
import pytest
import shapely.geometry as sg
from shapely.ops import unary_union

from curvslice.toolpaths import layer_paths
from curvslice.toolpaths.constants import FIRST_LEVEL
from curvslice.verify.toolpaths import layer_cover
from test_toolpaths import polygon_mesh

WIDTH = 1.0


@pytest.mark.parametrize("neck, length, lobe", [(0.5, 1.5, 1.2), (0.8, 2.0, 2.0)])
def test_a_lobe_across_a_long_neck_is_not_spliced_through_it(neck, length, lobe):
    """Two discs (2.5 w and ``lobe`` w in radius) joined by a neck ``neck`` w wide -- under both rings at
    the first level, so the two are siblings -- and ``length`` w long, more than a width: at most one pass
    crosses the neck's middle (a splice ran its links in and out along it: two crossings, 1.5 and 2.9 %
    overlap on main dced594), and the layer stays covered."""
    assert neck < 2.0 * FIRST_LEVEL
    poly = unary_union([sg.Point(0, 0).buffer(2.5, 16), sg.Point(2.5 + length + lobe, 0).buffer(lobe, 16),
                        sg.box(2.3, -neck / 2, 2.7 + length, neck / 2)])
    mesh = polygon_mesh(poly, 0.1)
    result = layer_paths(mesh, WIDTH, min_bead=lambda p: np.full(len(p), 0.8 * WIDTH))
    middle = 2.5 + length / 2
    assert sum(int(np.sum(np.diff(np.sign(p[:, 0] - middle)) != 0)) for p in result.pieces) <= 1
    pos = np.vstack(result.pieces)
    piece = np.repeat(np.arange(len(result.pieces)), [len(p) for p in result.pieces])
    coverage, overlap = layer_cover(mesh, pos, piece, WIDTH, seed=1, bead=np.concatenate(result.widths))
    assert coverage >= 0.96 and overlap <= 0.015
