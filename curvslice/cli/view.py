"""``curvslice view OUTDIR``: show a slice folder in meshcat (a local server, the browser on localhost).

The scene (:func:`curvslice.viz.build_scene`) holds the solid, the voxels coloured by layer (one
toggle per layer in the scene tree), the working surfaces, the tool-paths with orientation glyphs
and, after the robot stage, the robot animated along ``joints.csv`` with the part on its flange.
"""

from __future__ import annotations

import argparse
import time
import webbrowser
from pathlib import Path

from curvslice.viz import build_scene, open_viewer, read_slice_folder


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("view", help="show a slice folder in a 3D viewer (meshcat, in the browser)",
                       description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("outdir", help="output folder of `curvslice slice`")
    p.add_argument("--open", action="store_true", help="open the viewer page in the default browser")
    p.add_argument("--html", help="write the scene as one self-contained HTML file and exit")
    p.add_argument("--zmq-url", help="use a running meshcat server (e.g. tcp://127.0.0.1:6000) instead of starting one")
    p.add_argument("--glyph-stride", type=int, default=5, help="draw the tool orientation at every N-th sample")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    folder = read_slice_folder(args.outdir)
    viewer = open_viewer(args.zmq_url)
    try:
        placed = build_scene(viewer.vis, folder, glyph_stride=max(1, args.glyph_stride))
        print(f"{len(placed)} objects from {folder.path}")
        if args.html:
            Path(args.html).write_text(viewer.vis.static_html())
            print(f"wrote {args.html}")
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
