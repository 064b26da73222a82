"""Sums of several per-row columns within groups of rows, in one compiled pass.

What every binned statistic is made of (the likelihood's range windows and stops, the diagnosis's bins):
`group_sums(labels, columns)` returns the distinct labels (sorted) and, per label, the sum of each
column over its rows. Labels are any integers; rows with a label below `skip_below` are left out.
"""

from __future__ import annotations

import numpy as np
from numba import njit


def group_sums(labels: np.ndarray, columns: list[np.ndarray | float] | np.ndarray, *, more: np.ndarray | None = None,
               skip_below: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(sorted distinct labels, sums of shape (labels, columns)). `columns` is a list (a scalar column counts as
    that value per row) or a 2-D array with one row per column; `more`, one more column after them."""
    labels = np.asarray(labels)
    n = len(labels)
    if isinstance(columns, np.ndarray) and columns.ndim == 2:
        table = columns
    else:
        table = np.empty((len(columns), n))
        for i, c in enumerate(columns):
            table[i] = c
    extra = np.zeros((0, n)) if more is None else np.asarray(more, dtype=np.float64).reshape(1, n)
    width = table.shape[0] + extra.shape[0]
    valid = labels[labels >= skip_below] if skip_below is not None else labels
    if valid.size == 0:
        return np.zeros(0, np.int64), np.zeros((0, width))
    lo, hi = int(valid.min()), int(valid.max())
    sums, counts = _sums(np.ascontiguousarray(labels, dtype=np.int64), table, extra, lo, hi - lo + 1)
    present = np.flatnonzero(counts)
    return present + lo, sums[present]


@njit(cache=True, nogil=True)
def _sums(labels, table, extra, lo, size):  # pragma: no cover - compiled
    k, n = table.shape
    k2 = extra.shape[0]
    sums = np.zeros((size, k + k2))
    counts = np.zeros(size, np.int64)
    for i in range(n):
        g = labels[i] - lo
        if g < 0 or g >= size:
            continue
        counts[g] += 1
        for j in range(k):
            sums[g, j] += table[j, i]
        for j in range(k2):
            sums[g, k + j] += extra[j, i]
    return sums, counts
