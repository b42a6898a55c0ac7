"""curvslice: support-free multi-axis printing with robot arms (Dai 2020, TU Delft thesis).

Each pipeline stage is a module named after the thesis's concept; stages exchange plain data
(numpy arrays, trimesh meshes, small dataclasses) so they can be run one at a time in a notebook.
"""

from curvslice.errors import CurvsliceError

__all__ = ["CurvsliceError"]
__version__ = "0.1.0"
