"""Viewer and previews: geometry built for the scene, the scene held by a real meshcat server, a
headless Chromium screenshot of the viewer page, and the ``--preview`` PNG, all checked on content."""

from __future__ import annotations

import base64
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh
import umsgpack
from matplotlib.image import imread
from scipy import ndimage

from curvslice.cli import main
from curvslice.errors import CurvsliceError
from curvslice.exporters.joints_csv import write_joints_csv
from curvslice.kinematics import fk_reference, load_robot
from curvslice.viz import (build_scene, layer_colors, open_viewer, path_segments, preview_png,
                           read_slice_folder, voxel_layer_faces)
from curvslice.workcell import load_workcell, save_workcell

REPO = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


# ----------------------------------------------------------------------------- geometry


def _same_layer_neighbours(mask: np.ndarray) -> np.ndarray:
    kernel = np.zeros((3, 3, 3))
    kernel[1, 1, [0, 2]] = kernel[1, [0, 2], 1] = kernel[[0, 2], 1, 1] = 1
    return ndimage.convolve(mask.astype(int), kernel, mode="constant")


def test_voxel_layer_faces_bound_each_layer_exactly():
    rng = np.random.default_rng(3)
    growing = rng.integers(0, 4, size=(7, 6, 5)).astype(np.int32)
    w, origin = 0.7, np.array([-2.0, 1.0, 0.35])
    meshes = voxel_layer_faces(growing, origin, w)
    assert sorted(meshes) == [1, 2, 3]
    for layer, mesh in meshes.items():
        mask = growing == layer
        # one quad per voxel face not shared with a voxel of the same layer (independent count)
        exposed = int((6 * mask - _same_layer_neighbours(mask) * mask).sum())
        assert len(mesh.faces) == 2 * exposed
        # corners are shared, so each layer's boundary is closed; outward orientation: the divergence
        # theorem gives the layer's voxel volume, positive
        assert trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).is_winding_consistent
        assert np.isclose(mesh.volume, mask.sum() * w**3, rtol=1e-9)
        lo = origin + w * (np.argwhere(mask).min(axis=0) - 0.5)
        hi = origin + w * (np.argwhere(mask).max(axis=0) + 0.5)
        assert np.allclose(mesh.bounds, [lo, hi])


def test_path_segments_never_bridge_a_travel():
    pos = np.arange(30, dtype=float).reshape(10, 3)
    pid = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2, 5])
    seg = path_segments(pos, pid)
    assert len(seg) == len(pid) - len(np.unique(pid))
    ends = {(tuple(a), tuple(b)) for a, b in seg}
    for i in range(len(pid) - 1):
        assert ((tuple(pos[i]), tuple(pos[i + 1])) in ends) == (pid[i] == pid[i + 1])


# ----------------------------------------------------------------------------- a small slice


@pytest.fixture(scope="module")
def tee_folder(tmp_path_factory) -> Path:
    """tee.stl at 2 mm with surfaces and tool-paths, and a synthetic robot trajectory
    (UR5 workcell, a smooth joint sweep) so the robot part of the scene is exercised too."""
    out = tmp_path_factory.mktemp("viz") / "tee"
    assert main(["slice", str(REPO / "models" / "tee.stl"), "--voxel", "2", "--no-verify", "--out", str(out),
                 "--stages", "toolpaths", "--preview", "--quiet"]) == 0
    cell = load_workcell("ur5")
    save_workcell(cell, out / "workcell.json")
    s = np.linspace(0, 1, 40)[:, None]
    q = np.array([0.0, -1.6, 1.6, -1.6, -1.57, 0.0]) + s * np.array([0.4, 0.2, -0.2, 0.1, 0.0, 1.0])
    n = len(q)
    write_joints_csv(out / "joints.csv", layer=np.ones(n, int), path_id=np.zeros(n, int), index=np.arange(n),
                     t=s[:, 0] * 10, positions=np.zeros((n, 3)), normals=np.tile([0, 0, 1.0], (n, 1)), q=q,
                     segment=np.zeros(n, int), extruding=np.ones(n, bool))
    return out


def _scene_commands(html: str) -> list[dict]:
    """The commands the meshcat server holds, decoded from its static page (base64 msgpack)."""
    blobs = re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)", html)
    return [umsgpack.unpackb(base64.b64decode(b)) for b in blobs]


def test_meshcat_server_holds_the_expected_scene(tee_folder):
    viewer = open_viewer()
    try:
        placed = build_scene(viewer.vis, read_slice_folder(tee_folder))
        commands = _scene_commands(viewer.vis.static_html())
    finally:
        viewer.close()
    objects = {c["path"] for c in commands if c["type"] == "set_object"}
    assert set(placed) == objects
    with np.load(tee_folder / "field.npz") as f:
        growing = f["growing"]
    prefix = "/meshcat/curvslice/part"
    want = {f"{prefix}/solid", f"{prefix}/platform"}
    want |= {f"{prefix}/voxels/layer_{g:04d}" for g in np.unique(growing[growing > 0])}
    layers = sorted((tee_folder / "layers").glob("layer_*.ply"))
    want |= {f"{prefix}/surfaces/layer_{i:04d}" for i, p in enumerate(layers, 1)
             if len(trimesh.load(p, force="mesh").faces)}
    if (tee_folder / "toolpaths.npz").exists():
        with np.load(tee_folder / "toolpaths.npz") as tp:
            want |= {f"{prefix}/toolpaths/layer_{g:04d}" for g in np.unique(tp["layer"])}
            want |= {f"{prefix}/orientations/layer_{g:04d}" for g in np.unique(tp["layer"])}
    robot = load_robot("ur5")
    want |= {f"/meshcat/curvslice/robot/{k:02d}_{s.link}" for k, s in enumerate(robot.links)}
    cell = load_workcell("ur5")
    want |= {f"/meshcat/curvslice/extruder/{b.name}" for b in cell.extruder}
    want |= {f"/meshcat/curvslice/obstacles/{b.name}" for b in cell.obstacles}
    assert want <= objects, sorted(want - objects)

    # the voxel objects are the layers' voxel boundaries: two triangles per exposed voxel face
    for c in commands:
        if c["type"] == "set_object" and "/voxels/layer_" in c["path"]:
            layer = int(c["path"][-4:])
            mask = growing == layer
            exposed = int((6 * mask - _same_layer_neighbours(mask) * mask).sum())
            index = c["object"]["geometries"][0]["data"]["index"]["array"]
            assert len(np.frombuffer(index.data, np.uint32)) == 3 * 2 * exposed
    # the part sits on the flange: its pose is pinocchio's flange pose at q0 times T_P^E (Eq. 2.3)
    q0 = np.loadtxt(tee_folder / "joints.csv", delimiter=",", skiprows=1, ndmin=2)[0, 10:16]
    part = [c for c in commands if c["type"] == "set_transform" and c["path"] == "/meshcat/curvslice/part"]
    assert part
    matrix = np.asarray(part[-1]["matrix"], float).reshape(4, 4).T
    assert np.allclose(matrix, fk_reference(robot, q0)[0] @ cell.platform_mount, atol=1e-6)
    anim = [c for c in commands if c["type"] == "set_animation"]
    assert anim and any(a["path"] == "/meshcat/curvslice/part" for a in anim[-1]["animations"])


def _screenshot(url: str, png: Path, profile: Path) -> np.ndarray:
    subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                    "--disable-background-networking", "--disable-component-update", "--disable-sync",
                    "--enable-unsafe-swiftshader", f"--user-data-dir={profile}", f"--screenshot={png}",
                    "--window-size=800,600", "--virtual-time-budget=8000", url],
                   check=True, capture_output=True, timeout=180)
    return (imread(png)[..., :3] * 255).round()


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (CI installs it)")
def test_chromium_screenshot_shows_the_model(tee_folder, tmp_path):
    folder = read_slice_folder(tee_folder)
    folder.layers, folder.toolpaths, folder.joints = [], None, None  # the voxels are what is shown
    viewer = open_viewer()
    try:
        blank = _screenshot(viewer.url, tmp_path / "blank.png", tmp_path / "profile")
        build_scene(viewer.vis, folder)
        shot = _screenshot(viewer.url, tmp_path / "scene.png", tmp_path / "profile")
    finally:
        viewer.close()
    assert blank.shape == shot.shape == (600, 800, 3)
    changed = np.abs(shot - blank).max(axis=2) > 30
    assert changed.mean() > 0.03, f"only {changed.mean():.2%} of the pixels differ from an empty scene"
    # the changed pixels carry the layer colours (lit, so compare colour directions, not values)
    colors = layer_colors(folder.layer_count) * 255
    unit = lambda a: a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-9)  # noqa: E731
    cos = unit(shot[changed]) @ unit(colors).T
    layered = cos.max(axis=1) > 0.995
    assert layered.sum() > 0.01 * changed.size, "the voxel layers' colours are missing from the page"
    seen = np.bincount(cos.argmax(axis=1)[layered], minlength=len(colors)) >= 10
    assert seen.mean() > 0.5, f"only {seen.sum()} of {len(colors)} layer colours are visible"
    # the model is framed: the changed region is near the image centre
    rows, cols = np.nonzero(changed)
    assert 150 < rows.mean() < 450 and 200 < cols.mean() < 600


def test_preview_png_shows_every_layer_colour(tee_folder):
    png = tee_folder / "preview.png"
    img = (imread(png)[..., :3] * 255).round()
    assert img.shape[0] > 400 and img.shape[1] > 1200
    n = read_slice_folder(tee_folder).layer_count
    colors = layer_colors(n) * 255
    # the section panel is drawn flat: each layer's exact colour appears there
    dist = np.linalg.norm(img[:, :, None, :] - colors[None, None], axis=-1)
    present = (dist < 6).reshape(-1, n).any(axis=0)
    assert present.mean() > 0.8, f"layers without their colour in the preview: {np.flatnonzero(~present) + 1}"


def test_preview_rejects_a_layer_without_tool_paths(tee_folder, tmp_path):
    folder = read_slice_folder(tee_folder)
    with pytest.raises(CurvsliceError, match="no tool-path on that layer"):
        preview_png(folder, tmp_path / "p.png", layer=10_000)
    layer = int(np.bincount(folder.toolpaths["layer"]).argmax())  # the layer with the most samples
    img = (imread(preview_png(folder, tmp_path / "ok.png", layer=layer))[..., :3] * 255).round()
    right = img[:, 2 * img.shape[1] // 3:]  # the tool-path panel draws the paths in the layer's colour
    colours = layer_colors(folder.layer_count)
    vivid = right[(right.max(axis=-1) - right.min(axis=-1)) > 60]  # grey surface, black glyphs excluded
    assert len(vivid) > 200
    nearest = np.argmin(np.linalg.norm(vivid[:, None] / 255 - colours[None], axis=-1), axis=1) + 1
    assert abs(np.median(nearest) - layer) <= 2


def test_view_command_writes_the_scene_page_and_refuses_a_non_slice_folder(tee_folder, tmp_path, capsys):
    page = tmp_path / "scene.html"
    assert main(["view", str(tee_folder), "--html", str(page)]) == 0
    paths = {c["path"] for c in _scene_commands(page.read_text()) if c["type"] == "set_object"}
    assert "/meshcat/curvslice/part/solid" in paths and any("/voxels/layer_" in p for p in paths)
    assert "MeshCat.Viewer" in page.read_text()  # self-contained: the viewer's script is embedded
    assert main(["view", str(tmp_path)]) == 2
    assert "not a slice folder" in capsys.readouterr().err
