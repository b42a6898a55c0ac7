"""curvslice.vectors.row_norms is ``np.linalg.norm(x, axis=-1)`` bit for bit (the tool-path stage relies on
it to give the same paths), for any float64 rows and shapes, and falls back for other dtypes."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from curvslice.vectors import row_norms

finite = st.floats(min_value=-1e150, max_value=1e150, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(0, 40), st.integers(1, 10)), elements=finite))
def test_rows_match_numpy_bit_for_bit(x: np.ndarray) -> None:
    assert np.array_equal(row_norms(x), np.linalg.norm(x, axis=-1))
    strided = x.T.copy().T
    assert np.array_equal(row_norms(strided), np.linalg.norm(strided, axis=-1))


def test_stacks_large_arrays_and_other_dtypes() -> None:
    rng = np.random.default_rng(0)
    x = rng.standard_normal((40, 500, 3)) * rng.random((40, 500, 1)) ** 6 * 1e4
    assert np.array_equal(row_norms(x), np.linalg.norm(x, axis=-1))
    y = rng.standard_normal((200_000, 3))
    assert np.array_equal(row_norms(y), np.linalg.norm(y, axis=1))
    for other in (y.astype(np.float32), np.array([[3, 4], [6, 8]])):
        result = row_norms(other)
        assert result.dtype == np.linalg.norm(other, axis=-1).dtype
        assert np.array_equal(result, np.linalg.norm(other, axis=-1))
