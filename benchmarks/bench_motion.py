"""Motion-stage benchmark: analytic IK throughput per robot, ladder-graph time vs waypoints, and
the collision estimators' query time.

The thesis's reference (Table 4.2, WS1): 2,545 waypoints, graph initialization 86 s. Here the
ladder is built from a spiral on a dome (tilts up to 60°) in the shipped UR5 workcell with p = 30
rotations and every IK solution, then searched rung by rung; with --collisions the whole layer
planner runs instead (:func:`curvslice.motion.plan_motion`: p from 15, doubled per rung where the
motion breaks, lazy exact collision checks; --coarse 8: the coarse-to-fine search on every 8th rung,
as plan_layer). --estimators times fcl, the sphere proxy and the learned SVM (§4.4) on that ladder's
nodes (accuracy: ``benchmarks/bench_collision.py``).
Run: ``python benchmarks/bench_motion.py [--collisions] [--estimators] [--counts 500 2545]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from curvslice.collision import CollisionScene
from curvslice.collision_estimate import LearnedCollision
from curvslice.kinematics import ROBOT_NAMES, fk_reference, ik, load_robot
from curvslice.ladder import circular_joints, ladder, shortest_path
from curvslice.motion import COARSE_STEP, coarse_rungs, plan_motion, step_times
from curvslice.workcell import load_workcell

THESIS_INIT_S = 86.0


def dome_spiral(m: int, turns: float = 12.0, tilt_deg: float = 60.0, radius: float = 40.0):
    s = np.linspace(0, 1, m)
    pol = np.radians(tilt_deg) * (1 - s)
    az = 2 * np.pi * turns * s
    t = np.stack([np.sin(pol) * np.cos(az), np.sin(pol) * np.sin(az), np.cos(pol)], 1)
    return radius * t, t


def ik_throughput(n: int = 20_000) -> None:
    for name in ROBOT_NAMES:
        robot = load_robot(name)
        q = np.random.default_rng(0).uniform(np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi), (n, 6))
        T = fk_reference(robot, q)
        start = time.perf_counter()
        _, ok = ik(robot, T)
        dt = time.perf_counter() - start
        print(f"IK {name:7s} {n / dt:10,.0f} poses/s  {ok.sum() / dt:12,.0f} solutions/s  ({ok.sum(1).mean():.2f} per pose)")


def graph_times(counts: list[int], collisions: bool, coarse: int = 1) -> None:
    robot, cell = load_robot("ur5"), load_workcell("ur5")
    lo, hi = cell.limits(robot)
    circ = circular_joints(lo, hi)
    scene = CollisionScene(robot, cell) if collisions else None
    for m in counts:
        c, t = dome_spiral(m, turns=12.0 * m / 2545)
        dt = step_times(c, cell.linear_speed, cell.min_step_time)
        start = time.perf_counter()
        q, valid = ladder(robot, cell, c, t, cell.rotations)
        built = time.perf_counter() - start
        if scene is None:
            path, _, _ = shortest_path(q, valid, dt, cell.max_joint_speed, circ)
            total = time.perf_counter() - start
            extra = f"segments {path.segment.max() + 1}"
        else:
            keep = coarse_rungs(np.zeros(m), coarse) if coarse > 1 else None
            motion = plan_motion(robot, cell, c, t, dt, collides=scene.collisions, keep=keep)
            total = time.perf_counter() - start - built  # plan_motion builds its own ladder
            extra = (f"segments {motion.segment.max() + 1}, p {motion.rotations}, collision checks "
                     f"{motion.collision_checks:,}, path cost {motion.cost:.2f}")
        nodes = int(valid.sum())
        print(f"graph m={m:6d}  nodes {nodes:9,d}  build {built:6.2f} s  build+search {total:6.2f} s  "
              f"thesis/ours {THESIS_INIT_S * m / 2545 / total:5.1f}x  {extra}")


def estimator_times(m: int = 2545, sample: int = 20_000) -> None:
    """Query time per configuration on ladder nodes of the dome spiral: fcl (with the bounding-box
    broad phase and the exact box witness), the sphere proxy, the learned SVM (trained on 3,000)."""
    robot, cell = load_robot("ur5"), load_workcell("ur5")
    c, t = dome_spiral(m, turns=12.0 * m / 2545)
    q, valid = ladder(robot, cell, c, t, 15)
    nodes = q[valid][np.random.default_rng(0).permutation(int(valid.sum()))[:sample]]
    exact, proxy = CollisionScene(robot, cell), CollisionScene(robot, cell, bounds=True)
    start = time.perf_counter()
    truth = exact.collisions(nodes)
    fcl_s = time.perf_counter() - start
    start = time.perf_counter()
    maybe = proxy.maybe_colliding(nodes)
    proxy_s = time.perf_counter() - start
    start = time.perf_counter()
    svm = LearnedCollision(nodes[:3000], truth[:3000])
    fit_s = time.perf_counter() - start
    start = time.perf_counter()
    said = svm.maybe_colliding(nodes)
    svm_s = time.perf_counter() - start
    n = len(nodes)
    print(f"estimators on {n:,} ladder nodes ({100 * truth.mean():.0f} % colliding): fcl {1e6 * fcl_s / n:.0f} us, "
          f"spheres {1e6 * proxy_s / n:.0f} us (says free {100 * (~maybe).mean():.0f} %, false free {int((truth & ~maybe).sum())}), "
          f"svm {1e6 * svm_s / n:.0f} us with {svm.kernels} kernels (fit {fit_s:.1f} s, false free {int((truth & ~said).sum())})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--counts", type=int, nargs="+", default=[500, 1000, 2545, 5000])
    parser.add_argument("--collisions", action="store_true", help="plan with lazy exact collision checks")
    parser.add_argument("--estimators", action="store_true", help="time the collision estimators")
    parser.add_argument("--coarse", type=int, default=1, help=f"with --collisions: coarse-to-fine search on every "
                        f"n-th rung (plan_layer's default: {COARSE_STEP}; 1 = the full ladder)")
    args = parser.parse_args()
    ik_throughput()
    graph_times(args.counts, args.collisions, args.coarse)
    if args.estimators:
        estimator_times()


if __name__ == "__main__":
    main()
