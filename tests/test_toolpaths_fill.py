"""Beads over what the passes leave open (issue 18): the last widening of a layer's beads reaches every open
sample up to the halfway line of the free space between two beads, and a sample the print pulls onto the
layer keeps its bead where it takes nothing from another; passes never added where nothing is open (a
bridged hole) or beside a pass whose bead widens over the place (a thin strip that widens)."""

from __future__ import annotations

import numpy as np
import pytest
import shapely.geometry as sg
import trimesh

from curvslice.toolpaths.beads import _nearest_per_group, _point_hash, _Projector, fill_slivers, surface_samples
from curvslice.toolpaths.constants import BEAD_RANGE
from curvslice.toolpaths.plan import layer_paths
from curvslice.toolpaths.resampling import resample
from curvslice.verify.toolpaths import layer_cover
from test_toolpaths import polygon_mesh


def _line(y: float, n: int = 81) -> np.ndarray:
    return np.c_[np.linspace(0.0, 8.0, n), np.full(n, y), np.zeros(n)]


@pytest.mark.parametrize("spacing, beads", [(1.5, (1.0, 1.0)), (1.6, (0.8, 1.2)), (1.9, (1.0, 0.6)), (2.4, (1.0, 1.0))])
def test_open_strip_between_two_passes_is_split_at_the_halfway_line(spacing, beads):
    """Two straight passes ``spacing`` widths apart with beads that leave the strip between them open (e.g.
    0.5 w of it at 1.5 w apart): both beads grow into it up to the halfway line of the free space between
    them, so the two never overlap (their half widths add up to at most the spacing) and the strip is
    covered -- or, where the strip is wider than two widest
    beads, each grows to the widest bead. The old rule (only 0.15 w beyond a bead, up to the other bead's
    edge as it stood) left a strip wider than 0.3 w open."""
    width = 1.0
    strip = polygon_mesh(sg.box(0.0, 0.0, 8.0, spacing), 0.1)
    pieces = [_line(0.0), _line(spacing)]
    widths = [np.full(81, beads[0]), np.full(81, beads[1])]
    x, _, edge = surface_samples(strip, width)
    grown = fill_slivers(x, pieces, widths, width, inner=~edge)
    inner = slice(10, 71)  # away from the passes' round ends
    a, b = grown[0][inner], grown[1][inner]
    assert np.all(a >= beads[0] - 1e-12) and np.all(b >= beads[1] - 1e-12)  # widened, never narrowed
    assert np.all(0.5 * (a + b) <= spacing + 1e-9)  # the two beads never overlap
    free = spacing - 0.5 * (beads[0] + beads[1])
    widest = BEAD_RANGE[1] * width
    for mine, bead in ((a, beads[0]), (b, beads[1])):
        # out to the halfway line of the free space, or the widest bead (to the farthest open sample it is
        # nearest, plus the surface that sample stands for: within a lattice spacing, about 0.14 w)
        halfway = min(0.5 * bead + 0.5 * free, 0.5 * widest)
        assert np.all(0.5 * mine >= halfway - 0.15 * width) and np.mean(0.5 * mine) >= halfway - 0.1 * width
    pos = np.vstack([p[inner] for p in pieces])
    ids = np.repeat([0, 1], len(range(10, 71)))
    middle = polygon_mesh(sg.box(1.5, 0.0, 6.5, spacing), 0.1)  # clear of the beads' round ends
    coverage, overlap = layer_cover(middle, pos, ids, width, seed=1, bead=np.r_[a, b])
    assert overlap <= 0.001
    if 0.5 * (beads[0] + beads[1]) + free <= widest:  # the widest beads span the strip
        assert coverage >= 0.99


def test_a_bead_grows_to_the_edge_of_a_neighbour_that_cannot_grow():
    """A strip 0.4 w wide left open between a bead already the widest (1.6 w) and a narrow one (0.6 w): the
    widest bead claims nothing of it, so the narrow one grows across all of it, up to the widest bead's edge
    -- the halfway split holds back only beads that both grow."""
    width = 1.0
    strip = polygon_mesh(sg.box(0.0, 0.0, 8.0, 1.5), 0.1)
    pieces = [_line(0.0), _line(1.5)]
    widths = [np.full(81, BEAD_RANGE[1]), np.full(81, 0.6)]  # edges at 0.8 and 1.2
    x, _, edge = surface_samples(strip, width)
    grown = fill_slivers(x, pieces, widths, width, inner=~edge)
    inner = slice(10, 71)
    assert np.allclose(grown[0][inner], BEAD_RANGE[1])
    edge = 1.5 - 0.8
    assert np.all(0.5 * grown[1][inner] <= edge + 1e-9) and np.mean(0.5 * grown[1][inner]) >= edge - 0.1


def test_a_sample_pulled_onto_the_layer_keeps_its_bead_short_of_the_others():
    """A pass end the fit put 0.3 w past the layer's edge is printed on the edge. With another pass's bead
    just ahead of the edge it narrows to stay short of that bead, but never below the fitted bead less
    twice the pull (the printed disc then lies inside the fitted one); with nothing near it keeps its bead
    (what lies past the edge still covers the layer around the end); a chord's sample dropped onto a
    curved layer along its normal keeps its bead."""
    from curvslice.toolpaths.plan import _pulled_beads

    width = 1.0
    end = np.c_[np.linspace(4.0, 8.0, 5), np.zeros(5), np.zeros(5)]  # pass 0, its end at x = 8 on the edge
    fitted = end.copy()
    fitted[-1, 0] += 0.3  # where the fit had put it
    normals = np.tile([0.0, 0.0, 1.0], (5, 1))
    bead = np.full(5, 1.2)
    alone = _pulled_beads(fitted, end, normals, bead, np.zeros(5, int), width)
    assert np.allclose(alone, bead)
    for gap in (0.9, 1.2, 1.5):  # pass 1 crosses the end at this distance ahead of the printed end
        other = np.c_[np.full(5, 8.0 + gap), np.linspace(-2.0, 2.0, 5), np.zeros(5)]
        printed, was = np.vstack([end, other]), np.vstack([fitted, other])
        out = _pulled_beads(was, printed, np.tile([0.0, 0.0, 1.0], (10, 1)), np.full(10, 1.2), np.repeat([0, 1], 5), width)
        room = gap - 0.6  # to the edge of pass 1's bead
        assert out[4] == pytest.approx(max(1.2 - 2 * 0.3, min(1.2, 2 * room)))
        assert np.allclose(out[:4], 1.2) and np.allclose(out[5:], 1.2)
    dropped = _pulled_beads(end + [0.0, 0.0, 0.05], end, normals, bead, np.zeros(5, int), width)
    assert np.allclose(dropped, bead)


def test_no_gap_pass_runs_over_a_bridged_hole():
    """A ring 0.6 widths broad round a hole 1.6 w across (bridged: its rim is shorter than 3π w, and no
    contour ring lies on the bridge) on a mesh coarse enough to be subdivided, whose centre loop covers all
    of it: the bridge's fan is far from every bead but holds nothing to print, so no gap pass runs over it
    (the corpus dome at 1.5 mm, layer 12: a gap pass through the bridge, printed across the hole, 8.5 %
    overlap where it met the ring); through the same vertices, not marked as a bridge, one would."""
    from curvslice.toolpaths.passes import gap_passes
    from curvslice.toolpaths.plan import layer_rings

    width = 1.0
    mesh = polygon_mesh(sg.Point(0, 0).buffer(1.4, 64).difference(sg.Point(0, 0).buffer(0.8, 64)), 0.6)
    r = layer_rings(mesh, width)
    assert r.bridged == 1 and r.bridge.sum() > 3 and np.linalg.norm(r.v[r.bridge, :2], axis=1).max() < 0.8
    angle = np.linspace(0, 2 * np.pi, 200)
    loop = np.c_[1.1 * np.cos(angle), 1.1 * np.sin(angle), np.zeros(200)]
    assert gap_passes(r.v, r.f, [loop], width, bridge=r.bridge) == []
    over_hole = gap_passes(r.v, r.f, [loop], width)
    assert len(over_hole) == 1 and np.linalg.norm(over_hole[0][:, :2], axis=1).max() < 0.8


def test_a_thin_strip_that_widens_gets_one_ridge_pass_not_a_second_beside_it():
    """One arc of an unseen bowl shell's layer 40 at 0.6 mm (tests/data/bowl_arc.npz, in path widths: the
    strip along the shell's inner skin, 0.44 w broad, widening to about 0.9 w at 45°): its ridge pass leaves
    vertices beyond half its bead where the strip widens, which used to get a second ridge 3.3 w long beside
    the first (a 'branch'; 17-23 % overlap). That ridge lies within reach of the first pass's widest bead: the
    bead widens over it and the strip is one pass."""
    from pathlib import Path

    data = np.load(Path(__file__).parent / "data" / "bowl_arc.npz")
    mesh = trimesh.Trimesh(data["vertices"], data["faces"], process=False)
    for floor in (0.8, 1.0):
        result = layer_paths(mesh, 1.0, start=np.array([0.0, 0.0, 30.0]), min_bead=lambda p: np.full(len(p), floor))
        assert result.thin_passes == 1 and len(result.pieces) == 1
        s = resample(np.c_[result.pieces[0], result.widths[0]], 0.25)
        coverage, overlap = layer_cover(mesh, s[:, :3], np.zeros(len(s), int), 1.0, seed=1, bead=s[:, 3])
        assert coverage >= 0.99 and overlap <= 0.01


@pytest.mark.parametrize("n, ties", [(0, False), (1, False), (7, True), (5000, False), (5000, True)])
def test_nearest_per_group_is_lexsorts_first_entry(n: int, ties: bool) -> None:
    rng = np.random.default_rng(n)
    code = rng.integers(0, max(n // 3, 1), n)
    gap = rng.integers(0, 3, n).astype(float) if ties else rng.random(n)
    ref = np.lexsort((gap, code))
    ref = ref[np.r_[True, code[ref][1:] != code[ref][:-1]]] if n else ref
    assert np.array_equal(_nearest_per_group(code, gap), ref)


def test_projector_answers_repeated_and_colliding_points_as_asked_anew() -> None:
    """The projector's memory (points looked up by a hash of their bits, matched exactly) gives every point
    the answer it gets on its own, also for a point whose hash another point already holds."""
    surface = trimesh.creation.icosphere(subdivisions=3, radius=5.0)
    rng = np.random.default_rng(3)
    pts = rng.standard_normal((300, 3)) * 4.0
    fresh = _Projector(surface)
    projector = _Projector(surface)
    projector(pts[:200])
    again = projector(np.vstack([pts[100:], pts[:50]]))
    alone = fresh(np.vstack([pts[100:], pts[:50]]))
    for a, b in zip(again, alone):
        assert np.array_equal(a, b)
    # a forced collision: the memory holds another point under the asked point's hash
    projector.keys[:] = _point_hash(pts[:1])[0]
    projector.keys.sort()
    for a, b in zip(projector(pts[:5]), fresh(pts[:5])):
        assert np.array_equal(a, b)
