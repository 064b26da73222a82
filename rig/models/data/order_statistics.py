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
    """The values of rank `ranks` (0: the smallest) of `x`, or None where numpy should do it (module docstring):
    data with NaN, or whose wanted bins hold more than half of the values. The passes over every value are compiled
    loops; the few steps on the bins are numpy's (numba's own partition and search took 16 s to compile)."""
    if x.size < SMALL or x.dtype.kind != "f":
        return None
    lo, hi, finite = _value_range(x)
    if not finite:
        return None
    if not hi > lo:  # every value the same
        return np.full(len(ranks), lo)
    scale = BINS / (hi - lo)
    counts = np.zeros(BINS, np.int64)
    _count_bins(x, lo, scale, counts)
    start = np.concatenate([[0], np.cumsum(counts)])
    bin_of = np.searchsorted(start, ranks, side="right") - 1  # each rank's bin
    wanted = np.unique(bin_of)
    ends = np.cumsum(counts[wanted])  # the wanted bins' values, one after another in `kept`
    if ends[-1] > x.size // 2:
        return None
    slot = np.full(BINS, -1, np.int64)  # where each wanted bin's values go in `kept`
    slot[wanted] = ends - counts[wanted]
    kept = np.empty(int(ends[-1]), x.dtype)
    _gather_bins(x, lo, scale, slot.copy(), kept)
    out = np.empty(len(ranks))
    for j, (b, rank) in enumerate(zip(bin_of.tolist(), np.asarray(ranks).tolist())):
        k = rank - int(start[b])
        out[j] = np.partition(kept[slot[b]:slot[b] + counts[b]], k)[k]
    return out


@njit(cache=True, nogil=True)
def _value_range(x):  # pragma: no cover - compiled
    """The least and greatest of `x` (float64), and whether every value is a number (no NaN)."""
    lo, hi = np.inf, -np.inf
    for i in range(x.size):
        v = np.float64(x[i])
        if v != v:
            return lo, hi, False
        lo, hi = min(lo, v), max(hi, v)
    return lo, hi, True


@njit(cache=True, nogil=True, inline="always")
def _bin(v, lo, scale):  # pragma: no cover - compiled
    """A value's bin: (v - lo) * scale never decreases as v grows, so a bin's values are all at least the lower bins'."""
    return min(np.int64((np.float64(v) - lo) * scale), BINS - 1)


@njit(cache=True, nogil=True)
def _count_bins(x, lo, scale, counts):  # pragma: no cover - compiled
    """How many values of `x` fall in each of the BINS bins (`_bin`)."""
    for i in range(x.size):
        counts[_bin(x[i], lo, scale)] += 1


@njit(cache=True, nogil=True)
def _gather_bins(x, lo, scale, at, kept):  # pragma: no cover - compiled
    """Each value of a wanted bin (`at[b]` >= 0: its next place in `kept`) into `kept`."""
    for i in range(x.size):
        b = _bin(x[i], lo, scale)
        if at[b] >= 0:
            kept[at[b]] = x[i]
            at[b] += 1
