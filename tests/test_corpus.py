"""Regression corpus (issue 18): solids the pipeline was not tuned on, sliced through every stage to
the tool-paths and re-checked by every ``curvslice verify`` check.

Procedural solids probe one feature each -- thin walls, sharp tips, an overhanging arch, a hole
through the part, a tall needle, flat faces on voxel faces (a cantilevered L, an inverted cone), a closed
cavity, overhangs all round (a flat torus, a sphere, a lying capsule, a mushroom's cap, a leaning cylinder),
walls thinner than two beads (a vase, a cup with a handle, a dome's shell), a twisted prism
-- and the eight shared models run at a coarse voxel: slice and
verify take 1.5-3 CPU-seconds per solid and 4-14 per shared model (bunny the most; measured as
process CPU time on a loaded 2-core machine, so about the wall time on an idle core), some 75 s in
all. A case listed in :data:`KNOWN_FAILURES` names the checks it fails: it is an xfail while exactly those
fail, and fails outright when another check fails too (a strict xfail alone let the torus's overlap
failure turn into a 80.9 % coverage failure unseen) or when one of them passes (the entry must then
shrink or go), so the corpus only ever tightens. Marked ``corpus`` (``pytest -m "not corpus"`` leaves it out); the
shared models skip cleanly when ../shared/models is absent.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from curvslice.cli import main
from curvslice.verify import verify_outdir

#: voxel (mm) of the procedural solids (20-30 mm across) and of the shared models (70-80 mm)
SOLID_VOXEL = 1.5
SHARED_VOXEL = 2.5

#: case -> the checks it fails at the voxel above (``{"toolpaths/overlap": "5.8 % (layer 4)"}``), while a cause is
#: being fixed. Empty since 2026-11-28 (fourteenth session): the last five (sharp-tips 5.8 % overlap on layer 4,
#: homer 5.8 % on 18, cheburashka 5.0 % on 2, tower 5.1 % on 19, bowl 5.0 % on 2) passed once fitted beads stopped
#: at the bisector with the pass beside them (beads._bisectors; overlap by the report's own measure 5.9, 5.9, 5.1,
#: 5.5, 5.2 % -> 5.2, 4.7, 3.4, 3.5, 4.3 %). Earlier entries went as their causes were fixed: the seam trim, the
#: end trim, a lone dot's centre line, sibling splices, ringed bridges, a chain's last ring hosting the rings past
#: a thin band, a dot in a thin outermost loop, empty layers judged piece by piece (git log -- tests/test_corpus.py).
KNOWN_FAILURES: dict[str, dict[str, str]] = {}


def _box(extents, centre) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def _boolean(a: trimesh.Trimesh, b: trimesh.Trimesh, op: str) -> trimesh.Trimesh:
    """Exact union / difference / intersection by manifold3d (the standard mesh-boolean backend of trimesh)."""
    import manifold3d as mf

    def to_manifold(m: trimesh.Trimesh) -> mf.Manifold:
        return mf.Manifold(mf.Mesh(vert_properties=np.asarray(m.vertices, np.float32),
                                   tri_verts=np.asarray(m.faces, np.uint32)))

    ops = {"union": lambda x, y: x + y, "difference": lambda x, y: x - y, "intersection": lambda x, y: x ^ y}
    out = ops[op](to_manifold(a), to_manifold(b))
    mesh = out.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts))


def procedural_solid(name: str) -> trimesh.Trimesh:
    """The corpus' procedural solids (mm, resting on z = 0)."""
    if name == "thin-walls":  # an open-top box with 1.5 mm walls
        return _boolean(_box([24, 18, 14], [0, 0, 7]), _box([21, 15, 14], [0, 0, 8.5]), "difference")
    if name == "sharp-tips":  # a cone on a slab: the tip narrows to a point
        cone = trimesh.creation.cone(radius=9, height=18, sections=48)
        cone.apply_translation([0, 0, 4])
        return _boolean(_box([20, 20, 4], [0, 0, 2]), cone, "union")
    if name == "arch":  # two 5 mm pillars and a 5 mm bridge over a 20 mm span
        return _boolean(_box([30, 8, 16], [0, 0, 8]), _box([20, 10, 11], [0, 0, 5.5]), "difference")
    if name == "hole":  # a horizontal 8 mm hole through a block: an overhanging ceiling
        cyl = trimesh.creation.cylinder(radius=4, height=30, sections=48)
        cyl.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
        cyl.apply_translation([0, 0, 9])
        return _boolean(_box([24, 16, 18], [0, 0, 9]), cyl, "difference")
    if name == "needle":  # a 3.2 mm needle 30 mm tall on a foot
        needle = trimesh.creation.cylinder(radius=1.6, height=30, sections=32)
        needle.apply_translation([0, 0, 17])
        return _boolean(_box([12, 12, 2], [0, 0, 1]), needle, "union")
    if name == "overhang-l":  # a post carrying a 22 mm cantilever; flat faces on voxel faces at 1.5 mm
        return _boolean(_box([8, 20, 24], [-11, 0, 12]), _box([30, 20, 6], [0, 0, 27]), "union")
    if name == "inverted-cone":  # standing on its apex; the flat top (z = 24) on a voxel face
        cone = trimesh.creation.cone(radius=12, height=24, sections=64)
        cone.apply_transform(trimesh.transformations.rotation_matrix(np.pi, [1, 0, 0]))
        cone.apply_translation([0, 0, 24])
        return cone
    if name == "hollow-box":  # a closed 18 mm cavity: its ceiling is an overhang inside the part
        return _boolean(_box([24, 24, 24], [0, 0, 12]), _box([18, 18, 18], [0, 0, 12]), "difference")
    if name == "torus":  # genus 1 lying flat: overhangs inside and outside the ring
        return _resting(trimesh.creation.torus(major_radius=14, minor_radius=5, major_sections=64, minor_sections=32))
    if name == "sphere":  # the lower hemisphere overhangs all round, down to a point of contact
        return _resting(trimesh.creation.icosphere(subdivisions=4, radius=12))
    if name == "capsule":  # a capsule lying down: overhangs on both long sides and at both ends
        capsule = trimesh.creation.capsule(height=30, radius=6, count=[32, 16])
        capsule.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
        return _resting(capsule)
    if name == "mushroom":  # a 6 mm stem under a 24 mm cap: a 9 mm flat overhang all round
        stem = trimesh.creation.cylinder(radius=3, height=16, sections=48)
        stem.apply_translation([0, 0, 8])
        cap = trimesh.creation.cylinder(radius=12, height=5, sections=64)
        cap.apply_translation([0, 0, 18])
        return _boolean(stem, cap, "union")
    if name == "tilted-cylinder":  # a cylinder leaning 40 deg from vertical on a slab
        cylinder = trimesh.creation.cylinder(radius=5, height=30, sections=48)
        cylinder.apply_transform(trimesh.transformations.rotation_matrix(np.radians(40), [1, 0, 0]))
        return _resting(_boolean(_resting(cylinder), _box([20, 30, 3], [0, 0, 1.5]), "union"))
    if name == "vase":  # an open cylinder with a 1.6 mm wall, thinner than the path width at 1.5 mm voxels
        return _boolean(_cylinder(12, 30, 0), _cylinder(10.4, 30, 1.5), "difference")
    if name == "cup":  # a 1.5 mm wall with a handle: thin arcs of wall meet a ring-shaped handle
        handle = trimesh.creation.torus(major_radius=6, minor_radius=1.5, major_sections=48, minor_sections=16)
        handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
        handle.apply_translation([12, 0, 12])
        cup = _boolean(_cylinder(10, 25, 0), _cylinder(8.5, 25, 1.5), "difference")
        return _boolean(cup, _boolean(handle, _cylinder(9.5, 25, 0), "difference"), "union")
    if name == "dome":  # a hemispherical shell 2 mm thick standing on its rim: its inside overhangs all round
        shell = _boolean(trimesh.creation.icosphere(subdivisions=4, radius=15),
                         trimesh.creation.icosphere(subdivisions=4, radius=13), "difference")
        return _resting(_boolean(shell, _box([40, 40, 20], [0, 0, 10]), "intersection"))
    if name == "twist":  # a square prism twisted by 90 degrees over its 30 mm height
        import manifold3d as mf

        mesh = mf.Manifold.extrude(mf.CrossSection.square([14, 14], True), 30, 20, 90).to_mesh()
        return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts))
    if name == "gear":  # 14 teeth 3.5 mm deep round a 10 mm bore, 8 mm thick: many thin convex tips
        import shapely.geometry as sg

        angle = np.linspace(0, 2 * np.pi, 56, endpoint=False)
        radius = np.where((np.arange(56) // 2) % 2 == 0, 20.0, 16.5)
        outline = sg.Polygon(np.c_[radius * np.cos(angle), radius * np.sin(angle)]).difference(sg.Point(0, 0).buffer(5, 64))
        return trimesh.creation.extrude_polygon(outline, 8.0)
    if name == "two-bodies":  # a cube and a cylinder 9 mm apart: two parts in one file
        cylinder = _cylinder(6, 25, 0)
        cylinder.apply_translation([12, 0, 0])
        return trimesh.util.concatenate([_box([15, 15, 15], [-12, 0, 7.5]), cylinder])
    if name == "plate":  # 50 x 40 x 2 mm: thinner than two voxels at 1.5 mm, its top layer extracted lower
        return _box([50, 40, 2], [0, 0, 1])
    if name == "tower":  # a 6 mm square tower 50 mm tall on an 18 mm foot 3 mm high
        return _boolean(_box([6, 6, 50], [0, 0, 25]), _cylinder(9, 3, 0), "union")
    if name == "bowl":  # the lower half of a spherical shell (radius 20, wall 3 mm), standing on its bottom
        shell = _boolean(trimesh.creation.icosphere(subdivisions=5, radius=20),
                         trimesh.creation.icosphere(subdivisions=5, radius=17), "difference")
        return _resting(_boolean(shell, _box([60, 60, 30], [0, 0, -15]), "intersection"))
    if name == "t-bridge":  # two 6 mm pillars 24 mm apart carrying a 42 mm beam: a flat overhang between them
        pillars = _boolean(_box([6, 10, 20], [-15, 0, 10]), _box([6, 10, 20], [15, 0, 10]), "union")
        return _boolean(pillars, _box([42, 10, 5], [0, 0, 22.5]), "union")
    if name == "knot":  # a (2, 3) torus knot of 6.4 mm tube: it overhangs itself three times
        import manifold3d as mf

        u = np.linspace(0, 2 * np.pi, 90, endpoint=False)
        centre = np.c_[(14 + 5 * np.cos(3 * u)) * np.cos(2 * u), (14 + 5 * np.cos(3 * u)) * np.sin(2 * u), 5 * np.sin(3 * u)]
        balls = [mf.Manifold.sphere(3.2, 24).translate(tuple(c)) for c in centre]
        tube = [mf.Manifold.batch_hull([a, b]) for a, b in zip(balls, balls[1:] + balls[:1])]
        mesh = mf.Manifold.batch_boolean(tube, mf.OpType.Add).to_mesh()
        return _resting(trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts)))
    if name == "wedge":  # a 37 deg ramp up to a 10 mm flat top, with a vertical back (lying on its 15 mm side)
        import shapely.geometry as sg

        wedge = trimesh.creation.extrude_polygon(sg.Polygon([(0, 0), (40, 0), (40, 23), (30, 23)]), 15)
        wedge.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
        return _resting(wedge)
    raise ValueError(name)


def _cylinder(radius: float, height: float, bottom: float) -> trimesh.Trimesh:
    """A vertical cylinder standing at z = ``bottom``."""
    cylinder = trimesh.creation.cylinder(radius=radius, height=height, sections=96)
    cylinder.apply_translation([0, 0, bottom + height / 2])
    return cylinder


def _resting(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh`` moved up or down onto z = 0."""
    mesh.apply_translation([0, 0, -mesh.bounds[0, 2]])
    return mesh


SOLIDS = ["thin-walls", "sharp-tips", "arch", "hole", "needle", "overhang-l", "inverted-cone", "hollow-box", "torus",
          "sphere", "capsule", "mushroom", "tilted-cylinder", "vase", "cup", "dome", "twist", "gear", "two-bodies",
          "plate", "tower", "bowl", "t-bridge", "knot", "wedge"]
SHARED = ["kitten", "bunny", "fertility", "rocker-arm", "fandisk", "cheburashka", "cow", "homer"]


def _case(name: str):
    return pytest.param(name, id=name)


def _as_known(name: str, failed: list[str]) -> None:
    """Pass when no check fails and none is known to; xfail when exactly the :data:`KNOWN_FAILURES` of
    ``name`` fail; fail when another check fails too, or when a known one passes now."""
    known = KNOWN_FAILURES.get(name, {})
    names = {f.split(": ")[0] for f in failed}
    assert names <= set(known), f"{name}: checks fail beyond the known ones {sorted(known)}: {failed}"
    assert names == set(known), f"{name}: known failures pass now, take them out of KNOWN_FAILURES: " \
                                f"{sorted(set(known) - names)}"
    if known:
        pytest.xfail(f"{name}: {failed} (known: {known})")


def _slice_and_verify(model, voxel: float, out) -> list:
    """The failed checks of ``curvslice verify`` on the model sliced to the tool-paths (verified once, here), and
    the layers holding degenerate triangles: trimming can put a triangle's corners on one point, and a crossing
    test through its plane cannot see it (the bunny at 2.5 mm had 10, one of the elephant's crossed a layer)."""
    assert main(["slice", str(model), "--voxel", str(voxel), "--stages", "toolpaths", "--out", str(out),
                 "--quiet", "--no-verify"]) == 0
    layers = [trimesh.load(p, force="mesh", process=False) for p in sorted((out / "layers").glob("layer_*.ply"))]
    degenerate = [i + 1 for i, m in enumerate(layers)
                  if len(m.faces) and not trimesh.triangles.nondegenerate(m.triangles, height=1e-9).all()]
    return ([f"{c.stage}/{c.name}: {c.value}" + (f" on layers {list(c.layers)}" if c.layers else "")
             for c in verify_outdir(out) if not c.passed]
            + ([f"layers/degenerate triangles: on layers {degenerate}"] if degenerate else []))


def test_procedural_solids_are_closed_and_rest_on_the_platform():
    for name in SOLIDS:
        solid = procedural_solid(name)
        assert solid.is_watertight and solid.volume > 0, name
        assert solid.bounds[0, 2] == pytest.approx(0.0, abs=1e-6), name


@pytest.mark.corpus
@pytest.mark.parametrize("name", [_case(n) for n in SOLIDS])
def test_procedural_solid_passes_every_verify_check(name, tmp_path):
    path = tmp_path / f"{name}.stl"
    procedural_solid(name).export(path)
    _as_known(name, _slice_and_verify(path, SOLID_VOXEL, tmp_path / "out"))


@pytest.mark.corpus
@pytest.mark.parametrize("name", [_case(n) for n in SHARED])
def test_shared_model_at_a_coarse_voxel_passes_every_verify_check(name, shared_model, tmp_path):
    _as_known(name, _slice_and_verify(shared_model(name), SHARED_VOXEL, tmp_path / "out"))


#: Solids at finer voxels whose tiny top layers failed until a rule that follows from their geometry changed
#: (benchmarks/bench_corpus.py measures the whole corpus at 1.0 and 0.8 mm): the sharp tips' top at 0.8 mm, a
#: lone ring with no straight stretch whose seam sat at a corner of the layer (94.3 % coverage: the seam now goes
#: where the strip to the edge is narrowest), and the needle's top at 0.8 mm, a root chain of two rings cut two
#: widths open for links only one of which crosses the cut (93.9 %: now a width, as a lone ring's seam).
FINER = [("sharp-tips", 0.8), ("needle", 0.8)]


@pytest.mark.corpus
@pytest.mark.parametrize("name, voxel", [pytest.param(n, v, id=f"{n}-{v:g}") for n, v in FINER])
def test_procedural_solid_at_a_finer_voxel_passes_every_verify_check(name, voxel, tmp_path):
    path = tmp_path / f"{name}.stl"
    procedural_solid(name).export(path)
    assert _slice_and_verify(path, voxel, tmp_path / "out") == []
