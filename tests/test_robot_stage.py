"""The per-layer robot stage (curvslice.robot_stage): blocks of layers, the join, and the reasons
given for waypoints no pose reaches."""

from __future__ import annotations

import numpy as np

from curvslice.collision import PART_BLOCK, CollisionScene
from curvslice.kinematics import load_robot
from curvslice.robot_stage import layer_blocks, skip_reasons
from curvslice.workcell import load_workcell


def test_layer_blocks_partition_the_layers_in_print_order():
    layer = np.repeat(np.arange(1, 2 * PART_BLOCK + 4), 3)
    blocks = layer_blocks(layer)
    assert [v for b in blocks for v in b] == list(range(1, 2 * PART_BLOCK + 4))
    assert all(len(b) == PART_BLOCK for b in blocks[:-1]) and 0 < len(blocks[-1]) <= PART_BLOCK


def test_skip_reasons_tell_out_of_reach_from_collision():
    cell, robot = load_workcell("ur5"), load_robot("ur5")
    scene = CollisionScene(robot, cell)
    # far beyond the arm's reach; and 20 mm below the platform's top (the tool inside the platform)
    tp = {"positions": np.array([[5000.0, 0, 50], [0.0, 0, -20]]), "normals": np.array([[0, 0, 1.0], [0, 0, 1.0]]),
          "layer": np.array([1, 1])}
    far, buried = skip_reasons(robot, cell, scene, tp, np.array([0, 1]))
    assert far["reason"].startswith("no IK solution") and far["layer"] == 1 and far["tilt_deg"] == 0
    assert buried["reason"].startswith("all ") and "platform" in buried["reason"]
