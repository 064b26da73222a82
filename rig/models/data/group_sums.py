"""Sums of several per-row columns within groups of rows, in one compiled pass.

What every binned statistic is made of (the likelihood's range windows and stops, the diagnosis's bins):
`group_sums(labels, columns)` returns the distinct labels (sorted) and, per label, the sum of each
column over its rows. Labels are any integers; rows with a label below `skip_below` are left out.
"""

from __future__ import annotations

import numpy as np
from numba import njit


#: rows of the table of columns built at a time (list columns): bounded memory for any number of rows
BLOCK_ROWS = 1 << 18


def group_sums(labels: np.ndarray, columns: list[np.ndarray | float] | np.ndarray, *, more: np.ndarray | None = None,
               skip_below: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(sorted distinct labels, sums of shape (labels, columns)). `columns` is a list (a scalar column counts as
    that value per row) or a 2-D array with one row per pixel and one column per column (each pixel's values
    together in memory); `more`, one more column after them."""
    labels = np.asarray(labels)
    n = len(labels)
    width = (columns.shape[1] if isinstance(columns, np.ndarray) and columns.ndim == 2 else len(columns)) \
        + (0 if more is None else 1)
    valid = labels[labels >= skip_below] if skip_below is not None else labels
    if valid.size == 0:
        return np.zeros(0, np.int64), np.zeros((0, width))
    lo, hi = int(valid.min()), int(valid.max())
    sums = np.zeros((hi - lo + 1, width))
    counts = np.zeros(hi - lo + 1, np.int64)
    for a in range(0, n, BLOCK_ROWS):
        b = min(n, a + BLOCK_ROWS)
        if isinstance(columns, np.ndarray) and columns.ndim == 2:
            table = columns[a:b]
        else:
            table = np.empty((b - a, len(columns)))
            for i, c in enumerate(columns):
                table[:, i] = c[a:b] if isinstance(c, np.ndarray) and c.ndim else c
        extra = np.zeros(0) if more is None else np.asarray(more[a:b], dtype=np.float64)
        _sums(np.ascontiguousarray(labels[a:b], dtype=np.int64), np.ascontiguousarray(table), extra, lo, sums, counts)
    present = np.flatnonzero(counts)
    return present + lo, sums[present]


@njit(cache=True, nogil=True)
def _sums(labels, table, extra, lo, sums, counts):  # pragma: no cover - compiled
    """Row by row; a run of rows with one label (pixels of one bin lie together) is summed in a small local array
    and added into `sums` when the label changes."""
    n, k = table.shape
    k2 = 1 if extra.size else 0
    size = counts.size
    acc = np.zeros(k + k2)
    run = -1
    count = 0
    for i in range(n):
        g = labels[i] - lo
        if g < 0 or g >= size:
            continue
        if g != run:
            if run >= 0:
                counts[run] += count
                for j in range(k + k2):
                    sums[run, j] += acc[j]
                    acc[j] = 0.0
            run, count = g, 0
        count += 1
        for j in range(k):
            acc[j] += table[i, j]
        if k2:
            acc[k] += extra[i]
    if run >= 0:
        counts[run] += count
        for j in range(k + k2):
            sums[run, j] += acc[j]
