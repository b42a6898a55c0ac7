"""User-facing errors: the CLI prints ``CurvsliceError`` as one line and exits non-zero."""

from __future__ import annotations

import importlib
from types import ModuleType

#: pip's name for the modules whose import name differs from their distribution's.
PIP_NAMES = {
    "sklearn": "scikit-learn", "skimage": "scikit-image", "fcl": "python-fcl", "pinocchio": "pin",
    "dask": "dask[distributed]", "distributed": "dask[distributed]", "umsgpack": "u-msgpack-python",
    "charset_normalizer": "charset-normalizer", "cmeel": "cmeel",
}


class CurvsliceError(Exception):
    """A problem with the user's input or settings, with an actionable message."""


def missing_package(exc: ImportError, purpose: str = "") -> CurvsliceError:
    """One actionable line for a third-party module that failed to import."""
    module = (exc.name or str(exc)).split(".")[0]
    package = PIP_NAMES.get(module, module)
    need = f" (needed {purpose})" if purpose else ""
    return CurvsliceError(f"the Python package '{package}' is missing or broken{need}: "
                          f"install it with `pip install \"{package}\"`, or reinstall curvslice with "
                          f"`pip install -e .` ({exc})")


def require(module: str, purpose: str) -> ModuleType:
    """Import an optional backend, or raise one clear :class:`CurvsliceError` naming the package."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise missing_package(exc, purpose) from None
