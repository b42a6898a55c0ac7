"""PNG preview of a decomposition: the parts in colour from two sides, each part's build direction
drawn from the centre of its base cross-section (the arrows of the thesis's Fig. 2.2)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from curvslice.decompose.parts import to_manifold, to_trimesh


def plot_parts(parts: list, path: Path, title: str) -> None:
    """``parts``: objects with ``mesh`` (trimesh), ``base.normal`` and ``base_centre``, in printing order."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    colours = plt.get_cmap("tab20")(np.arange(len(parts)) % 20)
    lo = np.min([p.mesh.bounds[0] for p in parts], axis=0)
    hi = np.max([p.mesh.bounds[1] for p in parts], axis=0)
    size = float((hi - lo).max())
    fig = plt.figure(figsize=(12, 6))
    for k, azim in enumerate((-60, 120)):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        for i, p in enumerate(parts):
            mesh = to_trimesh(to_manifold(p.mesh).simplify(0.02 * size))  # a preview: coarse is enough
            shade = 0.55 + 0.45 * np.clip(mesh.face_normals @ np.array([0.3, -0.4, 0.85]), 0, 1)
            ax.add_collection3d(Poly3DCollection(mesh.triangles, facecolors=colours[i, :3] * shade[:, None],
                                                 edgecolors="none"))
            c, n = p.base_centre, p.base.normal
            ax.quiver(*c, *(0.15 * size * n), color="k", linewidth=1.5)
            ax.text(*(c + 0.17 * size * n), str(i), fontsize=8)
        mid = (lo + hi) / 2
        for setter, m in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid):
            setter(m - size / 2, m + size / 2)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=20, azim=azim)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
