"""Procedural test solids with known answers (run: ``python models/generate.py``).

* ``arch.stl`` — a 40 x 10 x 25 mm block with a semicircular opening of radius 14 mm: its
  crown underside is a horizontal overhang that planar or greedy growth cannot reach in time
  (thesis Fig. 3.5/3.6), so ``gcfa`` misses voxels there and ``pg-sp-gcfa`` must miss none.
* ``tee.stl`` — a 10 x 10 x 16 mm post carrying a 40 x 10 x 6 mm slab: two 15 mm horizontal
  overhangs, the classic support case of planar printing.

Both rest on z = 0, centred on the z axis, millimetres.
"""

from __future__ import annotations

from pathlib import Path

import manifold3d as m3d
import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent


def _to_trimesh(solid: m3d.Manifold) -> trimesh.Trimesh:
    mesh = solid.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=True)


def arch() -> trimesh.Trimesh:
    block = m3d.Manifold.cube([40.0, 10.0, 25.0]).translate([-20.0, -5.0, 0.0])
    hole = m3d.Manifold.cylinder(12.0, 14.0, 14.0, circular_segments=96, center=True)
    hole = hole.rotate([90.0, 0.0, 0.0])
    return _to_trimesh(block - hole)


def tee() -> trimesh.Trimesh:
    post = m3d.Manifold.cube([10.0, 10.0, 16.0]).translate([-5.0, -5.0, 0.0])
    slab = m3d.Manifold.cube([40.0, 10.0, 6.0]).translate([-20.0, -5.0, 16.0])
    return _to_trimesh(post + slab)


MODELS = {"arch": arch, "tee": tee}


def main() -> None:
    for name, make in MODELS.items():
        mesh = make()
        assert mesh.is_watertight and mesh.volume > 0, name
        mesh.export(HERE / f"{name}.stl")
        print(f"{name}.stl: {len(mesh.faces)} faces, volume {mesh.volume:.1f} mm^3")


if __name__ == "__main__":
    main()
