"""Tool-paths of every layer (thesis §3.5.1-3.5.2): the per-layer pipeline, orientations,
thickness and extrusion, and the ``toolpaths.npz`` / ``toolpaths.gcode`` files."""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import asdict, dataclass, field
from pathlib import Path
from time import perf_counter

import numpy as np
import scipy.sparse as sp
import trimesh
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from curvslice import orientation as ori
from curvslice.errors import CurvsliceError
from curvslice.executors import Executor, InProcess, query_threads
from curvslice.exporters.gcode6 import write_gcode6
from curvslice.geodesic import boundary_distance, edge_keys
from curvslice.toolpaths.beads import fill_slivers, layer_beads, nearest_below, surface_samples
from curvslice.toolpaths.constants import (BEAD_MIN, BRIDGE_HOLE, FIRST_LEVEL, FLOOR_CANDIDATES, GAP_NOISE, HARD_TILT, MAX_SHIFT,
                                           SUBDIVIDE_EDGE, THICKNESS_CANDIDATES, TURN_WEIGHT, WIDTH_WEIGHT)
from curvslice.toolpaths.passes import join_touching, split_off_layer, thin_passes, uncross
from curvslice.toolpaths.resampling import bead_room, extrusion_amounts, resample
from curvslice.toolpaths.rings import contour_gap, contour_rings, peak_rings, prune_islands, split_pinches
from curvslice.toolpaths.spirals import connected_spirals
from curvslice.toolpaths.stacked import piece_labels
from curvslice.vectors import row_norms


@dataclass
class LayerPaths:
    """Tool-path pieces of one layer (polylines, print order), each vertex's bead width (mm),
    and how they were made."""

    pieces: list[np.ndarray]
    widths: list[np.ndarray] = field(default_factory=list)
    thin_passes: int = 0  #: ridge passes of thin walls (bead as wide as the wall)
    rings: int = 0
    regions: int = 0
    splices: int = 0
    failed_splices: int = 0
    closed_components: int = 0
    gap_passes: int = 0  #: passes through what the others leave open, kept after needed_pieces
    bridged_holes: int = 0
    off_layer_links: int = 0  #: links cut because they left the layer (:func:`split_off_layer`)
    travel: float = 0.0
    max_distance: float = 0.0

    @property
    def jumps(self) -> int:
        return max(len(self.pieces) - 1, 0)



def clean_surface(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Merge duplicate vertices and drop degenerate or repeated triangles (no other change)."""
    m = trimesh.Trimesh(np.asarray(mesh.vertices, np.float64).reshape(-1, 3), np.asarray(mesh.faces, np.int64).reshape(-1, 3),
                        process=True, validate=False)
    m.update_faces(m.nondegenerate_faces(height=1e-9))
    m.update_faces(m.unique_faces())
    m.remove_unreferenced_vertices()
    return m


def bridge_small_holes(vertices: np.ndarray, faces: np.ndarray, max_perimeter: float,
                       leave_open: Collection[int] = ()) -> tuple[np.ndarray, np.ndarray, int]:
    """Close boundary loops shorter than ``max_perimeter`` by a triangle fan to their centroid.

    Pin-holes of a contoured, trimmed layer (a voxel wide) would each become a source of the
    boundary distance and break the spirals into fragments; a bead bridges them instead.
    Returns the new vertices (the fans' centres appended, one per hole closed, in order) and faces
    and the number of holes closed. ``leave_open``: the positions, in that order, of holes to leave
    open (:func:`_ringed_bridges`; the same input finds the same holes in the same order).
    """
    f = np.asarray(faces, np.int64)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    n_v = int(f.max()) + 1 if len(f) else 1
    _, inverse, counts = np.unique(edge_keys(directed[:, 0], directed[:, 1], n_v), return_inverse=True,
                                   return_counts=True)
    border = directed[counts[inverse.ravel()] == 1]
    if len(border) == 0:
        return vertices, f, 0
    n = len(vertices)
    graph = sp.coo_matrix((np.ones(len(border)), (border[:, 0], border[:, 1])), shape=(n, n))
    _, loop = connected_components(graph, directed=False)
    loop_of_edge = loop[border[:, 0]]
    length = row_norms(vertices[border[:, 0]] - vertices[border[:, 1]])
    perimeter = np.bincount(loop_of_edge, weights=length)
    # the longest loop of each connected piece is its outer boundary, never a hole
    mesh_graph = sp.coo_matrix((np.ones(len(directed)), (directed[:, 0], directed[:, 1])), shape=(n, n))
    _, piece = connected_components(mesh_graph, directed=False)
    loops = np.unique(loop_of_edge)
    first_edge = np.zeros(len(perimeter), np.int64)
    first_edge[loop_of_edge[::-1]] = np.arange(len(border))[::-1]
    loop_piece = piece[border[first_edge[loops], 0]]
    outer = np.zeros(len(perimeter), bool)
    order = np.lexsort((-perimeter[loops], loop_piece))
    first_of_piece = np.r_[True, loop_piece[order][1:] != loop_piece[order][:-1]]
    outer[loops[order][first_of_piece]] = True
    small = np.nonzero((perimeter > 0) & (perimeter < max_perimeter) & ~outer)[0]
    small = np.delete(small, np.asarray(sorted(k for k in set(leave_open) if 0 <= k < len(small)), np.int64))
    if len(small) == 0:
        return vertices, f, 0
    pick = np.isin(loop_of_edge, small)
    new_index = np.full(len(perimeter), -1)
    new_index[small] = n + np.arange(len(small))
    counts_v = np.bincount(loop_of_edge[pick], minlength=len(perimeter))[small]
    centres = np.stack([np.bincount(loop_of_edge[pick], weights=vertices[border[pick, 0], i],
                                    minlength=len(perimeter))[small] for i in range(3)], axis=1) / counts_v[:, None]
    fan = np.c_[border[pick, 1], border[pick, 0], new_index[loop_of_edge[pick]]]
    return np.vstack([vertices, centres]), np.vstack([f, fan]), len(small)


@dataclass
class LayerRings:
    """The start-independent part of one layer's tool-paths: its cleaned surface, the bridged (maybe
    subdivided) mesh ``v``/``f`` of the boundary distance, the iso-distance rings, the peak lines,
    the thin-wall passes and the surface samples the beads are fitted to (:func:`layer_rings`);
    ``None`` rings and samples when the layer has no faces."""

    surface: trimesh.Trimesh
    v: np.ndarray
    f: np.ndarray
    bridged: int
    rings: list | None = None
    lines: list = field(default_factory=list)
    thin: list = field(default_factory=list)
    closed: int = 0
    top: float = 0.0
    samples: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  #: :func:`surface_samples` of ``surface``
    bridge: np.ndarray | None = None  #: (len(v),) vertices of the bridges' fans only (no surface under them)


def layer_paths(mesh: trimesh.Trimesh, width: float, start: np.ndarray | None = None,
                fill_gaps: bool = True, min_bead: Callable[[np.ndarray], np.ndarray] | None = None) -> LayerPaths:
    """Connected-Fermat-spiral pieces covering one working surface (thesis §3.5.1), plus
    :func:`gap_passes` through what they leave open when ``fill_gaps``. Holes narrower than
    ``BRIDGE_HOLE`` widths are bridged (:func:`bridge_small_holes`); a mesh coarser than ``SUBDIVIDE_EDGE`` widths
    is subdivided once (1 → 4 triangles) so the distance field and contours resolve the passes.
    Regions narrower than ``2·THIN_REGION`` widths get one ridge pass of their own width
    (:func:`thin_passes`). Every pass is then freed of self-crossings (:func:`uncross`) and its
    bead fitted to the strip of surface it covers (:func:`fit_beads`; ``min_bead(points)`` gives
    the narrowest bead there, the local layer thickness), and widened over the slivers the fit
    leaves past tips and corners (:func:`fill_slivers`). The two halves: :func:`layer_rings` (independent
    of ``start``, so of the other layers) and :func:`layer_pieces`."""
    return layer_pieces(layer_rings(mesh, width, min_bead), width, start, fill_gaps, min_bead)


def layer_rings(mesh: trimesh.Trimesh, width: float,
                min_bead: Callable[[np.ndarray], np.ndarray] | None = None) -> LayerRings:
    """The part of :func:`layer_paths` that does not depend on where the previous layer ended: the
    boundary distance (heat method), its contour rings, peak lines and thin-wall passes, the bead
    floor of each ring, which decides whether it is a thin loop (``min_bead``: the layer thickness, from
    the earlier layers), and the surface samples of the bead fits (:func:`surface_samples`)."""
    surface = clean_surface(mesh)
    ringed: list[int] = []
    while True:
        r = _layer_rings(surface, width, min_bead, ringed)
        more = _ringed_bridges(r, len(surface.vertices), width)
        if not more:
            return r
        # a hole whose bridge would carry a ring is no pin-hole: left open, the rings go round it
        holes = [k for k in range(r.bridged + len(ringed)) if k not in ringed]
        ringed += [holes[k] for k in more]


def _ringed_bridges(r: LayerRings, n_surface: int, width: float) -> list[int]:
    """The holes (positions among those :func:`bridge_small_holes` closed) whose bridge carries a ring: one
    lying more than half on the fan, where no surface lies under it. A bridge is there for a bead to cross a
    pin-hole; a ring on it has nothing to print, and its bead, fitted to the nearest surface, doubles the one
    of the ring around the hole (the hollow box at 1.5 mm, layer 18: the last square of its ceiling, a strip
    1.1 w broad round a hole 2.4 w across; bridged, two rings 0.34 w apart in 3D and 9.9 % overlap)."""
    if not r.bridged or not r.rings:
        return []
    centres = r.v[n_surface:n_surface + r.bridged]
    # each fan's reach from its centre: to the farthest vertex of its hole's loop (whose mean the centre is)
    vertices = r.surface.vertices
    border = r.surface.edges[trimesh.grouping.group_rows(r.surface.edges_sorted, require_count=1)]
    graph = sp.coo_matrix((np.ones(len(border)), (border[:, 0], border[:, 1])), shape=(len(vertices), len(vertices)))
    loop = connected_components(graph, directed=False)[1][border[:, 0]]
    count = np.bincount(loop)
    means = np.stack([np.bincount(loop, weights=vertices[border[:, 0], i]) for i in range(3)], axis=1) / np.maximum(count, 1)[:, None]
    hole = cKDTree(means[count > 0]).query(centres)[1]
    hole = np.nonzero(count > 0)[0][hole]
    rims = np.zeros(len(centres))
    for i, h in enumerate(hole):
        rims[i] = row_norms(vertices[border[loop == h, 0]] - centres[i]).max()
    tree = cKDTree(centres)
    out: set[int] = set()
    for ring in r.rings:
        d, k = tree.query(ring.points)
        if not np.all(k == k[0]) or np.any(d > rims[k[0]]):
            continue  # (the ring lies within one fan's reach: then is it on the fan?)
        _, off, _ = trimesh.proximity.closest_point(r.surface, ring.points)
        if np.median(off) > 1e-6 * width:
            out.add(int(k[0]))
    return sorted(out)


def _layer_rings(surface: trimesh.Trimesh, width: float, min_bead: Callable[[np.ndarray], np.ndarray] | None,
                 leave_open: Collection[int]) -> LayerRings:
    """:func:`layer_rings` of a cleaned ``surface`` with the holes ``leave_open`` left open."""
    v, f, bridged = bridge_small_holes(surface.vertices, surface.faces, BRIDGE_HOLE * np.pi * width, leave_open)
    real = len(surface.faces)  # the fans come after the surface's own faces
    if len(f) and row_norms(v[f[:, 1]] - v[f[:, 0]]).mean() > SUBDIVIDE_EDGE * width:
        v, f = trimesh.remesh.subdivide(v, f)  # finer heat step (t = h²) and contours than the voxels
        real *= 4  # (face i becomes faces 4i .. 4i + 3)
    if len(f) == 0:
        return LayerRings(surface, v, f, bridged)
    bridge = np.ones(len(v), bool)
    bridge[f[:real].ravel()] = False
    dist = boundary_distance(v, f)
    gap = contour_gap(v, f, dist, width)
    if abs(gap - 1.0) > GAP_NOISE:
        dist = dist * gap
    f, thin = thin_passes(v, f, dist, width)
    closed = int(np.isnan(dist).any())
    finite = dist[np.isfinite(dist)]
    top = float(finite.max()) if len(finite) else 0.0
    levels = np.arange(FIRST_LEVEL * width, top, width)
    rings, bands = contour_rings(v, f, dist, levels)
    rings = prune_islands(rings, bands.top, width)

    def floor_of(points: np.ndarray) -> float:
        """The narrowest bead along a contour (fit_beads), in widths: the local layer thickness
        (0.8 w at the default path width, voxel / 0.8 of §3.6, on layers a voxel thick), which
        decides whether the contour is a thin loop (thin_rise)."""
        return max(float(np.median(min_bead(points))) / width, BEAD_MIN) if min_bead is not None else BEAD_MIN

    for r in rings:
        r.top, r.floor = float(bands.top[r.above]), floor_of(r.points)
    extra, lines = peak_rings(v, f, dist, levels, rings, bands, width, floor_of)
    rings, necks = split_pinches(rings + extra, width, min_bead)
    lines += necks
    return LayerRings(surface, v, f, bridged, rings, lines, thin, closed, top, surface_samples(surface, width), bridge)


def layer_pieces(r: LayerRings, width: float, start: np.ndarray | None = None, fill_gaps: bool = True,
                 min_bead: Callable[[np.ndarray], np.ndarray] | None = None) -> LayerPaths:
    """The part of :func:`layer_paths` that depends on ``start`` (the seam, or where the previous layer
    ended): the connected spirals from the rings, the beads, and the order of the pieces, each freed of
    its self-crossings (:func:`~curvslice.toolpaths.passes.uncross`)."""
    out, order = _beaded_pieces(r, width, start, fill_gaps, min_bead)
    widths = _sliver_widths(r, out, width)
    done = [_finish_piece(out.pieces[i], widths[i], reverse, width) for i, reverse in order]
    out.pieces, out.widths = [p for p, _ in done], [b for _, b in done]
    return out


def _beaded_pieces(r: LayerRings, width: float, start: np.ndarray | None = None, fill_gaps: bool = True,
                  min_bead: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[LayerPaths, list[tuple[int, bool]]]:
    """:func:`layer_pieces` but the last steps: the paths with their beaded pieces as fitted (beads not yet
    widened over the slivers), and the print order (piece index, reversed) with its travel. Widening the
    beads (:func:`_sliver_widths`) leaves the pieces as they are and uncrossing a piece keeps its two ends,
    so the order, the travel and where the layer ends are known before either: both can run elsewhere."""
    if r.rings is None:
        return LayerPaths(pieces=[]), []
    surface, v, f, bridged, rings, lines, thin, closed, top = (r.surface, r.v, r.f, r.bridged, r.rings, r.lines,
                                                               r.thin, r.closed, r.top)
    spirals, regions, splices, failed = connected_spirals(rings, width, start, r.samples[0][r.samples[2]])
    out = LayerPaths(pieces=spirals + lines, rings=len(rings), regions=regions + len(lines) + len(thin),
                     splices=splices, failed_splices=failed, closed_components=closed, max_distance=top,
                     bridged_holes=bridged, thin_passes=len(thin))
    passes = join_touching([p for p in out.pieces + thin if len(p) > 1 and np.ptp(p, axis=0).max() > 1e-9], width)
    out.pieces, out.widths, out.gap_passes, out.off_layer_links = layer_beads(surface, v, f, passes, width, min_bead,
                                                                               fill_gaps, r.samples, r.bridge)
    order = _order_pieces(out.pieces, start)
    ends = [(out.pieces[i][-1], out.pieces[i][0]) if reverse else (out.pieces[i][0], out.pieces[i][-1])
            for i, reverse in order]
    out.travel = float(sum(np.linalg.norm(b[0] - a[1]) for a, b in zip(ends[:-1], ends[1:])))
    return out, order


def _sliver_widths(r: LayerRings, paths: LayerPaths, width: float) -> list[np.ndarray]:
    """The bead widths of :func:`_beaded_pieces`' ``paths`` widened over the slivers the fits leave
    (:func:`~curvslice.toolpaths.beads.fill_slivers` on the layer's surface samples); ``paths`` unchanged."""
    return fill_slivers(r.samples[0], paths.pieces, paths.widths, width, inner=~r.samples[2]) if paths.pieces else paths.widths


def _finish_piece(piece: np.ndarray, widths: np.ndarray, reverse: bool, width: float) -> tuple[np.ndarray, np.ndarray]:
    """A beaded piece freed of its self-crossings (:func:`~curvslice.toolpaths.passes.uncross`, which keeps
    its ends) and its vertex widths, printed backward when ``reverse``."""
    o = uncross(piece, width)
    p, b = piece[o], widths[o]
    return (p[::-1], b[::-1]) if reverse else (p, b)


def _order_pieces(pieces: list[np.ndarray], start: np.ndarray | None) -> list[tuple[int, bool]]:
    """Greedy nearest-end ordering (pieces may be reversed) to shorten travels (§3.3.2 item 2): the
    pieces' indices in print order, each with whether it is printed backward."""
    left = list(range(len(pieces)))
    cursor = np.asarray(start, float) if start is not None else (pieces[0][0] if pieces else None)
    order = []
    while left:
        d0 = [np.linalg.norm(pieces[i][0] - cursor) for i in left]
        d1 = [np.linalg.norm(pieces[i][-1] - cursor) for i in left]
        k = int(np.argmin(np.minimum(d0, d1)))
        i, reverse = left.pop(k), bool(d0[k] > d1[k])
        order.append((i, reverse))
        cursor = pieces[i][0] if reverse else pieces[i][-1]
    return order



# ----------------------------------------------------------------------------- all layers


#: Where each layer's spiral starts. ``chain`` (the default): nearest where the previous layer ended
#: (§3.3.2 item 2, the least travel between layers, but each layer waits for the one before: a
#: sequential fold). ``seam``: nearest a fixed point of the part (:func:`seam_point`), so every layer's
#: tool-paths are one independent task that scales over workers. Overlap still depends on where the
#: spirals are cut, and the seam's cut takes one corpus case past verify's 5 % (fandisk at 2.5 mm:
#: 6.0 %, chain 4.5 %): ``seam`` can become the default once overlap no longer depends on the cut.
START_RULES = ("chain", "seam")


@dataclass(frozen=True)
class ToolpathSettings:
    """Parameters of the tool-path stage (mm, mm/min, radians)."""

    path_width: float = 1.0  #: iso-contour spacing; default: the nozzle diameter
    step: float = 1.0  #: re-sampling distance (thesis §3.5.2: 1 mm)
    filament_diameter: float = 1.75
    feed: float = 600.0  #: nozzle speed along the path, mm/min
    max_angle: float = float(np.radians(10.0))  #: low-pass / slerp threshold (§3.5.2)
    #: largest angle between orientation and layer normal: the shipped nozzle cone has a 40° half-angle,
    #: so past ~50° it would cut the layer; 40° let every kitten waypoint reach a collision-free pose
    max_tilt: float = float(np.radians(40.0))
    window: int = 8  #: earlier layers searched for the closest point (Eq. 3.3)
    fill_gaps: bool = True  #: extra passes through strips the spirals leave open (more jumps)
    #: where a layer's spiral starts (:data:`START_RULES`): ``chain`` (nearest where the previous layer
    #: ended) or ``seam`` (nearest a fixed point of the part, every layer on its own)
    start_rule: str = "chain"

    def __post_init__(self) -> None:
        for name in ("path_width", "step", "filament_diameter", "feed", "max_angle", "max_tilt"):
            if not getattr(self, name) > 0:
                raise CurvsliceError(f"tool-path setting {name} must be positive (got {getattr(self, name)})")
        if not self.max_tilt < np.pi / 2:
            raise CurvsliceError("the largest tilt from the layer normal must be below 90° (else the nozzle could point into printed material)")
        if self.start_rule not in START_RULES:
            raise CurvsliceError(f"tool-path start rule must be one of {', '.join(START_RULES)} (got {self.start_rule!r})")
        if not 0 < self.min_thickness <= self.max_thickness <= 1.0:
            raise CurvsliceError("layer thickness clamps need 0 < min_thickness <= max_thickness <= 1 (shares of the path width)")
    min_thickness: float = 0.1  #: local layer thickness clamp, as a share of the path width
    max_thickness: float = 1.0


@dataclass
class Toolpaths:
    """Samples of all layers in print order (the ``toolpaths.npz`` contract) and per-layer figures."""

    positions: np.ndarray
    normals: np.ndarray
    layer: np.ndarray
    path: np.ndarray
    extrusion: np.ndarray
    thickness: np.ndarray
    feed: np.ndarray
    bead: np.ndarray  #: bead width per sample (mm), encoded in ``extrusion``
    layers: list[dict[str, float]]
    seconds: dict[str, float]


def _thickness(points: np.ndarray, earlier: list[tuple[np.ndarray, cKDTree, np.ndarray]],
               candidates: int = THICKNESS_CANDIDATES) -> tuple[np.ndarray, np.ndarray]:
    """Closest point under each point on the platform top ``z = 0`` or the ``earlier`` layers'
    triangles (Eq. 3.3; ``candidates`` nearest triangle centroids tried on each; each layer comes
    with its centroid tree and its triangles' centroid-to-corner reaches) and the distance
    to it: the local layer thickness (unclamped). Layers are searched newest first, and a layer
    only for the points it may bring closer: no triangle is nearer than its nearest centroid
    less the layer's largest centroid-to-corner reach."""
    q = np.asarray(points, np.float64).reshape(-1, 3)
    closest = np.column_stack([q[:, 0], q[:, 1], np.zeros(len(q))])
    dist = np.abs(q[:, 2])
    for tri_k, tree_k, reach in reversed(earlier):
        # (a layer's nearest centroid farther than the point's thickness and reach brings it no closer)
        bound = nearest_below(tree_k, q, (dist + reach.max()) * (1.0 + 1e-9))[0] - reach.max()
        todo = np.nonzero(bound < dist)[0]
        if len(todo) == 0:
            continue
        c_k, d_k, _ = ori.closest_points(q[todo], tri_k, tree_k, candidates, reach)
        better = d_k < dist[todo]
        closest[todo[better]], dist[todo[better]] = c_k[better], d_k[better]
    return closest, dist


def layer_support(surface: trimesh.Trimesh) -> tuple[np.ndarray, cKDTree | None, np.ndarray]:
    """A cleaned layer as later layers stand on it (Eq. 3.3, :func:`_thickness`): its triangles, their
    centroid tree and each one's centroid-to-corner reach (:func:`~curvslice.orientation.triangle_reach`:
    they bound every later search)."""
    tri = surface.triangles
    if not len(tri):
        return tri, None, np.zeros(0)
    tree = cKDTree(tri.mean(axis=1))
    return tri, tree, ori.triangle_reach(tri, tree)


def _earlier(supports: list[tuple[np.ndarray, cKDTree | None, np.ndarray]], k: int, window: int) -> list:
    """The ``window`` last non-empty layers before layer ``k`` (0-based)."""
    return [s for s in supports[:k] if len(s[0])][-window:]


def seam_point(surfaces: list[trimesh.Trimesh]) -> np.ndarray:
    """Where every layer's spirals are rooted and cut under the ``seam`` rule: the lowest-x, mid-y side of
    all layers' bounding box on the platform (``z = 0``), like a slicer's aligned seam. It is fixed data
    of the stage, computed before any layer's task, so no layer waits for another's paths. A connected
    Fermat spiral ends next to where it starts (§3.5.1), and every other layer is printed backward
    (:func:`_layer_toolpaths`), so a layer that ends at the seam is followed by one that starts there,
    and one that ends after its last (farthest) piece by one that starts at its own, on similar
    geometry nearby: the travel between layers stays short (measured: benchmarks/SCALING.md)."""
    bounds = [m.bounds for m in surfaces if len(m.faces)]
    if not bounds:
        return np.zeros(3)
    lo, hi = np.min([b[0] for b in bounds], axis=0), np.max([b[1] for b in bounds], axis=0)
    return np.array([lo[0], 0.5 * (lo[1] + hi[1]), 0.0])


@dataclass
class _Floor:
    """The narrowest bead at given points of a layer: the local layer thickness of the nearest vertex (a
    bead is never narrower than it is high; ``min_bead`` of :func:`layer_rings` and :func:`layer_pieces`)."""

    vertex_thickness: np.ndarray
    tree: cKDTree | None

    def __call__(self, points: np.ndarray) -> np.ndarray:
        return self.vertex_thickness[self.tree.query(points, workers=query_threads(len(points)))[1]]


@dataclass
class _Prepared:
    """The start-independent work of one layer (:func:`_prepare_layer`)."""

    rings: LayerRings
    floor: _Floor
    seconds: float


@dataclass
class _Folded:
    """One layer's beaded pieces and their print order (:func:`_beaded_pieces`), where the layer ends, and
    the seconds of its :func:`_prepare_layer` and :func:`_fold_layer` work."""

    paths: LayerPaths
    order: list[tuple[int, bool]]
    cursor: np.ndarray | None
    seconds: float


def _prepare_layer(k: int, surfaces: list[trimesh.Trimesh], supports: list, settings: ToolpathSettings) -> _Prepared:
    """Layer ``k``'s thickness floor and rings: independent of the other layers' paths (a parallel task)."""
    t0 = perf_counter()
    w, surface = settings.path_width, surfaces[k]
    # (a floor: fewer candidate triangles than for the samples' own thickness below)
    vertex_thickness = np.clip(_thickness(surface.vertices, _earlier(supports, k, settings.window), FLOOR_CANDIDATES)[1],
                               settings.min_thickness * w, settings.max_thickness * w)
    floor = _Floor(vertex_thickness, cKDTree(surface.vertices) if len(surface.vertices) else None)
    return _Prepared(layer_rings(surface, w, floor), floor, perf_counter() - t0)


def _fold_layer(prepared: _Prepared, previous: _Folded | None, settings: ToolpathSettings,
                start: np.ndarray | None = None, backward: bool = False) -> _Folded:
    """A layer's beaded pieces and their order from ``start``, or (the ``chain`` rule) from where
    ``previous`` ended: the sequential part of the stage, so only what decides where the layer ends is
    done here. The surface samples of the fits come from :func:`_prepare_layer`; widening the beads over
    the slivers, uncrossing and re-sampling run in :func:`_orient_layer` (where the layer ends is read off
    its last piece: :func:`_printed_end`). ``backward``: printed in reverse, so that it ends at ``start``."""
    t0 = perf_counter()
    w = settings.path_width
    cursor = previous.cursor if previous is not None else start
    paths, order = _beaded_pieces(prepared.rings, w, start=cursor, fill_gaps=settings.fill_gaps, min_bead=prepared.floor)
    if backward:  # the same pieces printed the other way round: the layer ends where it would start
        order = [(i, not reverse) for i, reverse in order[::-1]]
    for at in order[::-1]:  # the layer ends at the last sample of its last piece of two
        end = _printed_end(paths.pieces[at[0]], at[1])
        if end is None:  # the piece's samples tell (the widths, not yet final, never move its end)
            tail = _piece_samples(paths, paths.widths, at, settings)
            end = tail[-1, :3] if len(tail) >= 2 else None
        if end is not None:
            cursor = end
            break
    return _Folded(paths, order, cursor, prepared.seconds + perf_counter() - t0)


#: Distance (mm) beyond which :func:`_printed_end` knows a piece's last point survives re-sampling: twice
#: the distance below which :func:`~curvslice.toolpaths.resampling.resample` merges consecutive points.
_DISTINCT_END = 2e-9


def _printed_end(piece: np.ndarray, reverse: bool) -> np.ndarray | None:
    """The last sample of ``piece`` as printed (:func:`_piece_samples`) without uncrossing or re-sampling
    it, when that is certain: uncrossing reorders the inner points only, and re-sampling keeps the last
    point exactly when it differs from its predecessor -- whatever that is, so when it lies farther than
    ``_DISTINCT_END`` from every other point of the piece (then the samples are two or more, too). ``None``
    when not certain."""
    end = piece[0] if reverse else piece[-1]
    others = piece[1:] if reverse else piece[:-1]
    if len(others) and row_norms(others - end).min() > _DISTINCT_END:
        return np.array(end, np.float64)
    return None


def _piece_samples(paths: LayerPaths, widths: list[np.ndarray], at: tuple[int, bool],
                   settings: ToolpathSettings) -> np.ndarray:
    """Samples (x, y, z, bead) of the piece ``at`` (index, reversed) of :func:`_beaded_pieces`' ``paths``
    with bead ``widths`` as printed: uncrossed (:func:`_finish_piece`) and re-sampled (§3.5.2)."""
    w = settings.path_width
    piece, bead = _finish_piece(paths.pieces[at[0]], widths[at[0]], at[1], w)
    return resample(np.c_[piece, bead], settings.step, WIDTH_WEIGHT, TURN_WEIGHT * w)


def _pulled_beads(fitted: np.ndarray, printed: np.ndarray, normals: np.ndarray, bead: np.ndarray,
                  pid: np.ndarray, width: float) -> np.ndarray:
    """Bead widths of samples the print pulls onto the layer (``fitted`` -> ``printed``, the layer's
    ``normals`` there; ``pid`` the piece of each sample, in print order). A sample the fit put past the
    layer's edge -- a pass end lengthened towards a corner, a bead's excess spilled over the edge -- is
    printed on the edge, ``m`` along the layer from where its bead was fitted, and would carry its bead
    that far into the layer: into a neighbouring pass's bead where one lies there (fertility 0.8 layer 13,
    a strip a width wide whose pieces meet end to end: ends pulled back 0.2-0.4 w, 4.7 % overlap). Its
    bead keeps its width short of the bead of every other pass as the segments lay them (another piece,
    or the same one more than ``SAME_PASS_BEADS`` beads along it, as
    :func:`~curvslice.toolpaths.resampling.extrusion_amounts` raises a bead: :func:`~curvslice.toolpaths.resampling.bead_room`), and narrows no further
    than by ``2·m``, where the printed disc lies within the fitted one and takes nothing the fitted bead
    did not (fertility 0.8 layer 13: 3.6 %). Only the move within the layer's tangent plane counts (a
    chord of a curved pass drops onto it along the normal, its bead still reaching as far to either
    side), and only up to ``MAX_SHIFT`` widths (farther, the sample is a link's chord across a bend, as
    in :func:`~curvslice.toolpaths.beads._onto_layer`)."""
    off = fitted - printed
    along = row_norms(off - np.einsum("ij,ij->i", off, normals)[:, None] * normals)
    pulled = np.nonzero((along > 1e-9 * width) & (along <= MAX_SHIFT * width))[0]
    if not len(pulled):
        return bead
    seg = np.r_[0.0, row_norms(np.diff(printed, axis=0))]
    first = np.r_[True, pid[1:] != pid[:-1]]
    laid = np.where(first, 0.0, np.r_[bead[0], 0.5 * (bead[1:] + bead[:-1])])  # each segment at its ends' mean
    room = bead_room(printed, seg, first, laid, pulled, bead[pulled], None)
    out = bead.copy()
    out[pulled] = np.maximum(bead[pulled] - 2.0 * along[pulled], np.minimum(bead[pulled], room))
    return out


def _orient_layer(k: int, folded: _Folded, prepared: _Prepared, surfaces: list[trimesh.Trimesh], supports: list,
                  settings: ToolpathSettings) -> tuple[dict[str, np.ndarray], dict[str, float], float, float]:
    """Layer ``k``'s pieces as printed (beads widened over the slivers: :func:`_sliver_widths` on the
    surface samples of ``prepared``; uncrossed, re-sampled: :func:`_piece_samples`; cut where a printed segment's
    chord leaves the layer: :func:`~curvslice.toolpaths.passes.split_off_layer`), their orientations
    (Eq. 3.3), thickness and beads per sample: a parallel task once its pieces are known. Returns its
    arrays (path ids from 0 within the layer), its report row, and the seconds of its pieces and of this."""
    t1 = perf_counter()
    w, surface, paths = settings.path_width, surfaces[k], folded.paths
    widths = _sliver_widths(prepared.rings, paths, w)
    samples = [_piece_samples(paths, widths, at, settings) for at in folded.order]
    samples = [s for s in samples if len(s) >= 2]
    tri, own_tree, own_reach = supports[k]
    earlier = _earlier(supports, k, settings.window)
    out: dict[str, np.ndarray] = {}
    row = {"layer": k + 1, "pieces": len(samples), "jumps": max(len(samples) - 1, 0),
           "travel_mm": round(paths.travel, 3), "rings": paths.rings, "regions": paths.regions,
           "splices": paths.splices, "failed_splices": paths.failed_splices,
           "closed_components": paths.closed_components, "gap_passes": paths.gap_passes,
           "bridged_holes": paths.bridged_holes, "off_layer_links": paths.off_layer_links,
           "thin_passes": paths.thin_passes, "max_distance_mm": round(paths.max_distance, 3),
           "samples": 0, "length_mm": 0.0}
    if samples:
        q = np.vstack(samples)
        q, bead = q[:, :3], q[:, 3]
        pid = piece_labels(samples)
        fitted = q
        q, _, own_face = ori.closest_points(q, tri, own_tree, reach=own_reach)  # chords (links) back onto the layer
        surface_normal = ori.surface_normals(surface, q, own_face)
        bead = _pulled_beads(fitted, q, surface_normal, bead, pid, w)
        closest, dist = _thickness(q, earlier)
        t = ori.accumulation_directions(q, closest, surface_normal)
        t = ori.limit_tilt(t, surface_normal, settings.max_tilt)
        t = ori.low_pass(t, pid, settings.max_angle)
        pos, nrm, parent, frac = ori.slerp_subdivide(q, t, pid, settings.max_angle)
        pos, _, pos_face = ori.closest_points(pos, tri, own_tree, reach=own_reach)  # crest subdivisions onto the layer
        # the low-pass may have tilted a sample past the limit: never into the printed side
        nrm = ori.limit_tilt(nrm, ori.surface_normals(surface, pos, pos_face), HARD_TILT)
        # a segment whose chord still leaves the layer, its ends on it, is a travel and not a bead through the
        # air or through the layers below (femur 0.8 layer 99: a 1.8 w segment across a fold of the femoral
        # head's cap, 0.64 mm outside H); a sample left alone between two such segments prints nothing
        parts = split_off_layer(np.split(np.c_[pos, nrm, parent, frac], np.flatnonzero(np.diff(pid[parent])) + 1),
                                lambda x: ori.closest_points(x, tri, own_tree, reach=own_reach)[1], w, on_layer=True)
        parts = [part for part in parts if len(part) >= 2]
        row["pieces"], row["jumps"] = len(parts), max(len(parts) - 1, 0)
        if not parts:
            return out, row, folded.seconds, perf_counter() - t1
        stacked = np.vstack(parts)
        pos, nrm, parent, frac = stacked[:, :3], stacked[:, 3:6], stacked[:, 6].astype(np.int64), stacked[:, 7]
        nxt = np.minimum(parent + 1, len(q) - 1)
        thick = np.clip(dist, settings.min_thickness * w, settings.max_thickness * w)
        row["thickness_clamped"] = int(np.sum((dist < settings.min_thickness * w) | (dist > settings.max_thickness * w)))
        out["positions"] = pos
        out["normals"] = nrm
        out["layer"] = np.full(len(pos), k + 1, np.int32)
        out["path"] = piece_labels(parts).astype(np.int32)
        out["thickness"] = thick[parent] + frac * (thick[nxt] - thick[parent])
        out["bead"] = bead[parent] + frac * (bead[nxt] - bead[parent])
        row["samples"] = len(pos)
        row["subdivided"] = int(len(pos) - len(q))
        row["length_mm"] = round(float(sum(row_norms(np.diff(s[:, :3], axis=0)).sum() for s in samples)), 3)
    return out, row, folded.seconds, perf_counter() - t1


def _layer_toolpaths(k: int, seam: np.ndarray, surfaces: list[trimesh.Trimesh], supports: list,
                     settings: ToolpathSettings) -> tuple[dict[str, np.ndarray], dict[str, float], float, float]:
    """All of layer ``k``'s tool-path work under the ``seam`` rule, one task: rings, pieces from the
    :func:`seam_point` (odd ``k``: printed backward, to end there), orientations (what
    :func:`_orient_layer` returns)."""
    prepared = _prepare_layer(k, surfaces, supports, settings)
    folded = _fold_layer(prepared, None, settings, start=seam, backward=k % 2 == 1)
    return _orient_layer(k, folded, prepared, surfaces, supports, settings)


#: CPU shares of a layer's preparation, fold and orientation under ``chain`` (bunny 1.0 mm, 131 layers:
#: 17.5, 20.1 and 12.2 s, benchmarks/SCALING.md), for :func:`_orient_lanes`' estimate.
_CHAIN_SHARES = (0.35, 0.40, 0.25)


def _orient_lanes(triangles: list[int], workers: int) -> list[str]:
    """The lane (:data:`~curvslice.executors.LANES`) of each layer's orientation under ``chain`` on ``workers``:
    on the workers that prepare (``apart``) but for the last layers', which the chain's worker takes between
    and after its last folds (``chain``) -- as many as balance the lanes' work, estimated from
    :data:`_CHAIN_SHARES` and the layers' ``triangles``. Dask decides where a task goes once it is ready and a worker
    runs whatever it holds while the next fold is on its way: orientations left to Dask went to the chain's
    worker (its queue looked shortest) and each delayed the next fold (bunny: 82 of 131, 14 s of gaps)."""
    p, f, o = _CHAIN_SHARES
    share = min(max((p + o - (workers - 1) * f) / (workers * o), 0.0), 1.0)
    size = np.asarray(triangles, float)
    behind = np.cumsum(size[::-1])[::-1]  # the triangles of a layer and of every later one
    return ["chain" if b <= share * size.sum() and workers > 1 else "apart" for b in behind]


def plan_toolpaths(surfaces: list[trimesh.Trimesh], settings: ToolpathSettings = ToolpathSettings(),
                   progress=None, executor: Executor | None = None) -> Toolpaths:
    """Tool-paths, orientations and extrusion for working surfaces in print order (§3.5.1-3.5.2).

    Layer 1 stands on the platform top ``z = 0``; every later layer also on the ``window``
    layers before it (Eq. 3.3). ``progress`` is an optional tqdm-like object updated per layer.

    Tasks on ``executor`` (default: in-process, in order); every executor gives the same arrays. Under
    the ``seam`` start rule one independent task per layer (:func:`_layer_toolpaths`); under ``chain``
    three: the start-independent rings and thickness floor, then -- a chain, since each layer starts
    where the previous one ended -- its pieces, then its orientations. Only the concatenation (path
    ids numbered on over the layers) is sequential. On a cluster the chain keeps one worker (lane
    ``chain``) and the rings are made on the others (``apart``), so that no task holds up the next
    link; the orientations run on the others too, but for the last layers' (:func:`_orient_lanes`).
    """
    ex = executor if executor is not None else InProcess()
    cleaned = [clean_surface(mesh) for mesh in surfaces]
    supports = [layer_support(surface) for surface in cleaned]
    shared = {"surfaces": ex.share(cleaned), "settings": settings}
    shared_supports = ex.share(supports)
    n = len(cleaned)
    if settings.start_rule == "seam":
        seam = seam_point(cleaned)
        # the largest layers first, so that no large one is left for the end while the other workers idle
        rank = np.argsort(np.argsort([len(m.faces) for m in cleaned], kind="stable"), kind="stable")
        oriented = [ex.submit(_layer_toolpaths, k, seam, supports=shared_supports, priority=int(rank[k]), **shared)
                    for k in range(n)]
    else:
        # priorities (higher first, Dask's order on a worker): a fold above all, then the preparations in layer
        # order (the chain takes them in that order: ties would run in Dask's own order and let a fold wait
        # behind later layers'), then the orientations in layer order
        prepared = [ex.submit(_prepare_layer, k, supports=shared_supports, priority=2 * n - k, lane="apart", **shared)
                    for k in range(n)]
        folded, previous = [], None
        for k, p in enumerate(prepared):
            previous = ex.submit(_fold_layer, p, previous, settings, priority=2 * n + 1, lane="chain")
            folded.append(previous)
        lanes = _orient_lanes([len(m.faces) for m in cleaned], ex.workers)
        oriented = [ex.submit(_orient_layer, k, f, p, supports=shared_supports, priority=n - k, lane=lane, **shared)
                    for k, (f, p, lane) in enumerate(zip(folded, prepared, lanes))]
    layers = ex.gather(oriented, progress)
    out: dict[str, list[np.ndarray]] = {k: [] for k in ("positions", "normals", "layer", "path", "thickness", "bead")}
    per_layer: list[dict[str, float]] = []
    seconds = {"spirals": 0.0, "orientation": 0.0}
    first_path = 0
    for arrays, row, spirals_s, orient_s in layers:
        if "path" in arrays:
            arrays["path"] = arrays["path"] + np.int32(first_path)
        first_path += row["pieces"]
        for name, values in arrays.items():
            out[name].append(values)
        seconds["spirals"] += spirals_s
        seconds["orientation"] += orient_s
        row["seconds"] = round(spirals_s + orient_s, 3)
        per_layer.append(row)
    cat = {k: (np.concatenate(v) if v else np.zeros((0, 3) if k in ("positions", "normals") else 0)) for k, v in out.items()}
    path = cat["path"].astype(np.int32)
    bead = np.maximum(cat["bead"], cat["thickness"]) if len(path) else np.zeros(0)
    extrusion = (extrusion_amounts(cat["positions"], path, cat["thickness"], bead, settings.filament_diameter, cat["layer"])
                 if len(path) else np.zeros(0))
    return Toolpaths(cat["positions"], cat["normals"], cat["layer"].astype(np.int32), path, extrusion,
                     cat["thickness"], np.full(len(path), settings.feed), bead, per_layer, seconds)


def save_toolpaths(outdir: Path, tp: Toolpaths, settings: ToolpathSettings) -> None:
    """Write ``toolpaths.npz`` (the stage contract) and the extended ``toolpaths.gcode``."""
    outdir = Path(outdir)
    np.savez_compressed(outdir / "toolpaths.npz", positions=tp.positions, normals=tp.normals, layer=tp.layer,
                        path=tp.path, extrusion=tp.extrusion, thickness=tp.thickness, feed=tp.feed, bead=tp.bead)
    header = {k: (round(float(np.degrees(v)), 6) if k in ("max_angle", "max_tilt") else v)
              for k, v in asdict(settings).items()}
    header = {("max_angle_deg" if k == "max_angle" else "max_tilt_deg" if k == "max_tilt" else k): v
              for k, v in header.items()}
    header.update(layers=len(tp.layers), samples=len(tp.positions), pieces=int(len(np.unique(tp.path))))
    write_gcode6(outdir / "toolpaths.gcode", tp.positions, tp.normals, tp.extrusion, tp.feed, tp.path, tp.layer, header)
