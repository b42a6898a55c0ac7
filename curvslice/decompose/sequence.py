"""Phase II of the RoboFDM decomposition: sequence planning on the part graph (thesis §2.4.2).

The coarse patches and their adjacency form an undirected graph G; a breadth-first traversal from
a root orients it (parents printed before children). A child is printed from the plane separating
it from its parent, along that plane's normal oriented from parent to child. The root's direction
minimizes its facing-down area while keeping every separating plane facing up (Constraint II).
A separating plane that would face down (Constraint II) is not cut. The thesis picks the root interactively; with ``root=None`` every patch is tried and the root with
the smallest total risky area (all patches along their directions) is kept.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import trimesh

from curvslice.decompose.constraints import faces_up
from curvslice.decompose.parts import Plane
from curvslice.decompose.risky import PLATFORM_CONTACT_MM
from curvslice.decompose.shape_analysis import CoarseDecomposition


@dataclass
class Sequence:
    """A BFS tree over the coarse patches: order, parent per patch, oriented base planes."""

    root: int
    order: list[int]
    parent: dict[int, int]  # child patch -> parent patch
    planes: dict[int, Plane]  # child patch -> base plane (normal from parent into child)
    root_direction: np.ndarray
    score: float  # total risky area of the patches along their directions (analysis mesh), mm²


def fibonacci_sphere(n: int, hemisphere: bool = False) -> np.ndarray:
    """n nearly uniform unit vectors on the sphere (or the upper hemisphere z ≥ 0)."""
    i = np.arange(n) + 0.5
    z = 1 - i / n if hemisphere else 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def bfs_tree(root: int, edges: list[tuple[int, int]]) -> tuple[list[int], dict[int, int]]:
    """Breadth-first order and parent map of the graph ``edges`` from ``root``."""
    nbrs: dict[int, list[int]] = {}
    for i, j in edges:
        nbrs.setdefault(i, []).append(j)
        nbrs.setdefault(j, []).append(i)
    order, parent, queue = [root], {}, deque([root])
    while queue:
        i = queue.popleft()
        for j in sorted(nbrs.get(i, [])):
            if j != root and j not in parent:
                parent[j] = i
                order.append(j)
                queue.append(j)
    return order, parent


def plan_sequence(coarse: CoarseDecomposition, alpha_max: float, root: int | None = None,
                  directions: int = 400, tie: float = 0.005, min_contact: float = 0.5) -> Sequence:
    """Phase II for one root, or the best root when ``root`` is None.

    For a root r and a candidate root direction d (``directions`` nearly uniform on the sphere),
    the separating planes facing down along d are not cut (Constraint II); every patch is then
    printed along the plane normal of its nearest cut ancestor edge, or d in the root's region,
    and (r, d) minimizing the total facing-down area of all patches is kept (faces on the
    platform, within 0.5 mm of the lowest point along d, excluded); among the choices within
    ``tie`` × the model's area of that minimum, the one with the largest platform contact.
    When the model has a flat face (≥ 1 % of its area) to stand on, only directions whose platform
    contact is at least ``min_contact`` × the largest are considered: Eq. 2.1 alone would let a flat bottom pass by tilting it just under α_max, leaving
    the model standing on an edge (not in the thesis, which picks the root by hand).
    """
    mesh, labels = coarse.mesh, coarse.labels
    normals, area = mesh.face_normals, mesh.area_faces
    # candidates: nearly uniform, plus the axes and the directions that stand a large flat face on
    # the platform (a uniform set misses a flat bottom by a few degrees)
    big = np.argsort(-area)[:50]
    cand = np.vstack([fibonacci_sphere(directions), np.eye(3), -np.eye(3), -normals[big]])
    n_patches = len(coarse.areas)
    onehot = np.eye(n_patches)[labels]  # (F, P)
    low = (mesh.vertices @ cand.T).min(axis=0)
    above = (mesh.vertices[mesh.faces] @ cand.T).max(axis=1) > low + PLATFORM_CONTACT_MM  # (F, D)
    down_d = onehot.T @ (area[:, None] * ((normals @ cand.T + np.sin(alpha_max) < 0) & above))  # (P, D)
    edges = list(coarse.planes)
    plane_n = np.array([coarse.planes[e].normal for e in edges])  # oriented low -> high patch index
    down_e = onehot.T @ (area[:, None] * (normals @ plane_n.T + np.sin(alpha_max) < 0))  # (P, E)
    down_e_rev = onehot.T @ (area[:, None] * (-normals @ plane_n.T + np.sin(alpha_max) < 0))
    contact = area @ ~above  # (D,) platform contact area along each direction
    options = []
    for r in (range(n_patches) if root is None else [root]):
        order, parent = bfs_tree(r, edges)
        edge_of = {j: edges.index((min(i, j), max(i, j))) for j, i in parent.items()}
        sign = {j: 1.0 if parent[j] < j else -1.0 for j in parent}
        up = np.stack([sign[j] * (cand @ plane_n[edge_of[j]]) > 1e-6 for j in order[1:]], axis=0) \
            if parent else np.zeros((0, len(cand)), bool)
        row = {j: k for k, j in enumerate(order[1:])}
        # source[j]: per direction, -1 = printed along d (root region) else the child whose plane it uses
        source = {r: np.full(len(cand), -1)}
        total = down_d[r].copy()
        for j in order[1:]:
            source[j] = np.where(up[row[j]], j, source[parent[j]])
            along = np.where(source[j] < 0, down_d[j], 0.0)
            for s_ in set(source[j][source[j] >= 0].tolist()):
                e = edge_of[s_]
                val = (down_e if sign[s_] > 0 else down_e_rev)[j, e]
                along = np.where(source[j] == s_, val, along)
            total = total + along
        options.append((r, order, parent, edge_of, sign, up, row, total))
    flat = contact.max() >= 0.01 * area.sum()  # the model has a flat face to stand on
    stands = contact >= min_contact * contact.max() if flat else np.ones(len(cand), bool)
    least = min(float(o[-1][stands].min()) for o in options)
    best_key, best = None, None
    for r, order, parent, edge_of, sign, up, row, total in options:
        ok = stands & (total <= least + tie * area.sum())
        if not ok.any():
            continue
        k = int(np.flatnonzero(ok)[np.argmax(contact[ok])])
        key = (float(contact[k]), -float(total[k]))
        if best_key is None or key > best_key:
            planes = {}
            for j in order[1:]:
                if up[row[j], k]:
                    p = coarse.planes[edges[edge_of[j]]]
                    planes[j] = p if sign[j] > 0 else Plane(-p.normal, -p.offset)
            best_key, best = key, Sequence(r, order, parent, planes, cand[k], float(total[k]))
    assert best is not None
    assert all(faces_up(p.normal, best.root_direction) for p in best.planes.values())
    return best


def breadth_first_order(root: int, parent: dict[int, int | None]) -> list[int]:
    """Breadth-first order of the part tree (each part printed after its parent), §2.4.2."""
    order, frontier = [root], [root]
    while frontier:
        frontier = sorted(c for c, p in parent.items() if p in frontier)
        order += frontier
    return order


def _ancestors(k: int, parent: dict[int, int | None]) -> set[int]:
    out = set()
    while parent.get(k) is not None:
        k = parent[k]
        out.add(k)
    return out


def extruder_aware_order(root: int, parent: dict[int, int | None], meshes: dict[int, trimesh.Trimesh],
                         directions: dict[int, np.ndarray], cell, samples: int = 100, spacing: float = 3.0,
                         seed: int = 0) -> tuple[list[int], dict[int, tuple[int, int]]]:
    """A printing order (parents first, as the breadth-first one) in which the extruder, printing a
    part, meets as little of the parts printed before it as can be: ``samples`` surface points of
    each part stand for its nozzle positions, the other parts' surface on a ``spacing`` mm grid for
    their material, and a position is *blocked* when every turn of the extruder about its axis holds
    such material (:func:`extruder_hits`). Greedy: among the parts whose parent is printed, the next
    is the one whose own blocked positions plus those it would cause to every unrelated part still to
    print are fewest (ties: breadth-first order; an ancestor, printed before in any order, counts
    alike for every candidate). Not in the thesis (its BFS ignores the extruder,
    §2.6): on the bunny it prints first the sibling that leans over the other (in BFS order the heater
    block hit the part printed before). Returns the order and each part's (blocked, sampled)
    positions in it."""
    from curvslice.decompose.constraints import extruder_hits

    bfs = breadth_first_order(root, parent)
    rng = np.random.default_rng(seed)
    pos = {k: m.vertices[rng.choice(len(m.vertices), min(samples, len(m.vertices)), replace=False)]
           for k, m in meshes.items()}
    obs = {}
    for k, m in meshes.items():  # one surface point per grid cell
        _, first = np.unique(np.floor(m.vertices / spacing), axis=0, return_index=True)
        obs[k] = m.vertices[first]
    anc = {k: _ancestors(k, parent) for k in meshes}
    hits = {(k, j): extruder_hits(cell, pos[k], directions[k], obs[j]) for k in meshes for j in meshes
            if k != j and k not in anc[j]}  # not with its descendants, printed after it in any order

    def blocked(k: int, before: list[int]) -> int:
        h = [hits[k, j] for j in before if (k, j) in hits]
        return int(np.all(np.any(h, axis=0), axis=1).sum()) if h else 0

    order, left = [root], [k for k in bfs if k != root]
    while left:
        ready = [c for c in left if parent[c] in order]
        score = {c: blocked(c, order) + sum(blocked(k, [c]) for k in left if k != c and c not in anc[k]) for c in ready}
        nxt = min(ready, key=lambda c: (score[c], bfs.index(c)))
        order.append(nxt)
        left.remove(nxt)
    return order, {k: (blocked(k, order[:i]), len(pos[k])) for i, k in enumerate(order)}
