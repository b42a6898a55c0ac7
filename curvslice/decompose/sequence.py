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

from curvslice.decompose.constraints import faces_up
from curvslice.decompose.parts import Plane
from curvslice.decompose.risky import risky_mask
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
                  directions: int = 400) -> Sequence:
    """Phase II for one root, or the best root when ``root`` is None."""
    mesh, labels = coarse.mesh, coarse.labels
    normals, area = mesh.face_normals, mesh.area_faces
    heights = mesh.vertices
    candidates = fibonacci_sphere(directions)
    n_patches = len(coarse.areas)
    roots = range(n_patches) if root is None else [root]
    best: Sequence | None = None
    for r in roots:
        order, parent = bfs_tree(r, list(coarse.planes))
        planes = {}
        for j, i in parent.items():
            p = coarse.planes[(min(i, j), max(i, j))]
            planes[j] = p if i < j else Plane(-p.normal, -p.offset)
        # root direction: facing-down area of the root patch (faces on the lowest plane excluded);
        # a child whose plane would face down along d is not cut and counts with the root
        low = (heights @ candidates.T).min(axis=0)

        def facing_down(face: np.ndarray) -> np.ndarray:
            tri_h = (heights[mesh.faces[face]] @ candidates.T).max(axis=1)  # (Fr, D)
            down = (normals[face] @ candidates.T + np.sin(alpha_max) < 0) & (tri_h > low + 0.5)
            return area[face] @ down

        root_risk = facing_down(labels == r)
        for j, i in parent.items():
            if i == r:
                up = candidates @ planes[j].normal > 1e-6
                own = float(area[(labels == j) & risky_mask(normals, planes[j].normal, alpha_max)].sum())
                root_risk = root_risk + np.where(up, own, facing_down(labels == j))
        k = int(np.argmin(root_risk))
        d = candidates[k]
        # deeper planes facing down (Constraint II) are not cut: those patches stay with their parent
        planes = {j: p for j, p in planes.items() if faces_up(p.normal, d)}
        # total: every patch along the direction of its nearest cut ancestor (the root: d)
        direction = {r: d}
        for j in order[1:]:
            direction[j] = planes[j].normal if j in planes else direction[parent[j]]
        lowest = (heights[mesh.faces] @ d).max(axis=1) <= low[k] + 0.5
        total = sum(float(area[(labels == j) & ~lowest & risky_mask(normals, direction[j], alpha_max)].sum())
                    for j in order)
        if best is None or total < best.score - 1e-9:
            best = Sequence(r, order, parent, planes, d, total)
    if best is None:
        raise ValueError("no root direction found")
    assert all(faces_up(p.normal, best.root_direction) for p in best.planes.values())
    return best
