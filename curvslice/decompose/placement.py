"""Nozzle placement by reachability analysis (thesis §2.3.1).

Random joint configurations of the arm are mapped by forward kinematics to platform frames
(T_E^B T_P^E, Eq. 2.3); frames facing down (platform normal below the horizon) are dropped, as the
nozzle is fixed and points down. The working envelope B is a cube of side ``box`` centred on the
nozzle; the nozzle goes where B holds the most frames, found by exhaustive search over a grid:
the frames are binned into cells of ``cell`` mm and the count of every cube of ``box / cell`` cells
is read off a 3D summed-area table, so all grid positions are evaluated at once.

B's size is not given in the thesis; the default 100 mm cube holds the ~80 mm models of Table 2.1.
Sampling joints uniformly piles frames up on the base axis (joint 1 turns every frame about it),
so the plain optimum sits right above the robot, inside its own links; ``min_radius`` drops frames
closer than that to the base axis (0 = the thesis's rule alone).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from curvslice.kinematics import Robot, fk
from curvslice.workcell import Workcell


@dataclass
class Reachability:
    """Box counts over the grid of nozzle positions and the optimum."""

    counts: np.ndarray  # (nx, ny, nz) frames inside B centred at each grid position
    origin: np.ndarray  # centre of B for counts[0, 0, 0], mm
    cell: float  # grid step, mm
    box: float  # side of B, mm
    frames: int  # frames kept (not facing down)
    samples: int  # configurations sampled

    def centre(self, index: tuple[int, int, int]) -> np.ndarray:
        return self.origin + self.cell * np.asarray(index)

    @property
    def best(self) -> tuple[np.ndarray, int]:
        idx = np.unravel_index(int(np.argmax(self.counts)), self.counts.shape)
        return self.centre(idx), int(self.counts[idx])


def platform_frames(robot: Robot, cell: Workcell, samples: int, seed: int = 0, chunk: int = 200_000,
                    min_radius: float = 0.0) -> np.ndarray:
    """Platform-centre positions (m, 3) of the sampled configurations whose platform faces up (and
    lies at least ``min_radius`` mm from the base axis)."""
    rng = np.random.default_rng(seed)
    lo, hi = cell.limits(robot)
    out = []
    for start in range(0, samples, chunk):
        q = lo + (hi - lo) * rng.random((min(chunk, samples - start), 6))
        T = fk(robot, q) @ cell.platform_mount
        keep = (T[:, 2, 2] > 0) & (np.hypot(T[:, 0, 3], T[:, 1, 3]) >= min_radius)  # platform normal not down
        out.append(T[keep, :3, 3])
    return np.vstack(out)


def box_counts(points: np.ndarray, box: float, cell: float) -> Reachability:
    """Frames inside B for every grid position (exhaustive search by a summed-area table)."""
    b = int(round(box / cell))
    if b < 1 or abs(b * cell - box) > 1e-9 * box:
        raise ValueError(f"the box side ({box} mm) must be a multiple of the grid step ({cell} mm)")
    lo = np.floor(points.min(axis=0) / cell) * cell
    idx = np.floor((points - lo) / cell).astype(np.int64)
    shape = idx.max(axis=0) + 1
    hist = np.zeros(tuple(shape + 1), np.int64)  # one leading zero plane per axis after the shift
    np.add.at(hist, tuple((idx + 1).T), 1)
    S = hist.cumsum(0).cumsum(1).cumsum(2)
    n = np.maximum(shape - b + 1, 1)
    i, j, k = (np.arange(m) for m in n)
    I, J, K = np.ix_(i, j, k)
    c = (S[I + b, J + b, K + b] - S[I, J + b, K + b] - S[I + b, J, K + b] - S[I + b, J + b, K]
         + S[I, J, K + b] + S[I, J + b, K] + S[I + b, J, K] - S[I, J, K]) if (shape >= b).all() else np.zeros(n, np.int64)
    return Reachability(c, lo + cell * b / 2.0, cell, box, len(points), 0)


def brute_force_counts(points: np.ndarray, centres: np.ndarray, box: float) -> np.ndarray:
    """Frames with ``centre - box/2 <= p < centre + box/2`` per centre, by direct comparison."""
    half = box / 2.0
    return np.array([np.all((points >= c - half) & (points < c + half), axis=1).sum() for c in centres])


def place_nozzle(robot: Robot, cell: Workcell, box: float = 100.0, grid: float = 10.0, samples: int = 1_000_000,
                 seed: int = 0, min_radius: float = 0.0) -> tuple[Workcell, Reachability]:
    """The workcell with its nozzle moved to the optimum of §2.3.1 (orientation kept)."""
    pts = platform_frames(robot, cell, samples, seed, min_radius=min_radius)
    reach = box_counts(pts, box, grid)
    reach.samples = samples
    centre, _ = reach.best
    nozzle = cell.nozzle.copy()
    nozzle[:3, 3] = centre
    return replace(cell, nozzle=nozzle, name=f"{cell.robot}-placed"), reach


def plot_reachability(reach: Reachability, path, title: str) -> None:
    """PNG of the box counts through the optimum: the horizontal and the vertical (x-z) slice."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centre, count = reach.best
    i, j, k = np.unravel_index(int(np.argmax(reach.counts)), reach.counts.shape)
    o, c = reach.origin, reach.cell
    nx, ny, nz = reach.counts.shape
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, img, ext, labels in (
        (axes[0], reach.counts[:, :, k].T, (o[0], o[0] + c * nx, o[1], o[1] + c * ny), ("x (mm)", "y (mm)")),
        (axes[1], reach.counts[:, j, :].T, (o[0], o[0] + c * nx, o[2], o[2] + c * nz), ("x (mm)", "z (mm)")),
    ):
        im = ax.imshow(img, origin="lower", extent=(ext[0] - c / 2, ext[1] - c / 2, ext[2] - c / 2, ext[3] - c / 2),
                       cmap="viridis", aspect="equal")
        ax.plot(centre[0], centre[1] if labels[1].startswith("y") else centre[2], "r+", ms=14, mew=2)
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
        fig.colorbar(im, ax=ax, label=f"frames inside B ({reach.box:g} mm)")
    fig.suptitle(f"{title}: optimum {np.round(centre, 1).tolist()} mm, {count} of {reach.frames} frames")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
