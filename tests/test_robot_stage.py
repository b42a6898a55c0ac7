"""The per-layer robot stage (curvslice.robot_stage): blocks of layers, the join, and the reasons
given for waypoints no pose reaches."""

from __future__ import annotations

import numpy as np
import trimesh

from curvslice.collision import PART_BLOCK, PART_SUB, CollisionScene
from curvslice.kinematics import load_robot
from curvslice.ladder import ladder
from curvslice.robot_stage import layer_blocks, skip_reasons
from curvslice.verify.robot import confirm_unreachable
from curvslice.workcell import load_workcell


def test_layer_blocks_partition_the_layers_in_print_order():
    values = np.setdiff1d(np.arange(1, 3 * PART_BLOCK + 4), [5, PART_BLOCK, PART_BLOCK + 1, 2 * PART_BLOCK + 2])
    blocks = layer_blocks(np.repeat(values, 3)[::-1])
    assert [v for b in blocks for v in b] == values.tolist()
    # one scene base per block: the layers before the block's first end on a multiple of PART_BLOCK
    bases = [[(v - 1) // PART_BLOCK * PART_BLOCK for v in b] for b in blocks]
    assert all(len(set(b)) == 1 for b in bases) and len({b[0] for b in bases}) == len(blocks)
    assert all(0 < len(b) <= PART_BLOCK for b in blocks)


def test_skip_reasons_tell_out_of_reach_from_collision():
    cell, robot = load_workcell("ur5"), load_robot("ur5")
    scene = CollisionScene(robot, cell)
    # far beyond the arm's reach; and 20 mm below the platform's top (the tool inside the platform)
    tp = {"positions": np.array([[5000.0, 0, 50], [0.0, 0, -20]]), "normals": np.array([[0, 0, 1.0], [0, 0, 1.0]]),
          "layer": np.array([1, 1])}
    far, buried = skip_reasons(robot, cell, scene, tp, np.array([0, 1]))
    assert far["reason"].startswith("no IK solution") and far["layer"] == 1 and far["tilt_deg"] == 0
    assert buried["reason"].startswith("all ") and "platform" in buried["reason"]
    # the pairs of many configurations at once are each one's own
    q, ok = ladder(robot, cell, np.array([[0.0, 0, -20], [0.0, 0, 30]]), np.array([[0, 0, 1.0], [0.3, 0, 1.0]]), 12)
    q = q[ok]
    batch = scene.colliding_pairs(q)
    assert batch == [scene.colliding_pairs(x) for x in q] and any(batch) and not all(batch)


def _slabs(n: int) -> list:
    """n thin printed layers (8 mm squares) stacked on the platform."""
    out = []
    for i in range(n):
        slab = trimesh.creation.box((8.0, 8.0, 0.5))
        slab.apply_translation([0.0, 0.0, 0.5 * i + 0.25])
        out.append(slab)
    return out


def test_scene_pieces_built_once_for_a_block_straddling_a_boundary(monkeypatch):
    """A task whose layers straddle a PART_BLOCK boundary, asked for its layers twice (graph, then
    jerk stage), builds each piece once, and its answers equal a fresh scene's for every layer."""
    cell, robot = load_workcell("ur5"), load_robot("ur5")
    layers = _slabs(PART_BLOCK + 6)
    scene = CollisionScene(robot, cell)
    built = []
    real = CollisionScene._piece
    monkeypatch.setattr(CollisionScene, "_piece",
                        lambda self, mesh, *field: (self is scene and built.append(len(mesh.faces))) or real(self, mesh, *field))
    values = list(range(PART_BLOCK - 2, PART_BLOCK + 5))
    rng = np.random.default_rng(5)
    q, ok = ladder(robot, cell, rng.uniform(-4, 4, (4, 3)) * [1, 1, 0] + [0, 0, 0.5 * (PART_BLOCK + 6) - 1.0],
                   np.tile([0.3, 0.0, 1.0], (4, 1)), 4)
    q = q[ok]
    answers = []
    for _ in range(2):
        for v in values:
            got = scene.for_layer(layers, v)(q)
            fresh = CollisionScene(robot, cell)
            fresh.set_part(trimesh.util.concatenate(layers[:v - 1]))
            np.testing.assert_array_equal(got, fresh(q))
            answers.append(got)
    assert any(a.any() for a in answers) and not all(a.all() for a in answers)
    # each run of layers (base, whole PART_SUB groups after it, the rest) built once, nothing again
    # in the second round
    runs = set()
    for v in values:
        n = v - 1
        cut = n // PART_BLOCK * PART_BLOCK
        mid = cut + (n - cut) // PART_SUB * PART_SUB
        runs |= {r for r in ((0, cut), (cut, mid), (mid, n)) if r[1] > r[0]}
    assert len(built) == len(runs)


def test_verifier_confirms_only_waypoints_without_any_pose():
    """The verifier's re-check of listed waypoints: 80° tilted 1.5 mm above the platform (the heater
    block hits it at every rotation and tilt within 20°) is confirmed; upright, or 55° (tilting back
    frees it), is not."""
    cell, robot = load_workcell("ur5"), load_robot("ur5")
    a = np.radians([80.0, 0.0, 55.0])
    tp = {"positions": np.stack([np.zeros(3), np.zeros(3), np.full(3, 1.5)], 1),
          "normals": np.stack([np.sin(a), np.zeros(3), np.cos(a)], 1), "layer": np.ones(3, int)}
    confirmed = confirm_unreachable(robot, cell, None, [], tp, np.arange(3))
    np.testing.assert_array_equal(confirmed, [True, False, False])
