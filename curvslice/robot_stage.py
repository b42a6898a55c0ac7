"""The robot stage, layer by layer (§3.5.3, §4.3): each layer's pose-continuous motion (the ladder
graph search, :func:`curvslice.motion.plan_layer`) and its trajectory (jerk filter and time-scaling,
:func:`curvslice.jerk.layer_trajectory`) depend only on that layer's waypoints and on the earlier
layers as obstacles, so blocks of layers are independent tasks on any executor; joining them (a
joint move between layers) is the only sequential step and is cheap.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import trimesh

from curvslice.collision import PART_BLOCK, CollisionScene
from curvslice.executors import Executor, InProcess
from curvslice.jerk import merge_reports, rest_to_rest_time, trajectory_stage
from curvslice.kinematics import load_robot
from curvslice.motion import PrintMotion, join_motions, joint_move_time, plan_layer
from curvslice.workcell import Workcell


def layer_blocks(layer: np.ndarray) -> list[list[int]]:
    """The print's layer values in blocks of :data:`~curvslice.collision.PART_BLOCK` consecutive
    layers: a block's tasks share one collision scene, whose part BVH of the layers before the block
    is built once (the scene's own block boundary)."""
    values = [int(v) for v in np.unique(layer)]
    return [values[i:i + PART_BLOCK] for i in range(0, len(values), PART_BLOCK)]


def plan_block(values: list[int], *, cell: Workcell, toolpaths: dict[str, np.ndarray], layers: list[trimesh.Trimesh],
               platform_vertices: np.ndarray | None, cost: str, max_rotations: int | None,
               trajectory: str) -> tuple[list[PrintMotion], PrintMotion, dict]:
    """One task: the graph motion of each layer in ``values`` (:func:`curvslice.motion.plan_layer`),
    and the block's trajectory (:func:`curvslice.jerk.trajectory_stage` on the block's layers joined:
    one Gauss-Newton system per block, not per layer) and its report."""
    robot = load_robot(cell.robot)
    scene = CollisionScene(robot, cell, platform_vertices)
    layer = np.asarray(toolpaths["layer"])
    graphs = [plan_layer(robot, cell, toolpaths, np.flatnonzero(layer == v), scene.for_layer(layers, v), cost,
                         max_rotations) for v in values]
    block = join_motions(graphs, joint_move_time(cell))
    final, report = trajectory_stage(robot, cell, toolpaths, block, trajectory,
                                     lambda value: scene.for_layer(layers, value))
    return graphs, final, report


def plan_robot(cell: Workcell, toolpaths: dict[str, np.ndarray], layers: list[trimesh.Trimesh],
               platform_vertices: np.ndarray | None = None, cost: str = "l1", max_rotations: int | None = None,
               trajectory: str = "jerk", executor: Executor | None = None,
               progress: Any = None) -> tuple[PrintMotion, PrintMotion, dict]:
    """The whole print: blocks of layers (:func:`layer_blocks`) as tasks on ``executor`` (default
    in-process; the result does not depend on it), then joined in print order — by the graph's joint
    moves for the graph motion, by Ruckig's rest-to-rest moves for the jerk-optimized one. Returns the
    graph motion, the final motion and the trajectory report. ``progress``: tqdm-like, in layers."""
    blocks = layer_blocks(np.asarray(toolpaths["layer"]))
    ex = executor if executor is not None else InProcess()
    done = ex.map(plan_block, blocks, progress=_Blocks(progress, [len(b) for b in blocks]), cell=cell,
                  toolpaths=toolpaths, layers=layers, platform_vertices=platform_vertices, cost=cost,
                  max_rotations=max_rotations, trajectory=trajectory)
    robot = load_robot(cell.robot)
    graph = join_motions([g for graphs, _, _ in done for g in graphs], joint_move_time(cell))
    if trajectory != "jerk":
        final = graph
    else:
        final = join_motions([f for _, f, _ in done], rest_to_rest_time(robot, cell))
    return graph, final, merge_reports(robot, cell, graph, final, [r for _, _, r in done], trajectory)


class _Blocks:
    """A progress bar in layers fed by the executor's one update per finished block."""

    def __init__(self, bar: Any, sizes: list[int]):
        self.bar, self.left = bar, sum(sizes)
        self.size = max(sizes, default=0)

    def update(self, n: int = 1) -> None:
        if self.bar is not None:
            step = min(n * self.size, self.left)
            self.left -= step
            self.bar.update(step)
