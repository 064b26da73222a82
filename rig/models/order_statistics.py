"""Quantiles and medians of large arrays, the very values numpy's `quantile` (linear method) and `median` give, made
by a selection through a histogram instead of numpy's partition of every value.

numpy partitions the whole array around each order statistic it needs (about 0.1 s for the seven brightness edges of
a sweep's 4.5 M pixels). Here one compiled pass finds the range, a second counts the values in BINS equal bins
(a bin's values are all at least those of the bins below it), and a third gathers the values of the bins that
hold the wanted ranks; only those are partitioned (a sweep's brightness, with many pixels alike, puts about a sixth
of its values in the bins of its seven quantiles). The order statistics are then combined by numpy itself, on a
two-value array whose quantile at the wanted fraction goes through the same arithmetic as the whole array's
(tests/test_order_statistics.py holds every value to numpy's, bit for bit). Data with NaN, or whose wanted bins hold
half the values (heavy ties), are left to numpy.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: bins of the counting pass
BINS = 1 << 16
#: fewer values than this: numpy's own partition is as quick
SMALL = 100_000


def quantiles(x: np.ndarray, q: np.ndarray) -> np.ndarray:
    """np.quantile(x, q) of a 1-D array, bit for bit (see the module docstring)."""
    x, q = np.ascontiguousarray(x).ravel(), np.asarray(q, dtype=np.float64)
    virtual = (x.size - 1) * q
    below = np.floor(virtual)
    ranks = np.minimum(np.concatenate([below, below + 1]).astype(np.int64), x.size - 1)
    stats = _order_statistics(x, ranks)
    if stats is None:
        return np.quantile(x, q)
    pairs = stats.reshape(2, -1).T
    return np.array([np.quantile(pair.astype(x.dtype), np.array([g]))[0] for pair, g in zip(pairs, virtual - below)])


def median(x: np.ndarray) -> float:
    """float(np.median(x)) of a 1-D array, bit for bit (see the module docstring)."""
    x = np.ascontiguousarray(x).ravel()
    half = x.size // 2
    ranks = np.array([half - 1, half] if x.size % 2 == 0 else [half], dtype=np.int64)
    stats = _order_statistics(x, ranks) if x.size else None
    return float(np.median(x if stats is None else stats.astype(x.dtype)))


def _order_statistics(x: np.ndarray, ranks: np.ndarray) -> np.ndarray | None:
    """The values of rank `ranks` (0: the smallest) of `x`, or None where numpy should do it."""
    if x.size < SMALL or x.dtype.kind != "f":
        return None
    out = np.empty(len(ranks))
    return out if _select(x, np.ascontiguousarray(ranks), out) else None


@njit(cache=True, nogil=True)
def _select(x, ranks, out):  # pragma: no cover - compiled
    """Into `out`, the value of each rank in `ranks` (module docstring); False, leaving the work to numpy, for data
    with NaN or whose wanted bins hold more than half of the values."""
    n = x.size
    lo, hi = np.inf, -np.inf
    for i in range(n):
        v = np.float64(x[i])
        if v != v:
            return False
        lo, hi = min(lo, v), max(hi, v)
    if not hi > lo:  # every value the same
        out[:] = lo
        return True
    scale = BINS / (hi - lo)
    counts = np.zeros(BINS, np.int64)
    for i in range(n):  # (x - lo) * scale never decreases as x grows: the bins are in order
        counts[min(np.int64((np.float64(x[i]) - lo) * scale), BINS - 1)] += 1
    start = np.zeros(BINS + 1, np.int64)
    for b in range(BINS):
        start[b + 1] = start[b] + counts[b]
    bin_of = np.searchsorted(start, ranks, side="right") - 1  # each rank's bin
    slot = np.full(BINS, -1, np.int64)  # where each wanted bin's values go in `kept`
    at = np.zeros(BINS, np.int64)
    kept_size = 0
    for b in bin_of:
        if slot[b] < 0:
            slot[b] = kept_size
            at[b] = kept_size
            kept_size += counts[b]
    if kept_size > n // 2:
        return False
    kept = np.empty(kept_size, x.dtype)
    for i in range(n):
        b = min(np.int64((np.float64(x[i]) - lo) * scale), BINS - 1)
        if slot[b] >= 0:
            kept[at[b]] = x[i]
            at[b] += 1
    for j in range(ranks.size):
        b = bin_of[j]
        k = ranks[j] - start[b]
        out[j] = np.partition(kept[slot[b]:slot[b] + counts[b]], k)[k]
    return True
