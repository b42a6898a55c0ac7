"""``curvslice view OUTDIR``: show a slice folder in meshcat (a local server, the browser on localhost).

The scene (:func:`curvslice.viz.build_scene`) holds the solid, the voxels coloured by layer (one
toggle per layer in the scene tree), the working surfaces, the tool-paths with orientation glyphs
and, after the robot stage, the robot animated along ``joints.csv`` with the part on its flange.
"""

from __future__ import annotations

import argparse
import os
import time
import webbrowser
import zipfile
from pathlib import Path

from curvslice.errors import CurvsliceError
from curvslice.validate import count, zmq_url
from curvslice.viz import build_scene, open_viewer, read_slice_folder


def _html_target(html: str, outdir: str) -> Path:
    """``--html``: a new or existing ``.html`` file outside the slice folder (the command's input)."""
    path = Path(html)
    if path.suffix.lower() not in (".html", ".htm"):
        raise CurvsliceError(f"--html {html}: the file name must end in .html")
    if path.is_dir():
        raise CurvsliceError(f"--html {html} is a folder; give a file name ending in .html")
    if not path.parent.is_dir():
        raise CurvsliceError(f"--html {html}: the folder {path.parent} does not exist")
    if Path(outdir).resolve() in path.resolve().parents:
        raise CurvsliceError(f"--html {html} is inside the slice folder {outdir} (an input); write it elsewhere")
    return path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="show a slice folder in a 3D viewer (meshcat, in the browser)",
                       description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("outdir", help="output folder of `curvslice slice`")
    p.add_argument("--open", action="store_true", help="open the viewer page in the default browser")
    p.add_argument("--html", help="write the scene as one self-contained HTML file and exit")
    p.add_argument("--zmq-url", type=zmq_url, help="use a running meshcat server (e.g. tcp://127.0.0.1:6000) instead of starting one")
    p.add_argument("--glyph-stride", type=count("samples", lo=1, hi=10**6), default=5, help="draw the tool orientation at every N-th sample")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    html = _html_target(args.html, args.outdir) if args.html else None
    try:
        folder = read_slice_folder(args.outdir)
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise CurvsliceError(f"{args.outdir}: a file of the slice folder is damaged ({type(exc).__name__}: "
                             f"{str(exc)[:120]}); `curvslice verify {args.outdir}` names it") from None
    viewer = open_viewer(args.zmq_url)
    try:
        placed = build_scene(viewer.vis, folder, glyph_stride=args.glyph_stride)
        print(f"{len(placed)} objects from {folder.path}")
        if html is not None:
            partial = html.with_name(f".{html.name}.partial-{os.getpid()}")
            try:
                partial.write_text(viewer.vis.static_html())
                os.replace(partial, html)
            finally:
                partial.unlink(missing_ok=True)
            print(f"wrote {html}")
            return 0
        if args.open:
            webbrowser.open(viewer.url, new=2)
        if args.zmq_url:
            return 0  # the scene lives on in the caller's server
        print(f"viewer at {viewer.url} — press Ctrl-C to stop")
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            return 0
    finally:
        viewer.close()
