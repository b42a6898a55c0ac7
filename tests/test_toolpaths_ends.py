"""Tool-path ends (issue 18): a lone dot's pass covers its blob whatever its shape, so does a lone round thin
loop's whatever its turn, and a pass end stops where its round cap touches the bead of another pass."""

from __future__ import annotations

import numpy as np
import pytest
import shapely.affinity
import shapely.geometry as sg

from curvslice.toolpaths import layer_paths
from curvslice.toolpaths.beads import trim_ends
from curvslice.toolpaths.constants import DOT_RING, END_DEPTH
from curvslice.verify.toolpaths import layer_cover
from test_toolpaths import polygon_mesh

#: a lone blob 2.2 × 1.5 widths (rocker-arm 0.8 layer 98's, in widths): a sharp corner and a slanted side
PENTAGON = [(-1.07, 0.24), (-0.51, -1.48), (0.61, -0.57), (1.13, 0.03), (0.44, 0.54), (-0.71, 0.52)]


@pytest.mark.parametrize("shape", ["pentagon", "pentagon turned", "octagon"])
def test_a_lone_dot_pass_covers_its_blob(shape):
    """A lone dot (one ring shorter than ``DOT_RING`` widths, one chord of a bead) of any shape: its pass
    and bead cover >= 97 % of it and never overlap themselves. The blobs are 1.1 times rocker-arm 0.8
    layer 98's pentagon (flat, it is a thin region at 1.0) and an octagon 1.76 w across; on main d403461
    the pentagon turned by 73° got a chord and two gap passes over it (9.5 % overlap)."""
    width = 1.0
    poly = {"pentagon": sg.Polygon(PENTAGON),
            "pentagon turned": shapely.affinity.rotate(sg.Polygon(PENTAGON), 73, origin=(0, 0)),
            "octagon": sg.Point(0, 0).buffer(0.8, 2)}[shape]
    mesh = polygon_mesh(shapely.affinity.scale(poly, 1.1, 1.1), 0.05)
    result = layer_paths(mesh, width, min_bead=lambda p: np.full(len(p), 0.8 * width))
    assert result.rings == 1 and len(result.pieces) == 1  # a lone dot, one pass
    pos = result.pieces[0]
    coverage, overlap = layer_cover(mesh, pos, np.zeros(len(pos), int), width, seed=1, bead=result.widths[0])
    assert coverage >= 0.97 and overlap <= 0.01


def test_a_pass_ending_at_another_beads_side_stops_where_its_cap_touches_it():
    """A pass along y runs into the side of a pass along x (a T-junction); its end is trimmed back until its
    round cap runs at most ``END_DEPTH`` of its bead into the other bead (touching it, less the sliver that
    balances what the cap leaves open), within one step of the trim; its other end and the pass along x
    stay, and so does an end beside a parallel neighbour (not ahead of it)."""
    width = 1.0
    across = np.c_[np.linspace(-4, 4, 81), np.zeros(81), np.zeros(81)]
    stem = np.c_[np.zeros(41), np.linspace(4, 0.3, 41), np.zeros(41)]  # ends 0.3 w from the other's line
    side = np.c_[np.linspace(-4, 1, 51), np.full(51, -1.0), np.zeros(51)]  # parallel, a width below
    beads = [np.full(81, 1.0), np.full(41, 1.2), np.full(51, 1.0)]
    pieces, widths = trim_ends([across, stem, side], beads, width)
    touch = 0.5 * (1.0 + 1.2)  # centre line to centre line when the cap touches the other bead
    gap = np.linalg.norm(pieces[1][-1, :2])
    step = 1.2 / 20
    assert touch - END_DEPTH * 1.2 - 1e-9 <= gap <= touch - END_DEPTH * 1.2 + step + 1e-9
    assert np.allclose(pieces[1][0], stem[0]) and np.allclose(pieces[0], across) and np.allclose(pieces[2], side)
    assert len(pieces[1]) < len(stem) and np.all(pieces[1][:, 1] >= gap - 1e-9)  # trimmed, not bent


@pytest.mark.parametrize("turn", [0, 40, 90, 135])
def test_a_lone_round_thin_loop_is_printed_along_its_blob(turn):
    """An elliptic blob 2.8 × 1.8 w on a layer as thick as a width: its one ring (at the first level) is
    longer than a dot's (``DOT_RING``), round, and rises less than :func:`thin_rise` -- a lone round thin
    loop. Whatever its turn, it is printed as one chord across the blob whose bead covers >= 95 % of it
    without covering any of it twice (cheburashka 0.8 layer 69, a blob 2.3 × 1.8 w: its loop's centre
    line left a wedge to a gap pass whose bead overlapped the centre line's, 5.9 % overlap)."""
    from curvslice.toolpaths.plan import layer_rings
    from curvslice.toolpaths.rings import lone_thin_loop

    width = 1.0
    shape = shapely.affinity.scale(sg.Point(0, 0).buffer(1.0, 32), 1.4, 0.9)
    mesh = polygon_mesh(shapely.affinity.rotate(shape, turn, origin=(0, 0)), 0.05)
    floor = lambda p: np.full(len(p), width)  # noqa: E731
    (ring,) = layer_rings(mesh, width, floor).rings
    assert ring.round and ring.length >= DOT_RING * width and lone_thin_loop(ring, width)
    result = layer_paths(mesh, width, min_bead=floor)
    assert len(result.pieces) == 1
    pos = result.pieces[0]
    coverage, overlap = layer_cover(mesh, pos, np.zeros(len(pos), int), width, seed=1, bead=result.widths[0])
    assert coverage >= 0.95 and overlap <= 0.01
