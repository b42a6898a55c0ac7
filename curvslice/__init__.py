"""curvslice: support-free multi-axis printing with robot arms (Dai 2020, TU Delft thesis).

Each pipeline stage is a module named after the thesis's concept; stages exchange plain data
(numpy arrays, trimesh meshes, small dataclasses) so they can be run one at a time in a notebook.
:mod:`curvslice.pipeline` composes them::

    import curvslice
    s = curvslice.slice("kitten.stl", curvslice.Settings(voxel=0.8), until="toolpaths")
    s.toolpaths.positions.shape
"""

from curvslice.errors import CurvsliceError

__all__ = ["CurvsliceError", "Settings", "Slice", "slice"]
__version__ = "0.1.0"


def __getattr__(name: str):
    """``slice``, ``Settings`` and ``Slice`` from :mod:`curvslice.pipeline`, imported on first use (the
    CLI's ``--help`` and ``--version`` should not pay for numpy, scipy and trimesh)."""
    if name in ("slice", "Settings", "Slice"):
        from curvslice import pipeline

        return {"slice": pipeline.run, "Settings": pipeline.Settings, "Slice": pipeline.Slice}[name]
    raise AttributeError(f"module 'curvslice' has no attribute {name!r}")
