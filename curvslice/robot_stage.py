"""The robot stage, layer by layer (§3.5.3, §4.3): each layer's pose-continuous motion (the ladder
graph search, :func:`curvslice.motion.plan_layer`) and its trajectory (jerk filter and time-scaling,
:func:`curvslice.jerk.layer_trajectory`) depend only on that layer's waypoints and on the earlier
layers as obstacles, so blocks of layers are independent tasks on any executor; joining them (a
joint move between layers) is the only sequential step and is cheap.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import trimesh

from curvslice.collision import PART_BLOCK, CollisionScene
from curvslice.executors import Executor, InProcess
from curvslice.jerk import merge_reports, rest_to_rest_time, retime_joins, trajectory_stage
from curvslice.kinematics import Robot, load_robot
from curvslice.ladder import ladder
from curvslice.motion import PrintMotion, join_motions, joint_move_time, plan_layer
from curvslice.workcell import Workcell


def layer_blocks(layer: np.ndarray) -> list[list[int]]:
    """The print's layer values in blocks: the values v with the same (v - 1) // PART_BLOCK (at most
    :data:`~curvslice.collision.PART_BLOCK` consecutive layers). A block's tasks share one collision
    scene, and the layers before the block are exactly that scene's base piece
    (:meth:`~curvslice.collision.CollisionScene.for_layer`), built once; blocks of PART_BLOCK
    values counted over a print whose layers skip values (layers without tool-paths) straddled a
    base boundary and built two bases (kitten 0.8: 3 of 6 tasks)."""
    values = np.unique(layer).astype(int)
    key = (values - 1) // PART_BLOCK
    return [[int(v) for v in values[key == k]] for k in np.unique(key)]


def plan_block(values: list[int], *, cell: Workcell, toolpaths: dict[str, np.ndarray], layers: list[trimesh.Trimesh],
               platform_vertices: np.ndarray | None, cost: str, max_rotations: int | None,
               trajectory: str) -> tuple[list[PrintMotion], PrintMotion, dict]:
    """One task: the graph motion of each layer in ``values`` (:func:`curvslice.motion.plan_layer`),
    and the block's trajectory (:func:`curvslice.jerk.trajectory_stage` on the block's layers joined:
    one Gauss-Newton system per block, not per layer) and its report."""
    robot = load_robot(cell.robot)
    scene = CollisionScene(robot, cell, platform_vertices)
    layer = np.asarray(toolpaths["layer"])
    graphs = []
    for v in values:
        rows = np.flatnonzero(layer == v)
        graph = plan_layer(robot, cell, toolpaths, rows, scene.for_layer(layers, v), cost, max_rotations)
        skipped = np.setdiff1d(rows, graph.index)
        graph.layers[0]["skipped_rows"] = skip_reasons(robot, cell, scene, toolpaths, skipped) if len(skipped) else []
        graphs.append(graph)
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
    moves for the graph motion, by Ruckig's moves from each block's end state to the next one's start state for the
    jerk-optimized one. Returns the
    graph motion, the final motion and the trajectory report. ``progress``: tqdm-like, in layers."""
    layer = np.asarray(toolpaths["layer"])
    blocks = layer_blocks(layer)
    # the blocks with most waypoints first (longest processing time first): on N workers the last
    # tasks to start are the short ones (bunny 1.0 on two workers: 91 -> 81 k waypoints on the busier
    # one, in print order against this order); the results are put back in print order
    order = sorted(range(len(blocks)), key=lambda i: -int(np.isin(layer, blocks[i]).sum()))
    ex = executor if executor is not None else InProcess()
    ran = ex.map(plan_block, [blocks[i] for i in order], progress=_Blocks(progress, [len(b) for b in blocks]),
                 cell=cell, toolpaths=toolpaths, layers=layers, platform_vertices=platform_vertices, cost=cost,
                 max_rotations=max_rotations, trajectory=trajectory)
    done = [ran[order.index(i)] for i in range(len(blocks))]
    robot = load_robot(cell.robot)
    graph = join_motions([g for graphs, _, _ in done for g in graphs], joint_move_time(cell))
    if trajectory != "jerk":
        final = graph
    else:
        final = retime_joins(robot, cell, join_motions([f for _, f, _ in done], rest_to_rest_time(robot, cell)))
    return graph, final, merge_reports(robot, cell, graph, final, [r for _, _, r in done], trajectory)


#: poses per skipped waypoint whose colliding pairs are named in its reason
REASON_SAMPLES = 24


def skip_reasons(robot: Robot, cell: Workcell, scene: CollisionScene, toolpaths: dict[str, np.ndarray],
                 rows: np.ndarray) -> list[dict]:
    """Why each waypoint in ``rows`` (skipped by the graph search even with its axis tilted up to the
    workcell's bound) has no pose, at its planned axis: no IK solution inside the joint limits at any
    sampled rotation θ (Eq. 4.3), or every pose collides — with the body pairs in contact most often
    (over up to :data:`REASON_SAMPLES` poses). ``scene`` carries the layer's obstacles."""
    positions = np.asarray(toolpaths["positions"], float)
    normals = np.asarray(toolpaths["normals"], float)
    out = []
    rungs, valid = ladder(robot, cell, positions[rows], normals[rows], cell.rotations) if len(rows) else (None, None)
    for i, r in enumerate(rows):
        nodes = rungs[i, valid[i]]
        n = normals[r] / np.linalg.norm(normals[r])
        entry = {"row": int(r), "layer": int(toolpaths["layer"][r]), "position_mm": np.round(positions[r], 3).tolist(),
                 "tilt_deg": round(float(np.degrees(np.arccos(np.clip(n[2], -1, 1)))), 2)}
        if not len(nodes):
            entry["reason"] = "no IK solution inside the joint limits at any rotation about the nozzle axis"
        else:
            sample = nodes[np.linspace(0, len(nodes) - 1, min(REASON_SAMPLES, len(nodes))).astype(int)]
            counts = Counter(pair for pairs in scene.colliding_pairs(sample) for pair in pairs)
            top = ", ".join(f"{a}/{b}" for (a, b), _ in counts.most_common(3))
            entry["reason"] = (f"all {len(nodes)} poses collide, also with the axis tilted up to "
                               f"{np.degrees(cell.max_axis_deviation):g} deg (most often {top})")
        out.append(entry)
    return out


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
