"""curvslice.vectors.row_norms is ``np.linalg.norm(x, axis=-1)`` bit for bit (the tool-path stage relies on
it to give the same paths), for any float64 rows and shapes, and falls back for other dtypes; pair_distances is
``row_norms(points[a] - points[b])`` bit for bit."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from curvslice.vectors import pair_distances, row_norms

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


@settings(max_examples=200, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 30), st.just(3)), elements=finite), st.data())
def test_pair_distances_match_row_gathers_bit_for_bit(points: np.ndarray, data: st.DataObject) -> None:
    n = len(points)
    pairs = data.draw(arrays(np.int64, st.tuples(st.integers(0, 60), st.just(2)), elements=st.integers(0, n - 1)))
    a, b = pairs[:, 0], pairs[:, 1]
    assert np.array_equal(pair_distances(points, a, b), row_norms(points[a] - points[b]))
    strided = points.T.copy().T  # (column-major rows, as a transposed view hands them over)
    assert np.array_equal(pair_distances(strided, a, b), row_norms(points[a] - points[b]))
