"""Rings cut where they pinch (curvslice.toolpaths.rings.split_pinches): a peninsula of a layer
narrower than two beads gets one pass down its middle, not a ring's two sides over each other; a neck
between two wide lobes is left to its ring."""

from __future__ import annotations

import numpy as np
import pytest
import shapely.geometry as sg
from scipy.spatial import cKDTree
from shapely.ops import unary_union

from curvslice.toolpaths.constants import DENSE_STEP, PINCH_ALONG
from curvslice.toolpaths.plan import layer_rings
from curvslice.toolpaths.resampling import resample
from curvslice.toolpaths.rings import thin_rise
from test_toolpaths import polygon_mesh

WIDTH = 1.0
FLOOR = 1.0  # the layer thickness: no bead narrower than one width
#: a neck (a peninsula) 3.6 w wide: the rings at 0.45 w run along both its edges and the ring at
#: 1.45 w runs through it twice, its sides 0.7 w apart, so each side's bead owns 0.35 + 0.5 = 0.85 w of
#: strip between its neighbours but is laid at least 1 w wide
NECK = 3.6
SHAPES = {
    "neck": unary_union([sg.box(0, 0, 8, 8), sg.box(14, 0, 22, 8), sg.box(7, 4 - NECK / 2, 15, 4 + NECK / 2)]),
    "peninsula": unary_union([sg.box(0, 0, 10, 10), sg.box(9, 5 - NECK / 2, 17, 5 + NECK / 2)]),
}
CROSS_X = 11.0


def _crossings(polyline: np.ndarray, x: float, closed: bool) -> int:
    p = np.vstack([polyline, polyline[:1]]) if closed else polyline
    side = np.sign(p[:, 0] - x)
    return int(np.sum(side[1:] * side[:-1] < 0))


def _floor(points: np.ndarray) -> np.ndarray:
    return np.full(len(points), FLOOR * WIDTH)


def test_a_neck_is_left_to_its_ring():
    """Both loops of the neck's inner ring are wide: cut, the far one would be a region of its own."""
    r = layer_rings(polygon_mesh(SHAPES["neck"], 0.2), WIDTH, _floor)
    assert sum(_crossings(g.points, CROSS_X, True) for g in r.rings) == 4 and not r.lines


@pytest.mark.parametrize("shape", ["peninsula"])
def test_a_pinch_gets_one_pass_and_no_ring_lies_over_itself(shape, monkeypatch):
    """Across the middle of the peninsula three passes run -- the outer ring's two sides along
    its edges and one down its middle: the crossings of that section by the rings and centre lines,
    counted on their geometry -- and no ring's two sides (points more than ``PINCH_ALONG`` widths
    apart along it) come closer than twice the thin-loop rise of the floor, the spacing below which
    their beads overlap. Without the cut the inner ring runs through twice (four passes)."""
    mesh = polygon_mesh(SHAPES[shape], 0.2)

    def passes():
        r = layer_rings(mesh, WIDTH, _floor)
        return r, sum(_crossings(g.points, CROSS_X, True) for g in r.rings) + sum(
            _crossings(line, CROSS_X, False) for line in r.lines)

    r, through = passes()
    assert through == 3
    reach = 2.0 * thin_rise(FLOOR, WIDTH)
    for ring in r.rings:
        q = resample(np.vstack([ring.points, ring.points[:1]]), DENSE_STEP * WIDTH)[:-1]
        s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))]
        pairs = cKDTree(q).query_pairs(reach - 0.05 * WIDTH, output_type="ndarray")
        along = np.abs(s[pairs[:, 0]] - s[pairs[:, 1]]) if len(pairs) else np.zeros(0)
        along = np.minimum(along, ring.length - along)
        assert not np.any(along > PINCH_ALONG * WIDTH + 0.2 * WIDTH), "a ring's sides lie closer than their beads"
    monkeypatch.setattr("curvslice.toolpaths.plan.split_pinches", lambda rings, width, min_bead: (rings, []))
    assert passes()[1] == 4  # the control: the inner ring's two sides
