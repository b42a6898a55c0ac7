"""Collision estimation against fcl (thesis §4.4, Table 4.1) on layers of a sliced model.

Per layer: the scene carries the part printed so far (the union of the earlier layers); the learned
collision-indication function (RBF SVM, Algorithm 7 samples) is trained on that layer's working
surface; the sphere proxy (:class:`curvslice.collision_estimate.SphereBounds`) is rebuilt for the
part. The SVM is measured as trained (b + ε) and after calibrating b on a held-out labelled set
(a third of the size, drawn the same way) so that none of its collisions is called free. Both are measured
against fcl (a scene without the proxy: every pair whose boxes overlap goes to fcl) on labelled
configurations near the contact C-space: half on it
(random surface point, normal, θ, every IK solution), half perturbed from it by N(0, σ) per joint.
False "free" (estimator says free, fcl finds contact) must be 0. Run from a slice folder:

    python benchmarks/bench_collision.py /work/data/kitten08 --layers 5 30 60 --per-layer 35000
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import trimesh

from curvslice.collision import CollisionScene
from curvslice.collision_estimate import LearnedCollision, contact_centred_samples, contact_configurations
from curvslice.kinematics import load_robot
from curvslice.workcell import load_workcell


def labelled_set(robot, cell, surface, count: int, sigma: float, rng) -> np.ndarray:
    """``count`` configurations: half on the contact C-space, half perturbed from it."""
    q = np.zeros((0, 6))
    while len(q) < count:
        q = np.vstack([q, contact_configurations(robot, cell, surface, count // 8, rng)])
    q = q[rng.permutation(len(q))[:count]]
    half = np.arange(len(q)) % 2 == 1
    q[half] += rng.normal(0.0, sigma, (int(half.sum()), 6))
    return q


def measure(name: str, maybe: np.ndarray, truth: np.ndarray, seconds: float) -> dict[str, object]:
    free = ~truth
    return {"estimator": name, "false_free": int((~maybe & truth).sum()),
            "false_collision_pct": round(100.0 * float((maybe & free).sum()) / max(int(free.sum()), 1), 2),
            "said_free_pct": round(100.0 * float((~maybe).mean()), 2),
            "query_us_per_config": round(1e6 * seconds / len(truth), 2)}


def run(folder: Path, layers: list[int], per_layer: int, samples: int, sigma: float, robot_name: str) -> list[dict]:
    robot, cell = load_robot(robot_name), load_workcell(robot_name)
    meshes = [trimesh.load(p, force="mesh") for p in sorted((folder / "layers").glob("layer_*.ply"))]
    platform = np.load(folder / "field.npz")["platform_vertices"]
    exact = CollisionScene(robot, cell, platform, bounds=False)  # the labels: fcl on every box-overlapping pair
    proxy = CollisionScene(robot, cell, platform, bounds=True)
    rng = np.random.default_rng(0)
    rows = []
    for layer in layers:
        surface = meshes[layer - 1]
        collides = exact.for_layer(meshes, layer)
        start = time.perf_counter()
        proxy.for_layer(meshes, layer)
        proxy_build = time.perf_counter() - start
        q = labelled_set(robot, cell, surface, per_layer, sigma, rng)
        start = time.perf_counter()
        truth = collides(q)
        fcl_s = time.perf_counter() - start
        start = time.perf_counter()
        train_q, train_label = contact_centred_samples(robot, cell, surface, collides, total=samples, rng=rng)
        sampling = time.perf_counter() - start
        start = time.perf_counter()
        svm = LearnedCollision(train_q, train_label)
        fit = time.perf_counter() - start
        trained_only = svm.maybe_colliding(q)
        start = time.perf_counter()
        held_out = labelled_set(robot, cell, surface, per_layer // 3, sigma, rng)
        svm.calibrate(held_out, collides(held_out))
        calibration = time.perf_counter() - start
        start = time.perf_counter()
        said = svm.maybe_colliding(q)
        svm_s = time.perf_counter() - start
        start = time.perf_counter()
        near = proxy.maybe_colliding(q)
        proxy_s = time.perf_counter() - start
        base = {"layer": layer, "configs": len(q), "colliding_pct": round(100.0 * float(truth.mean()), 2)}
        rows.append({**base, **measure("fcl", truth, truth, fcl_s), "train_s": 0.0})
        rows.append({**base, **measure("svm (Algorithm 7 samples, b + ε)", trained_only, truth, svm_s),
                     "train_s": round(sampling + fit, 2), "samples": len(train_q), "kernels": svm.kernels})
        rows.append({**base, **measure("svm calibrated", said, truth, svm_s),
                     "train_s": round(sampling + fit + calibration, 2), "samples": len(train_q) + len(held_out),
                     "kernels": svm.kernels, "bias_shift": round(svm.shift, 3)})
        rows.append({**base, **measure("spheres", near, truth, proxy_s), "train_s": round(proxy_build, 2)})
        for r in rows[-4:]:
            print(json.dumps(r))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", type=Path, help="a `curvslice slice` output folder (layers/, field.npz)")
    parser.add_argument("--layers", type=int, nargs="+", default=[5, 30, 60])
    parser.add_argument("--per-layer", type=int, default=35_000, help="labelled configurations per layer")
    parser.add_argument("--samples", type=int, default=3000, help="training samples per layer (Algorithm 7)")
    parser.add_argument("--sigma", type=float, default=0.05, help="rad, perturbation of the nearby half")
    parser.add_argument("--robot", default="ur5")
    a = parser.parse_args()
    rows = run(a.folder, a.layers, a.per_layer, a.samples, a.sigma, a.robot)
    total = sum(r["configs"] for r in rows if r["estimator"] == "fcl")
    for name in ("svm (Algorithm 7 samples, b + ε)", "svm calibrated", "spheres"):
        mine = [r for r in rows if r["estimator"] == name]
        print(f"{name}: {total} configs, false free {sum(r['false_free'] for r in mine)}, false collision "
              f"{np.mean([r['false_collision_pct'] for r in mine]):.1f} % (mean over layers)")


if __name__ == "__main__":
    main()
