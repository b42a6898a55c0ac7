"""Property-based tests (Hypothesis) of the G-code reader and the option parsing (issue 15).

* Any text: the reader returns finite arrays or raises :class:`CurvsliceError`, nothing else.
* Generated valid programs (numbers, comments of both kinds, a BOM, numbered lines with their
  checksums) read back to exactly the generated positions; one flipped checksum digit is refused.
* Any string as a numeric option: parsed to a finite value within the option's range, or refused
  by argparse with one line — never NaN, inf or a traceback.
"""

from __future__ import annotations

import contextlib
import io
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from curvslice.cell.gcode import MAX_NUMBER, parse_gcode
from curvslice.cli import build_parser
from curvslice.errors import CurvsliceError

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

gcode_alphabet = st.sampled_from(list("GMTNXYZEFSPnXYZ0123456789.-+ ;()*\t\ufeffe") + ["\n"])


@SETTINGS
@given(st.text(gcode_alphabet, max_size=200) | st.text(max_size=100))
def test_any_text_reads_to_finite_arrays_or_a_curvslice_error(text):
    try:
        prog = parse_gcode(text)
    except CurvsliceError as exc:
        assert "\n" not in str(exc)
        return
    for arr in (prog.positions, prog.feed, prog.extrusion):
        assert np.isfinite(arr).all()
    assert np.all(np.abs(prog.positions) <= 4 * MAX_NUMBER)


coordinate = st.decimals(min_value=-1000, max_value=1000, places=3, allow_nan=False, allow_infinity=False)


def _checksum(line: str) -> int:
    cs = 0
    for byte in line.encode():
        cs ^= byte
    return cs


@st.composite
def programs(draw):
    """(text, expected positions): G1 moves with optional comments, line numbers and checksums."""
    n = draw(st.integers(1, 8))
    lines, expected = ["G21", "G90"], []
    for k in range(n):
        x, y, z = (draw(coordinate) for _ in range(3))
        line = f"G1 X{x} Y{y} Z{z} F{draw(st.integers(1, 20000))}"
        style = draw(st.sampled_from(["plain", "paren", "semicolon", "numbered"]))
        if style == "paren":
            line = f"{line} (note; {k})"
        elif style == "semicolon":
            line = f"{line} ; a (comment)"
        elif style == "numbered":
            body = f"N{k + 1} {line}"
            line = f"{body}*{_checksum(body)}"
        lines.append(line)
        expected.append([float(x), float(y), float(z)])
    bom = "\ufeff" if draw(st.booleans()) else ""
    return bom + "\n".join(lines) + "\n", np.array(expected)


@SETTINGS
@given(programs())
def test_generated_programs_read_back_exactly(program):
    text, expected = program
    prog = parse_gcode(text)
    assert np.allclose(prog.positions, expected, atol=1e-9)


@SETTINGS
@given(programs(), st.integers(1, 255))
def test_a_wrong_checksum_is_refused(program, delta):
    text, _ = program
    lines = text.split("\n")
    numbered = [i for i, line in enumerate(lines) if line.lstrip("\ufeff").startswith("N")]
    if not numbered:
        return
    i = numbered[0]
    body, cs = lines[i].rsplit("*", 1)
    lines[i] = f"{body}*{(int(cs) + delta) % 256}"
    with pytest.raises(CurvsliceError, match="checksum"):
        parse_gcode("\n".join(lines))


#: (sub-command argv prefix, option, lowest allowed, excluded?, highest allowed) of numeric options.
NUMERIC_OPTIONS = [
    (["drape", __file__, "--surface", "brooks"], "--step", 0.0, True, math.inf),
    (["drape", __file__, "--surface", "brooks"], "--print-speed", 0.0, True, 10_000.0),
    (["drape", __file__, "--surface", "brooks"], "--clearance", 0.0, False, math.inf),
    (["drape", __file__, "--surface", "brooks"], "--fill-angle", -math.inf, False, math.inf),
    (["view", "D"], "--glyph-stride", 1.0, False, 1e6),
]

option_values = (st.floats(allow_nan=True, allow_infinity=True).map(repr)
                 | st.integers(-10**30, 10**30).map(str)
                 | st.sampled_from(["nan", "-inf", "1e309", "0x10", "", " 5", "1_000", "5mm", "1" * 400, "-0"])
                 | st.text(max_size=12))


@SETTINGS
@given(st.sampled_from(NUMERIC_OPTIONS), option_values)
def test_numeric_options_are_finite_in_range_or_refused_in_one_line(spec, value):
    prefix, option, lo, lo_open, hi = spec
    parser = build_parser(prefix[0])
    stderr = io.StringIO()
    try:
        with contextlib.redirect_stderr(stderr):
            args = parser.parse_args([*prefix, f"{option}={value}"])
    except SystemExit as exc:
        err = stderr.getvalue().strip()
        assert exc.code == 2 and len(err.splitlines()) == 1 and option in err, err
        return
    parsed = getattr(args, option.lstrip("-").replace("-", "_"))
    assert math.isfinite(parsed) and (lo < parsed if lo_open else lo <= parsed) and parsed <= hi
