"""Inverse peeling field F̄ (thesis §3.4.4, Algorithm 4, Eq. 3.1).

Peeling removes, from the convex hull C(U ∪ T) of the remaining voxels U and the platform T,
every voxel ε-located on the hull (one curved sheet of constant thickness, like 5-axis CNC
removing material along the hull normals), then iterates on what remains. The peel index F is
inverted, F̄ = 1 + max F − F (Eq. 3.1), so the last voxels peeled are grown first.

Speed-ups that do not change the result: the hull of U ∪ T equals the hull of U's boundary
voxels ∪ T; and a voxel whose whole r-neighbourhood (r = ⌈ε/w⌉, Chebyshev) is still in U is at
least r·w from the hull boundary, so only voxels near U's boundary are tested.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from curvslice.convex_front import PEEL_EPS, hull_of, plane_distance
from curvslice.voxelize import VoxelGrid


def peeling_field(grid: VoxelGrid, platform_vertices: np.ndarray, eps: float = PEEL_EPS,
                  progress=None) -> np.ndarray:
    """Algorithm 4: the inverse peeling field F̄ ≥ 1 on occupied voxels (0 elsewhere), int32 grid.

    ``eps`` is in voxel widths; ``progress`` is an optional tqdm-like object updated with the
    number of voxels peeled.
    """
    w = grid.voxel_size
    eps_mm = eps * w
    r = max(1, int(np.ceil(eps - 1e-9)))
    ball = np.ones((2 * r + 1,) * 3, bool)
    remaining = grid.occupied.copy()
    peel = np.zeros(grid.shape, dtype=np.int32)
    tau = 0
    while remaining.any():
        tau += 1
        near = remaining & ~ndimage.binary_erosion(remaining, ball, border_value=0)
        shell = remaining & ~ndimage.binary_erosion(remaining, border_value=0)
        ijk = np.argwhere(near)
        hull = hull_of(np.vstack([grid.centres(np.argwhere(shell)), platform_vertices]))
        depth = -plane_distance(hull, grid.centres(ijk))
        peeled = ijk[depth < eps_mm]
        if len(peeled) == 0:  # numerically impossible (hull vertices have depth 0); never loop forever
            peeled = ijk[[int(np.argmin(depth))]]
        peel[peeled[:, 0], peeled[:, 1], peeled[:, 2]] = tau
        remaining[peeled[:, 0], peeled[:, 1], peeled[:, 2]] = False
        if progress is not None:
            progress.update(len(peeled))
    fbar = np.where(grid.occupied, 1 + tau - peel, 0).astype(np.int32)
    return fbar
