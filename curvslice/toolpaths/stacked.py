"""Index bookkeeping of runs stacked into one array: pieces (polylines) by ``np.vstack``, or any
counts of entries one after the other."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def run_labels(counts: Sequence[int] | np.ndarray) -> np.ndarray:
    """The run of every entry when run ``k`` has ``counts[k]`` entries: ``0, 0, 1, 2, 2, 2`` for
    counts ``2, 1, 3``."""
    return np.repeat(np.arange(len(counts)), counts)


def run_offsets(counts: Sequence[int] | np.ndarray) -> np.ndarray:
    """Every entry's place within its run: ``0, 1, 0, 0, 1, 2`` for counts ``2, 1, 3``."""
    counts = np.asarray(counts, np.int64)
    return np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)


def concat_ranges(starts: np.ndarray, counts: Sequence[int] | np.ndarray) -> np.ndarray:
    """``np.concatenate([np.arange(s, s + c) for s, c in zip(starts, counts)])`` without the loop."""
    return np.repeat(starts, counts) + run_offsets(counts)


def piece_labels(pieces: Sequence[np.ndarray]) -> np.ndarray:
    """The piece of every row of ``np.vstack(pieces)``."""
    return run_labels([len(p) for p in pieces])
