"""Seeing a slice: a meshcat 3D scene (browser or notebook) and headless matplotlib previews.

Everything is read back from a slice folder (the output-folder contract: field.npz, layers/,
toolpaths.npz, joints.csv, report.json), so the viewer shows
what was written, not what a stage kept in memory:

* the solid H (``solid.stl``) and the platform T (hull of ``platform_vertices``);
* the voxels of H̄ coloured by layer = growing field G in print order (§3.4.2-3.4.4), one object
  per layer so each can be toggled in meshcat's scene tree;
* the working surfaces ``layers/layer_*.ply`` (§3.4.5);
* the tool-paths of ``toolpaths.npz`` with glyphs of the tool orientation t_q (§3.5.1-3.5.2);
* when ``joints.csv`` and ``workcell.json`` exist, the robot (its URDF collision meshes), the fixed
  extruder and the obstacles, animated along the joint trajectory with the part carried on the flange
  through T_P^E (Eq. 2.3).

The scene is built in millimetres under ``/curvslice`` scaled by 0.001, so meshcat shows metres.
"""

from __future__ import annotations

import json
import subprocess
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import meshcat
import meshcat.geometry as mg
import numpy as np
import trimesh
from matplotlib import colormaps
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from meshcat.animation import Animation
from meshcat.servers.zmqserver import start_zmq_server_as_subprocess

from curvslice.errors import CurvsliceError
from curvslice.exporters.joints_csv import read_joints_csv
from curvslice.workcell import Body, Workcell, workcell_from_dict

if TYPE_CHECKING:
    from curvslice.kinematics import Robot

ROOT = "curvslice"
COLORMAP = "turbo"
MAX_FRAMES = 600  # animation keyframes; longer trajectories are subsampled evenly


@dataclass
class SliceFolder:
    """The artefacts of one slice folder, each None (or empty) when its stage was not run."""

    path: Path
    occupied: np.ndarray
    growing: np.ndarray
    origin: np.ndarray
    voxel_size: float
    method: str
    platform_vertices: np.ndarray | None
    solid: trimesh.Trimesh | None
    layers: list[trimesh.Trimesh] = field(default_factory=list)
    toolpaths: dict[str, np.ndarray] | None = None
    joints: dict[str, np.ndarray] | None = None
    workcell: Workcell | None = None

    @property
    def layer_count(self) -> int:
        return int(self.growing.max(initial=0))


def read_slice_folder(outdir: str | Path) -> SliceFolder:
    """Load a ``curvslice slice`` output folder (``field.npz`` is required, the rest optional)."""
    out = Path(outdir)
    if not (out / "field.npz").is_file():
        raise CurvsliceError(f"{out} is not a slice folder (no field.npz); give the --out folder of `curvslice slice`")
    with np.load(out / "field.npz") as f:
        field_ = {k: f[k] for k in f.files}
    solid = trimesh.load(out / "solid.stl", force="mesh") if (out / "solid.stl").is_file() else None
    layers = [trimesh.load(p, force="mesh") for p in sorted((out / "layers").glob("layer_*.ply"))]
    toolpaths = None
    if (out / "toolpaths.npz").is_file():
        with np.load(out / "toolpaths.npz") as f:
            toolpaths = {k: f[k] for k in f.files}
    joints = read_joints_csv(out / "joints.csv") if (out / "joints.csv").is_file() else None
    cell = None
    if joints is not None and (out / "workcell.json").is_file():
        cell = workcell_from_dict(json.loads((out / "workcell.json").read_text()), str(out / "workcell.json"))
    platform = field_.get("platform_vertices")
    return SliceFolder(
        path=out, occupied=field_["occupied"].astype(bool), growing=field_["growing"].astype(np.int32),
        origin=np.asarray(field_["origin"], float), voxel_size=float(field_["voxel_size"]),
        method=str(field_.get("method", "")), platform_vertices=None if platform is None else np.asarray(platform, float),
        solid=solid, layers=layers, toolpaths=toolpaths, joints=joints, workcell=cell,
    )


def layer_colors(count: int) -> np.ndarray:
    """(count, 3) RGB in [0, 1]: print order from blue (first layer) to red (last)."""
    return colormaps[COLORMAP](np.linspace(0.05, 0.95, max(count, 1)))[:count, :3]


def _rgb_int(rgb: np.ndarray) -> int:
    r, g, b = (np.clip(np.asarray(rgb) * 255, 0, 255) + 0.5).astype(int)
    return int(r) << 16 | int(g) << 8 | int(b)


def voxel_layer_faces(growing: np.ndarray, origin: np.ndarray, voxel_size: float) -> dict[int, trimesh.Trimesh]:
    """Per layer l ≥ 1, the boundary of the voxel set {G = l} as an outward-oriented quad mesh (two
    triangles per face between a layer-l voxel and any voxel not in layer l)."""
    g = np.pad(np.asarray(growing), 1)
    h = voxel_size / 2
    quads, labels = [], []  # corners in half-voxel integer units, so shared corners merge exactly
    unit = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        for s in (-1, 1):
            mask = (g > 0) & (np.roll(g, -s, axis=a) != g)
            idx = np.argwhere(mask)
            if len(idx) == 0:
                continue
            corner = np.zeros((4, 3), int)
            corner[:, a] = s
            order = unit if s > 0 else unit[::-1]  # counter-clockwise seen from outside
            corner[:, b], corner[:, c] = order[:, 0], order[:, 1]
            quads.append(2 * (idx - 1)[:, None, :] + corner[None])
            labels.append(g[mask])
    if not quads:
        return {}
    quads_all, lab = np.concatenate(quads), np.concatenate(labels)
    order = np.argsort(lab, kind="stable")
    quads_all, lab = quads_all[order], lab[order]
    layers, starts = np.unique(lab, return_index=True)
    out = {}
    for layer, lo, hi in zip(layers, starts, np.r_[starts[1:], len(lab)]):
        corners, inverse = np.unique(quads_all[lo:hi].reshape(-1, 3), axis=0, return_inverse=True)
        quad = inverse.reshape(-1, 4)
        faces = np.concatenate([quad[:, [0, 1, 2]], quad[:, [0, 2, 3]]])
        out[int(layer)] = trimesh.Trimesh(np.asarray(origin, float) + h * corners, faces, process=False)
    return out


def path_segments(positions: np.ndarray, path_id: np.ndarray) -> np.ndarray:
    """(S, 2, 3) consecutive sample pairs inside one continuous extrusion path (no travel moves)."""
    keep = path_id[1:] == path_id[:-1]
    return np.stack([positions[:-1][keep], positions[1:][keep]], axis=1)


def body_mesh(body: Body) -> trimesh.Trimesh:
    """A workcell box or cylinder (axis = local z) as a mesh in its parent frame."""
    if body.kind == "box":
        mesh = trimesh.creation.box(extents=body.dims)
    else:
        mesh = trimesh.creation.cylinder(radius=body.dims[0], height=body.dims[1], sections=32)
    mesh.apply_transform(body.pose)
    return mesh


# ----------------------------------------------------------------------------- meshcat


@dataclass
class Viewer:
    """A meshcat visualizer and, when this process started it, its local server."""

    vis: meshcat.Visualizer
    server: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return self.vis.url()

    def close(self) -> None:
        """Stop the server this viewer started (no-op when it joined an existing one)."""
        if self.server is not None and self.server.poll() is None:
            self.server.terminate()
            self.server.wait(timeout=10)


def open_viewer(zmq_url: str | None = None, timeout: float = 10.0) -> Viewer:
    """Start a meshcat server on localhost (or join the one at ``zmq_url``) and connect to it.

    Joining waits at most ``timeout`` seconds: meshcat's handshake blocks forever on a port where
    no server answers, so it runs in a daemon thread that is abandoned on a timeout."""
    if zmq_url is not None:
        joined: list[meshcat.Visualizer] = []
        thread = threading.Thread(target=lambda: joined.append(meshcat.Visualizer(zmq_url=zmq_url)), daemon=True)
        thread.start()
        thread.join(timeout)
        if not joined:
            raise CurvsliceError(f"no meshcat server answered at {zmq_url} within {timeout:g} s")
        return Viewer(joined[0])
    proc, url, _ = start_zmq_server_as_subprocess()
    return Viewer(meshcat.Visualizer(zmq_url=url), proc)


def _mesh_object(mesh: trimesh.Trimesh, color: int, opacity: float = 1.0, flat: bool = False) -> mg.Mesh:
    material = mg.MeshLambertMaterial(color=color, opacity=opacity, transparent=opacity < 1.0, flatShading=flat)
    return mg.Mesh(mg.TriangularMeshGeometry(np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32)), material)


def _segments_object(segments: np.ndarray, color: np.ndarray) -> mg.LineSegments:
    pts = segments.reshape(-1, 3).astype(np.float32).T
    cols = np.broadcast_to(np.asarray(color, np.float32), (pts.shape[1], 3)).T
    return mg.LineSegments(mg.PointsGeometry(pts, np.ascontiguousarray(cols)), mg.LineBasicMaterial(vertexColors=True))


def _frame_camera(vis: meshcat.Visualizer, lo: np.ndarray, hi: np.ndarray) -> None:
    """Orbit target at the centre of the box [lo, hi] (metres), camera at a 3/4 view that fits it."""
    centre, radius = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-3)
    pose = np.eye(4)
    pose[:3, 3] = centre
    vis["/Cameras/default"].set_transform(pose)
    d = 1.7 * radius  # the rotated camera frame is y-up: (x, z, -y) of the model frame
    vis["/Cameras/default/rotated/<object>"].set_property("position", [d, 0.8 * d, d])


def build_scene(vis: meshcat.Visualizer, folder: SliceFolder, *, glyph_stride: int = 5,
                max_frames: int = MAX_FRAMES) -> list[str]:
    """Fill ``vis`` with everything in ``folder``; returns the scene paths of the objects set.

    Paths: ``/curvslice/part/{solid, platform, voxels/layer_NNNN, surfaces/layer_NNNN,
    toolpaths/layer_NNNN, orientations/layer_NNNN}`` and, with a robot stage,
    ``/curvslice/robot/<body>``, ``/curvslice/extruder/<body>``, ``/curvslice/obstacles/<body>``.
    Only the most downstream artefact is visible at first; the others are toggled in the scene tree.
    """
    motion = _robot_motion(folder, max_frames)
    # the camera first: a browser applies it before the (large) geometry has streamed in
    lo, hi = _part_bounds(folder) if motion is None else motion.bounds
    _frame_camera(vis, lo * 1e-3, hi * 1e-3)
    vis[ROOT].delete()
    root = vis[ROOT]
    scale = np.diag([1e-3, 1e-3, 1e-3, 1.0])
    root.set_transform(scale)
    part = root["part"]
    placed: list[str] = []

    def put(node, obj, visible: bool = True) -> None:
        node.set_object(obj)
        if not visible:
            node.set_property("visible", False)
        placed.append(node.path.lower())

    n_layers = folder.layer_count
    colors = layer_colors(n_layers)
    has_paths = folder.toolpaths is not None and len(folder.toolpaths["positions"]) > 0
    show_voxels = not folder.layers and not has_paths
    if folder.solid is not None:
        put(part["solid"], _mesh_object(folder.solid, 0xB0B0B0, 0.25))
    if folder.platform_vertices is not None and len(folder.platform_vertices) >= 4:
        put(part["platform"], _mesh_object(trimesh.convex.convex_hull(folder.platform_vertices), 0x606060, 0.6))
    for layer, mesh in voxel_layer_faces(folder.growing, folder.origin, folder.voxel_size).items():
        put(part["voxels"][f"layer_{layer:04d}"], _mesh_object(mesh, _rgb_int(colors[layer - 1]), flat=True), show_voxels)
    surface_colors = layer_colors(len(folder.layers))
    for i, mesh in enumerate(folder.layers, start=1):
        if len(mesh.faces):
            put(part["surfaces"][f"layer_{i:04d}"], _mesh_object(mesh, _rgb_int(surface_colors[i - 1])), not has_paths)
    if has_paths:
        tp = folder.toolpaths
        layer_ids = np.unique(tp["layer"])
        path_colors = layer_colors(int(layer_ids.max()))
        glyph = 0.8 * folder.voxel_size
        for layer in layer_ids:
            rows = tp["layer"] == layer
            pos, nrm, pid = tp["positions"][rows], tp["normals"][rows], tp["path"][rows]
            seg = path_segments(pos, pid)
            if len(seg):
                put(part["toolpaths"][f"layer_{layer:04d}"], _segments_object(seg, path_colors[layer - 1]))
            pick = np.arange(0, len(pos), glyph_stride)
            arrows = np.stack([pos[pick], pos[pick] + glyph * nrm[pick]], axis=1)
            put(part["orientations"][f"layer_{layer:04d}"], _segments_object(arrows, (0.1, 0.1, 0.1)))
    if motion is not None:
        _robot_scene(vis, folder.workcell, motion, put)
    return placed


def _part_bounds(folder: SliceFolder) -> tuple[np.ndarray, np.ndarray]:
    if folder.solid is not None:
        return folder.solid.bounds[0], folder.solid.bounds[1]
    ijk = np.argwhere(folder.occupied)
    pts = folder.origin + folder.voxel_size * ijk
    return pts.min(axis=0), pts.max(axis=0)


@dataclass
class _RobotMotion:
    """Poses along joints.csv (subsampled to animation frames): link bodies and the carried part."""

    robot: Robot
    names: list[str]
    links: np.ndarray  # (F, L, 4, 4) mm, base frame
    part: np.ndarray  # (F, 4, 4) T_P^B = T_E^B T_P^E (Eq. 2.3)
    bounds: tuple[np.ndarray, np.ndarray]  # the deposition region, for the camera


def _robot_motion(folder: SliceFolder, max_frames: int) -> _RobotMotion | None:
    if folder.joints is None or folder.workcell is None or not len(folder.joints["q"]):
        return None
    from curvslice.kinematics import fk, link_placements, load_robot  # pinocchio only with a robot stage

    cell, q = folder.workcell, folder.joints["q"]
    robot = load_robot(cell.robot)
    rows = np.unique(np.linspace(0, len(q) - 1, min(max_frames, len(q))).round().astype(int))
    part = fk(robot, q[rows]) @ cell.platform_mount
    pts = np.vstack([cell.nozzle[None, :3, 3], part[0][None, :3, 3]])
    return _RobotMotion(robot, [f"{k:02d}_{shape.link}" for k, shape in enumerate(robot.links)],
                        link_placements(robot, q[rows]), part, (pts.min(axis=0) - 80.0, pts.max(axis=0) + 80.0))


def _robot_scene(vis: meshcat.Visualizer, cell: Workcell, motion: _RobotMotion, put) -> None:
    """Robot links, extruder and obstacles; the arm and the part it carries animated along joints.csv."""
    root = vis[ROOT]
    for name, shape in zip(motion.names, motion.robot.links):
        put(root["robot"][name], _mesh_object(shape.mesh, 0xD8D8D8))
    for body in cell.extruder:
        put(root["extruder"][body.name], _mesh_object(body_mesh(body).apply_transform(cell.nozzle), 0x4060A0))
    for body in cell.obstacles:
        put(root["obstacles"][body.name], _mesh_object(body_mesh(body), 0x808070, 0.35))
    for name, T in zip(motion.names, motion.links[0]):
        root["robot"][name].set_transform(T)
    root["part"].set_transform(motion.part[0])
    anim = Animation(default_framerate=30)
    for frame, (link_T, part_T) in enumerate(zip(motion.links, motion.part)):
        with anim.at_frame(vis, frame) as f:
            f[ROOT]["part"].set_transform(part_T)
            for name, T in zip(motion.names, link_T):
                f[ROOT]["robot"][name].set_transform(T)
    vis.set_animation(anim, play=False)


def show_slice(outdir: str | Path, viewer: Viewer | None = None) -> Viewer:
    """Notebook entry: open (or reuse) a viewer and show the slice folder; ``viewer.url`` to browse,
    ``viewer.vis.render_static()`` to embed in a cell."""
    viewer = viewer or open_viewer()
    build_scene(viewer.vis, read_slice_folder(outdir))
    return viewer


# ----------------------------------------------------------------------------- matplotlib


def preview_png(folder: SliceFolder, path: str | Path, layer: int | None = None,
                max_points: int = 60_000) -> Path:
    """``preview.png``: voxels coloured by print order in a cut-away view (the half y ≤ centre),
    the vertical section through the centre, and the tool-paths of ``layer`` (default: the middle
    layer) with their orientation glyphs (§3.5.2). Headless (Agg canvas, no pyplot)."""
    path = Path(path)
    n = folder.layer_count
    if n == 0:
        raise CurvsliceError(f"{folder.path}: the growing field is empty; nothing to preview")
    cmap = ListedColormap(layer_colors(n))  # layer l drawn in exactly layer_colors(n)[l - 1]
    fig = Figure(figsize=(15, 5.2), dpi=110)
    ijk = np.argwhere(folder.growing > 0)
    g = folder.growing[tuple(ijk.T)]
    pts = folder.origin + folder.voxel_size * ijk
    ymid = float(np.median(pts[:, 1]))
    cut = pts[:, 1] <= ymid
    pts_c, g_c = pts[cut], g[cut]
    if len(pts_c) > max_points:
        pick = np.random.default_rng(0).choice(len(pts_c), max_points, replace=False)
        pts_c, g_c = pts_c[pick], g_c[pick]
    ax = fig.add_subplot(1, 3, 1, projection="3d")
    ax.scatter(pts_c[:, 0], pts_c[:, 1], pts_c[:, 2], c=g_c, cmap=cmap, vmin=0.5, vmax=n + 0.5,
               s=(250.0 / max(folder.growing.shape)) ** 2, marker="s", depthshade=False, linewidths=0)
    ax.view_init(elev=18, azim=65)  # looking at the cut face from +y
    _equal_axes(ax, pts)
    ax.set_title(f"voxels by print order, cut at y = {ymid:.1f} mm ({n} layers)")
    ax.set_xlabel("x mm"), ax.set_ylabel("y mm"), ax.set_zlabel("z mm")

    ax = fig.add_subplot(1, 3, 2)
    j = int(round((ymid - folder.origin[1]) / folder.voxel_size))
    sec = np.ma.masked_equal(folder.growing[:, j, :].T, 0)
    w = folder.voxel_size
    ext = [folder.origin[0] - w / 2, folder.origin[0] + w * (folder.growing.shape[0] - 0.5),
           folder.origin[2] - w / 2, folder.origin[2] + w * (folder.growing.shape[2] - 0.5)]
    im = ax.imshow(sec, origin="lower", extent=ext, cmap=cmap, vmin=0.5, vmax=n + 0.5, interpolation="nearest")
    missed = folder.occupied[:, j, :].T & (folder.growing[:, j, :].T == 0)
    if missed.any():
        ax.imshow(np.ma.masked_equal(missed.astype(int), 0), origin="lower", extent=ext, cmap="gray", vmin=0, vmax=2)
    ax.set_aspect("equal")
    ax.set_title(f"section y = {ymid:.1f} mm ({folder.method}; black = missed)")
    ax.set_xlabel("x mm"), ax.set_ylabel("z mm")
    fig.colorbar(im, ax=ax, label="layer (print order)", shrink=0.8).locator = MaxNLocator(integer=True)

    ax = fig.add_subplot(1, 3, 3, projection="3d")
    tp = folder.toolpaths
    if tp is not None and len(tp["positions"]):
        layers = np.unique(tp["layer"])
        chosen = int(layers[len(layers) // 2]) if layer is None else int(layer)
        if chosen not in layers:
            raise CurvsliceError(f"--preview-layer {chosen}: no tool-path on that layer (layers {layers.min()}-{layers.max()})")
        rows = tp["layer"] == chosen
        pos, nrm, pid = tp["positions"][rows], tp["normals"][rows], tp["path"][rows]
        if 0 < chosen <= len(folder.layers) and len(folder.layers[chosen - 1].faces):
            s = folder.layers[chosen - 1]
            ax.plot_trisurf(s.vertices[:, 0], s.vertices[:, 1], s.vertices[:, 2], triangles=s.faces,
                            color=(0.85, 0.85, 0.85, 0.35), linewidth=0)
        color = layer_colors(n)[min(chosen, n) - 1]
        for piece in np.unique(pid):
            p = pos[pid == piece]
            ax.plot(p[:, 0], p[:, 1], p[:, 2], color=color, lw=1.2)
        pick = np.arange(0, len(pos), 6)
        ax.quiver(pos[pick, 0], pos[pick, 1], pos[pick, 2], nrm[pick, 0], nrm[pick, 1], nrm[pick, 2],
                  length=folder.voxel_size, color="k", linewidth=0.5, arrow_length_ratio=0.0)
        _equal_axes(ax, pos)
        ax.set_title(f"layer {chosen}: {len(np.unique(pid))} path(s), {len(pos)} samples, tool orientations")
    else:
        ax.text2D(0.5, 0.5, "no tool-paths in this folder\n(slice with --stages toolpaths)", ha="center",
                  va="center", transform=ax.transAxes)
        ax.set_title("tool-paths")
    ax.view_init(elev=30, azim=-60)
    fig.tight_layout()
    fig.savefig(path)
    return path


def _equal_axes(ax, pts: np.ndarray) -> None:
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    c, r = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-6)
    ax.set_xlim(c[0] - r, c[0] + r), ax.set_ylim(c[1] - r, c[1] + r), ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1))
