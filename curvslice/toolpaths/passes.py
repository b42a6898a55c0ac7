"""Passes that are not contours: ridge passes of thin walls and gap passes through what the
spirals leave open (thesis §3.7, the medial-axis gaps), the removal of self-crossings, and passes cut
where a link leaves the layer."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from curvslice.executors import query_threads
from curvslice.geodesic import edge_keys
from curvslice.toolpaths.constants import (BEAD_MIN, BEAD_RANGE, BRANCH_MARGIN, BRANCH_ROUNDS, CROSS_ANGLE, CROSS_GAP, CROSS_PERCENTILE,
                                           DENSE_STEP, GAP_PASS_LENGTH, GAP_PASS_VERTICES, JOIN_GAP, MAX_SHIFT, OFF_LAYER, OPEN_GAP, RIDGE_FLOOR,
                                           RIDGE_REACH, THIN_REGION, UNCROSS_ROUNDS, WALL_LENGTH)
from curvslice.toolpaths.resampling import resample
from curvslice.vectors import row_norms


def thin_passes(vertices: np.ndarray, faces: np.ndarray, dist: np.ndarray,
                width: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """Passes along the ridge of each connected region narrower than ``2·THIN_REGION`` widths.

    Closes the medial-axis gap of thin walls (thesis §3.7) by varying the bead width through the
    extrusion amount: the ridge of the boundary distance ``d`` is the region's centre line and
    ``2·d`` there (the largest ``d`` within half a width) its local width, the bead it needs (clamped to
    ``[BEAD_MIN, 2·THIN_REGION]`` widths; :func:`fit_beads` sets the final one). A ridge is the longest of the shortest paths over mesh
    edges weighted by ``length / d²`` (cheap along the ridge); branches it leaves open (vertices
    more than a quarter width beyond half a bead of it) get their own ridges, up to ``BRANCH_ROUNDS`` rounds,
    but a ridge lying beside the region's passes, within reach of their widest bead (every point of it, plus
    its own half-width ``d``, within ``BEAD_RANGE[1] / 2`` widths of them), is where the region widens, not a
    branch: the beads there widen over it (:func:`fit_beads`) and it gets no pass of its own (an unseen bowl
    shell at 0.6 mm, layer 40: four arcs of its inner skin, each widening to 0.9 w at 45°, got a second pass
    3.3 w long beside the first, 17 % overlap). Returns the faces of the other regions and the passes.
    """
    f = np.asarray(faces, np.int64)
    n = len(vertices)
    pairs = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    code = np.unique(edge_keys(pairs[:, 0], pairs[:, 1], n))
    edges = np.c_[code // n, code % n]
    graph = sp.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    top = np.full(label.max() + 1, np.inf)
    finite = np.isfinite(dist)
    top[np.unique(label[finite])] = -np.inf
    np.maximum.at(top, label[finite], dist[finite])
    thin_label = np.nonzero(top < THIN_REGION * width)[0]
    passes, widths = [], []
    if len(thin_label) == 0:
        return f, passes
    thin_v = np.nonzero(np.isin(label, thin_label))[0]  # the thin regions' own graph (small)
    e = np.searchsorted(thin_v, edges[np.isin(label[edges[:, 0]], thin_label)])
    mid = np.maximum(0.5 * (dist[thin_v[e[:, 0]]] + dist[thin_v[e[:, 1]]]), RIDGE_FLOOR * width)
    length = row_norms(vertices[thin_v[e[:, 0]]] - vertices[thin_v[e[:, 1]]])
    weighted = sp.coo_matrix((length / mid**2, (e[:, 0], e[:, 1])), shape=(len(thin_v),) * 2).tocsr()
    weighted = weighted + weighted.T
    metric = sp.coo_matrix((length, (e[:, 0], e[:, 1])), shape=(len(thin_v),) * 2).tocsr()
    metric = metric + metric.T
    done = []
    for c in thin_label:
        todo = np.nonzero(label[thin_v] == c)[0]
        mine = len(passes)
        widened: list[np.ndarray] = []  # ridges where the region widens beside its passes: (points, bead) rows
        for _ in range(BRANCH_ROUNDS):
            if len(todo) < 3:
                break
            sub = weighted[todo][:, todo]
            n_patch, patch = connected_components(sub, directed=False)
            for k in range(n_patch):
                members = todo[patch == k]
                if len(members) < 3:
                    continue
                ridge = thin_v[members[_longest_path(metric[members][:, members], weighted[members][:, members])]]
                pts = vertices[ridge].copy()
                if len(passes) == mine and row_norms(np.diff(pts, axis=0)).sum() < WALL_LENGTH * width:
                    break  # a blob, not a wall: the contours print it
                if len(pts) > 2:
                    pts[1:-1] = (pts[:-2] + pts[1:-1] + pts[2:]) / 3.0  # the edge path's zigzag smoothed
                near = cKDTree(pts).sparse_distance_matrix(cKDTree(vertices[thin_v[members]]), RIDGE_REACH * width,
                                                           output_type="coo_matrix")
                half = dist[ridge].copy()  # the ridge of d near each point: an edge path runs beside it
                np.maximum.at(half, near.row, dist[thin_v[members[near.col]]])
                bead = np.clip(2.0 * half, BEAD_MIN * width, 2.0 * THIN_REGION * width)
                if len(passes) > mine:
                    beside = cKDTree(np.vstack([resample(q, DENSE_STEP * width) for q in passes[mine:]])).query(pts)[0]
                    if (beside + dist[ridge]).max() <= 0.5 * BEAD_RANGE[1] * width:
                        widened.append(np.c_[pts, bead])
                        continue
                passes.append(pts)
                widths.append(bead)
            if len(passes) == mine:
                break
            done.append(c)
            dense = np.vstack([resample(np.c_[p, b], DENSE_STEP * width) for p, b in zip(passes[mine:], widths[mine:])]
                              + [resample(x, DENSE_STEP * width) for x in widened])
            gap, nearest = cKDTree(dense[:, :3]).query(vertices[thin_v[todo]])
            todo = todo[gap > 0.5 * dense[nearest, 3] + BRANCH_MARGIN * width]
    keep = ~np.isin(label[f[:, 0]], done)
    return f[keep], passes


def _longest_path(graph: sp.csr_matrix, route: sp.csr_matrix | None = None) -> np.ndarray:
    """Node indices of the longest shortest path found by two Dijkstra sweeps over ``graph`` (edge
    lengths), or, with ``route`` (other costs on the same edges), the cheapest path by ``route``
    between the two ends those sweeps find: a ridge runs between the ends of a region, which a
    sweep over a cost that soars at the boundary would not find (the costliest node to reach is a
    boundary one next to the start: cheburashka 0.8 layer 11, a 13 w strip got a 2.8 w ridge)."""
    d0 = dijkstra(graph, indices=0)
    far = int(np.argmax(np.where(np.isfinite(d0), d0, -1)))
    d1, pred = dijkstra(graph, indices=far, return_predecessors=True)
    node = int(np.argmax(np.where(np.isfinite(d1), d1, -1)))
    if route is not None:
        pred = dijkstra(route, indices=far, return_predecessors=True)[1]
    chain = [node]
    while pred[node] >= 0:
        node = int(pred[node])
        chain.append(node)
    return np.asarray(chain)


def gap_passes(vertices: np.ndarray, faces: np.ndarray, pieces: list[np.ndarray], width: float,
               widths: list[np.ndarray] | None = None, min_vertices: int = GAP_PASS_VERTICES,
               bridge: np.ndarray | None = None) -> list[np.ndarray]:
    """Extra passes through what the spirals leave open: narrow strips (thinner than a bead, where
    no contour exists) and the medial-axis gaps between contour families (thesis §3.7).

    Vertices more than ``OPEN_GAP - 0.5`` widths beyond the edge of every bead (``widths``: each piece
    vertex's bead, default ``width``) form connected patches; each patch at least
    ``min_vertices`` vertices whose sliver (the patch and the hairline along the beads) is half a width
    long -- down to the tips of a layer that its outermost contour cuts short -- gets one pass along its longest shortest path (two Dijkstra sweeps on its
    mesh edges), which runs down the middle of a strip. (:func:`needed_pieces` then drops those
    that add more overlap than coverage.) ``bridge``: (n,) the vertices of a bridged hole's fan only
    (:func:`~curvslice.toolpaths.plan.bridge_small_holes`), never open: a bridge lets a bead cross a hole,
    it holds nothing to print (the corpus dome at 1.5 mm, layer 12: a ring round a hole 1.8 w across got a
    gap pass through the bridge, printed across the hole with 8.5 % overlap where it met the ring).
    """
    v = np.asarray(vertices, np.float64)
    if not pieces:
        open_v = np.ones(len(v), bool)
    else:
        widths = widths if widths is not None else [np.full(len(p), width) for p in pieces]
        dense = np.vstack([resample(np.c_[p, b], DENSE_STEP * width) for p, b in zip(pieces, widths)])
        gap, nearest = cKDTree(dense[:, :3]).query(v, workers=query_threads(len(v)))
        open_v = gap > 0.5 * dense[nearest, 3] + (OPEN_GAP - 0.5) * width
    if bridge is not None:
        open_v &= ~bridge
    ring = np.roll(faces, -1, axis=1)
    inside = open_v[faces] & open_v[ring]
    code = np.unique(edge_keys(faces[inside], ring[inside], len(v)))
    edges = np.c_[code // len(v), code % len(v)]
    if len(edges) == 0:
        return []
    length = row_norms(v[edges[:, 0]] - v[edges[:, 1]])
    graph = sp.coo_matrix((length, (edges[:, 0], edges[:, 1])), shape=(len(v), len(v))).tocsr()
    graph = graph + graph.T
    n_comp, label = connected_components(graph, directed=False)
    sizes = np.bincount(label[open_v], minlength=n_comp)
    passes = []
    # what lies farther from a pass than its widest bead reaches once the fit has shifted it towards that side
    # (half of BEAD_RANGE's widest plus MAX_SHIFT), no bead of it can cover: a patch wider than that gets passes of
    # its own there (elephant 0.8 layer 73, a net of strips round holes: a patch 3 w across got one pass down its
    # side, 91 % coverage); a strip that one shifted bead spans keeps one pass (a second one beside it, each at
    # least as wide as the layer is thick, overlapped it: the corpus' thin walls at 1 mm)
    reach = (0.5 * BEAD_RANGE[1] + MAX_SHIFT) * width
    todo = [np.nonzero((label == c) & open_v)[0] for c in np.nonzero(sizes >= min_vertices)[0]]
    while todo:
        members = todo.pop(0)
        chain = members[_longest_path(graph[members][:, members])]
        # the open patch is its sliver less the hairline along the beads: the sliver is GAP_PASS_LENGTH
        # long when the patch is that less the hairline (the spikes of cheburashka 0.8 layer 45)
        if row_norms(np.diff(v[chain], axis=0)).sum() + (OPEN_GAP - 0.5) * width < GAP_PASS_LENGTH * width:
            continue
        passes.append(v[chain])
        beyond = cKDTree(resample(v[chain], DENSE_STEP * width)).query(v[members])[0] > reach
        rest = members[beyond]
        if len(rest) >= min_vertices:
            n_rest, rest_label = connected_components(graph[rest][:, rest], directed=False)
            todo += [part for part in (rest[rest_label == k] for k in range(n_rest)) if len(part) >= min_vertices]
    return passes


def join_touching(passes: list[np.ndarray], width: float) -> list[np.ndarray]:
    """``passes`` with those whose ends lie within ``JOIN_GAP`` widths of each other joined end to
    end into one pass (each end joined at most once, nearest pairs first, no pass joined into a
    loop with itself).

    Slivers and thin regions that touch at a single vertex (a layer pinched by the voxel steps:
    homer 0.8 layer 38, a chain of eleven sliver centre lines meeting end to end) are separate
    regions of the mesh, so each got a pass of its own, and every pass's round cap was laid over
    its neighbour's at the shared vertex (9.5 % overlap); one continuous pass deposits there once."""
    if len(passes) < 2:
        return passes
    ends = np.vstack([[p[0], p[-1]] for p in passes])
    pairs = cKDTree(ends).query_pairs(JOIN_GAP * width, output_type="ndarray")
    if len(pairs) == 0:
        return passes
    pairs = pairs[pairs[:, 0] // 2 != pairs[:, 1] // 2]
    pairs = pairs[np.argsort(row_norms(ends[pairs[:, 0]] - ends[pairs[:, 1]]), kind="stable")]
    root = list(range(len(passes)))

    def find(i: int) -> int:
        while root[i] != i:
            root[i] = root[root[i]]
            i = root[i]
        return i

    mate = np.full(len(ends), -1)
    for a, b in pairs:
        if mate[a] < 0 and mate[b] < 0 and find(a // 2) != find(b // 2):
            mate[a], mate[b] = b, a
            root[find(a // 2)] = find(b // 2)
    if (mate < 0).all():
        return passes
    joined, used = [], np.zeros(len(passes), bool)
    for start in range(len(ends)):
        if used[start // 2] or mate[start] >= 0:
            continue  # chains are walked from a free end
        chain, end = [], start
        while True:
            k = end // 2
            used[k] = True
            p = passes[k] if end % 2 == 0 else passes[k][::-1]
            chain.append(p if not chain or np.linalg.norm(p[0] - chain[-1][-1]) > 0 else p[1:])
            out = end ^ 1  # the other end of this pass
            if mate[out] < 0:
                break
            end = mate[out]
        joined.append(np.vstack(chain))
    return joined


def split_off_layer(passes: list[np.ndarray], off: Callable[[np.ndarray], np.ndarray],
                    width: float, on_layer: bool = False) -> list[np.ndarray]:
    """``passes`` cut in two wherever a segment leaves the layer: a point at a quarter, half or three
    quarters of it lies more than ``OFF_LAYER`` widths from the layer (``off(points)``: their distances to
    it). Ring walks follow the mesh; the straight links between rings and into spliced children do not,
    and across a fold of a curved layer or a notch in its edge such a link is a bead laid through the air,
    outside the part (kitten 1 mm, layer 64: a 4 mm link across a fold 0.75 mm outside the solid, its whole
    bead beyond it). There the piece ends and a travel move takes its place. Only segments longer than
    ``OFF_LAYER`` widths are tested (a shorter one cannot leave); with ``on_layer`` (every point lies on the
    layer) only those longer than twice that, as every point of a chord lies within half its length of an
    end. The passes' first three columns are the points; further columns (bead widths...) are cut with them."""
    factor = 2.0 if on_layer else 1.0
    long = [np.flatnonzero(row_norms(np.diff(p[:, :3], axis=0)) > factor * OFF_LAYER * width) for p in passes]
    u = np.array([0.25, 0.5, 0.75])
    probe = [(p[k, None, :3] + u[None, :, None] * (p[k + 1, :3] - p[k, :3])[:, None]).reshape(-1, 3)
             for p, k in zip(passes, long)]
    if not sum(len(q) for q in probe):
        return list(passes)
    far = off(np.vstack(probe)) > OFF_LAYER * width
    out, at = [], 0
    for p, k in zip(passes, long):
        cuts = k[far[at:at + 3 * len(k)].reshape(-1, 3).any(axis=1)] + 1
        at += 3 * len(k)
        out += [q for q in np.split(p, cuts) if len(q)]
    return out


def uncross(piece: np.ndarray, width: float, rounds: int = UNCROSS_ROUNDS) -> np.ndarray:
    """Order of a piece's points without the places where it crosses itself (2-opt: reverse the
    stretch between two crossing segments, so their ends are joined the other way round; the
    path stays one piece over the same points and gets shorter, so this ends).

    Contour arcs never cross each other; the links between them -- from ring to ring, into a
    spliced child spiral -- can, where the cuts of neighbouring rings drift apart (Zhao et al.
    2016 align them on one cut line) or once :func:`fit_beads` has moved the passes sideways.
    Two segments cross when they come within ``CROSS_GAP`` widths of each other at inner points,
    more than ``CROSS_ANGLE`` apart. Crossings whose stretches do not overlap are undone in the same round.
    """
    order = np.arange(len(piece))
    for _ in range(rounds):
        p = np.asarray(piece, np.float64)[order]
        if len(p) < 4:
            return order
        a, b = p[:-1], p[1:]
        length = row_norms(b - a)
        mid = 0.5 * (a + b)
        tree = cKDTree(mid)
        typical = float(np.percentile(length, CROSS_PERCENTILE)) + 1e-9
        long = np.nonzero(length > typical)[0]  # the few long links, against everything near
        near = tree.query_ball_point(mid[long], 0.5 * (length[long] + length.max()) + 1e-9)
        pairs = np.vstack([tree.query_pairs(typical, output_type="ndarray"),
                           np.column_stack([np.repeat(long, [len(n) for n in near]),
                                            np.fromiter((k for n in near for k in n), np.int64)])])
        i, j = pairs.min(axis=1), pairs.max(axis=1)
        keep = j > i + 1
        i, j = i[keep], j[keep]
        if len(i) == 0:
            return order
        u, v, w0 = b[i] - a[i], b[j] - a[j], a[i] - a[j]
        uu, uv, vv = np.einsum("ij,ij->i", u, u), np.einsum("ij,ij->i", u, v), np.einsum("ij,ij->i", v, v)
        uw, vw = np.einsum("ij,ij->i", u, w0), np.einsum("ij,ij->i", v, w0)
        den = uu * vv - uv * uv
        with np.errstate(all="ignore"):
            s = np.clip((uv * vw - vv * uw) / den, 0, 1)
            t = np.clip((uu * vw - uv * uw) / den, 0, 1)
        gap = row_norms(w0 + s[:, None] * u - t[:, None] * v)
        sin = np.sqrt(np.maximum(den, 0)) / np.maximum(np.sqrt(uu * vv), 1e-300)
        hit = (gap < CROSS_GAP * width) & (s > 0.0) & (s < 1.0) & (t > 0.0) & (t < 1.0) & (sin > np.sin(CROSS_ANGLE))
        if not hit.any():
            return order
        last = -2
        for a_k, b_k in sorted(zip(i[hit].tolist(), j[hit].tolist())):  # crossings whose stretches
            if a_k > last:  # do not overlap are undone in the same round
                order[a_k + 1:b_k + 1] = order[a_k + 1:b_k + 1][::-1].copy()
                last = b_k + 1
    return order

