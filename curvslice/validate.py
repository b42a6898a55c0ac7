"""One validation layer for everything a command reads, run before any work starts (issue 15).

* argparse ``type=`` factories (:func:`number`, :func:`count`, :func:`program_name`,
  :func:`input_file`, :func:`zmq_url`): finite, in range, right type, with the unit in the message;
* :func:`check_fields`: the same checks on the JSON of a cell or workcell, naming the offending key;
* :func:`require_finite`: every program writer refuses NaN / inf before writing a byte;
* :func:`check_budget`: resource guards that name the number (samples, grid points) and the limit.
"""

from __future__ import annotations

import argparse
import math
import re
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from types import UnionType

import numpy as np

from curvslice.errors import CurvsliceError

T = typing.TypeVar("T")

#: Largest input file any command reads (G-code, CSV, DXF, JSON, meshes): 2 GiB.
MAX_INPUT_BYTES = 2 << 30


def _bound_text(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {hi:g}")
    return " and ".join(parts)


def check_number(value: object, what: str, unit: str = "", *, lo: float | None = None, hi: float | None = None,
                 lo_open: bool = False, hi_open: bool = False, integer: bool = False) -> float:
    """``value`` as a float if it is a finite real number in the range, else a :class:`CurvsliceError`
    naming ``what``, the unit and the range."""
    kind = "an integer" if integer else "a finite number"
    bounds = _bound_text(lo, hi, lo_open, hi_open)
    expected = f"{kind}{f' of {unit}' if unit else ''}{f' {bounds}' if bounds else ''}"
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise CurvsliceError(f"{what} must be {expected}, got {value!r}")
    x = float(value)
    if not math.isfinite(x) or (integer and x != int(x)):
        raise CurvsliceError(f"{what} must be {expected}, got {value!r}")
    if ((lo is not None and (x < lo or (lo_open and x == lo)))
            or (hi is not None and (x > hi or (hi_open and x == hi)))):
        raise CurvsliceError(f"{what} must be {expected}, got {value!r}")
    return x


def _parse_float(text: str) -> float:
    if len(text) > 64:
        raise argparse.ArgumentTypeError(f"{text[:20]}… ({len(text)} characters) is not a usable number")
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def argument_type(check: Callable[[str], T], name: str) -> Callable[[str], T]:
    """An argparse ``type=`` from ``check(text)``, whose :class:`CurvsliceError` becomes argparse's one-line
    option error (the option's name is added by argparse)."""

    def parse(text: str) -> T:
        try:
            return check(text)
        except CurvsliceError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = name
    return parse


def number(unit: str, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
           hi_open: bool = False) -> Callable[[str], float]:
    """An argparse ``type=``: a finite float within the bounds, e.g. ``number("mm/s", lo=0, lo_open=True)``."""
    return argument_type(lambda text: check_number(_parse_float(text), "value", unit, lo=lo, hi=hi, lo_open=lo_open,
                                                   hi_open=hi_open), f"number of {unit}" if unit else "number")


def count(what: str, *, lo: int = 0, hi: int | None = None) -> Callable[[str], int]:
    """An argparse ``type=``: an integer ``lo <= n <= hi`` (``what`` is the unit, e.g. "points")."""
    return argument_type(lambda text: int(check_number(_parse_float(text), "value", what, lo=lo, hi=hi, integer=True)),
                         f"count of {what}")


_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,19}")


def program_name(text: str) -> str:
    """An argparse ``type=`` for ``--name``: a program identifier, so no path can hide in it."""
    if not _NAME.fullmatch(text):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a program name: use a letter then up to 19 letters, digits or _ (no paths)")
    return text


def input_file(text: str) -> Path:
    """An argparse ``type=`` for an input file: it exists, is a regular file and is at most 2 GiB."""
    path = Path(text)
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text!r} is not an existing file")
    size = path.stat().st_size
    if size > MAX_INPUT_BYTES:
        raise argparse.ArgumentTypeError(f"{text!r} is {size / 2**30:.1f} GiB, above the {MAX_INPUT_BYTES >> 30} GiB limit")
    return path


_ZMQ_URL = re.compile(r"tcp://[A-Za-z0-9.\-\[\]:]+:(\d{1,5})")


def zmq_url(text: str) -> str:
    """An argparse ``type=`` for a meshcat server address ``tcp://HOST:PORT``."""
    m = _ZMQ_URL.fullmatch(text)
    if not m or not 0 < int(m[1]) < 65536:
        raise argparse.ArgumentTypeError(f"{text!r} is not a ZeroMQ address tcp://HOST:PORT (port 1-65535)")
    return text


def read_text(path: Path, what: str) -> str:
    """The UTF-8 text of an input file (a leading byte-order mark dropped); a binary file is an error."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise CurvsliceError(f"{path}: cannot read the {what} ({exc.strerror})") from None
    if b"\0" in data[:1 << 20]:
        raise CurvsliceError(f"{path}: a binary file, not a {what} (text expected)")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CurvsliceError(f"{path}: the {what} is not UTF-8 text (byte {exc.start})") from None


#: Per-field numeric range of a cell or workcell JSON: (lo, hi, lo_open, unit).
Range = tuple[float | None, float | None, bool, str]


def _check_value(value: object, hint: object, where: str, rng: Range | None, allow_inf: bool) -> None:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, UnionType):
        if value is None and type(None) in args:
            return
        hint = next(a for a in args if a is not type(None))
        origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise CurvsliceError(f"{where} must be a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            args = (args[0],) * len(value)
        elif len(value) != len(args):
            raise CurvsliceError(f"{where} must have {len(args)} entries, got {len(value)}")
        for i, (v, h) in enumerate(zip(value, args)):
            _check_value(v, h, f"{where}[{i}]", rng, allow_inf)
    elif hint is bool:
        if not isinstance(value, bool):
            raise CurvsliceError(f"{where} must be true or false, got {value!r}")
    elif hint is str:
        if not isinstance(value, str):
            raise CurvsliceError(f"{where} must be a string, got {value!r}")
    elif hint in (int, float):
        lo, hi, lo_open, unit = rng or (None, None, False, "")
        if allow_inf and isinstance(value, float) and math.isinf(value):
            return
        check_number(value, where, unit, lo=lo, hi=hi, lo_open=lo_open, integer=hint is int)


def check_fields(kind: type, values: Mapping, where: str, ranges: Mapping[str, Range] | None = None,
                 infinite_ok: frozenset[str] = frozenset()) -> None:
    """Check the JSON ``values`` of dataclass ``kind`` against its field types (and ``ranges``),
    naming the offending key as ``where.key``; keys in ``infinite_ok`` may hold ±inf, never NaN."""
    hints = typing.get_type_hints(kind)
    for key, value in values.items():
        if key in hints:
            _check_value(value, hints[key], f"{where}.{key}", (ranges or {}).get(key), key in infinite_ok)


def require_finite(where: str, **arrays: object) -> None:
    """Refuse to write a program holding NaN or inf: the error names the array and its first bad row."""
    for name, values in arrays.items():
        a = np.asarray(values, dtype=np.float64)
        bad = ~np.isfinite(a)
        if bad.any():
            row = int(np.argwhere(bad)[0][0])
            raise CurvsliceError(f"{where}: {name} has a non-finite value ({a.reshape(len(a), -1)[row].tolist()} "
                                 f"at row {row}); refusing to write it into a program")


def check_budget(what: str, needed: float, limit: float, hint: str) -> None:
    """A resource guard: refuse when ``needed`` (samples, points…) exceeds ``limit``, with both numbers."""
    if not needed <= limit:
        raise CurvsliceError(f"{what}: {needed:.3g} needed, above the limit of {limit:.3g}; {hint}")
