"""How far the streaming per-pixel moments (protocols.stats.PixelMomentAccumulator) and numpy's two-pass moments of
the same frames may each be from the exact moments: first-order bounds on the rounding of the operations each
performs, pixel by pixel, in absolute terms (u = eps / 2: a correctly rounded operation's relative error). Two
implementations agree within the sum of their bounds; a test compares them so (tests/test_stats.py,
tests/test_runner.py, tests/test_stats_lag1.py), not to the last bit and not to a tolerance picked from one run.

The accumulator (protocols/stats.py): each pixel's samples x, shifted by its first valid sample, summed as S1, S2 in
int64 (exact), x^3 = x * x^2 (exact while |x| < 2^17.6: always, for uint16 samples) and x^4 = x^3 * x (rounded) in
float64, k - 1 additions each; then, with a = S1 / n (two roundings), M2 = (n S2 - S1^2) / n s^2 (an exact integer,
then 3 roundings), M3 = (S3 - 3 a S2 + 2 n a^3) s^3 and M4 = (S4 - 4 a S3 + 6 a^2 S2 - 3 n a^4) s^4, whose terms
each carry the roundings of their products and powers (numba raises to whole powers by products), and the mean
(shift + a) s. numpy: z = sample * s (one rounding), the mean of the k values (k - 1 additions and a quotient), the
deviations d = z - mean (one rounding, and the mean's error, which cancels from M2 to first order since the exact
deviations sum to 0, but not from M3, M4 and the lag-1 sum), their powers (d^2 a product, d^3 and d^4 numpy's pow,
within 1 ulp = 2 u) and their sum (k - 1 additions).
"""

from __future__ import annotations

import numpy as np

U = np.finfo(np.float64).eps / 2


def _valid(frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    valid = frames > 0
    return valid, valid.sum(axis=0).astype(np.float64)


def accumulator_bounds(frames: np.ndarray, scale: float) -> dict[str, np.ndarray]:
    """Bounds of the accumulator's mean_m, m2_m2, m3_m3, m4_m4 (m^k) on `frames` (n, h, w) of depth units, 0 missing."""
    valid, k = _valid(frames)
    first = np.argmax(valid, axis=0)
    shift = np.take_along_axis(frames, first[None], axis=0)[0].astype(np.float64)
    x = np.where(valid, frames.astype(np.float64) - shift, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        signed = np.nan_to_num(x.sum(axis=0) / k)
    a = np.abs(signed)
    dev = np.where(valid, np.abs(x - signed), 0.0)
    s2, s3, s4 = ((np.abs(x) ** p).sum(axis=0) for p in (2, 3, 4))
    m2, m3, m4 = ((dev**p).sum(axis=0) for p in (2, 3, 4))
    return {"mean_m": U * (2 * a + 2 * np.abs(shift + signed)) * scale,
            "m2_m2": 4 * U * m2 * scale**2,
            "m3_m3": U * ((k + 1) * s3 + 18 * a * s2 + 22 * k * a**3 + 4 * m3) * scale**3,
            "m4_m4": U * ((k + 3) * s4 + (k + 5) * 4 * a * s3 + 60 * a**2 * s2 + 42 * k * a**4 + 4 * m4) * scale**4}


def numpy_moments(frames: np.ndarray, scale: float) -> dict[str, np.ndarray]:
    """numpy's two-pass moments of `frames`: count, mean_m and the central sums m2_m2, m3_m3, m4_m4."""
    z = np.where(frames > 0, frames.astype(np.float64) * scale, np.nan)
    mean = np.nanmean(z, axis=0)
    d = z - mean
    return {"count": np.sum(frames > 0, axis=0), "mean_m": mean,
            **{f"m{p}_m{p}": np.nansum(d**p, axis=0) for p in (2, 3, 4)}}


def numpy_bounds(frames: np.ndarray, scale: float) -> dict[str, np.ndarray]:
    """Bounds of `numpy_moments` against the exact moments (see the module docstring)."""
    valid, k = _valid(frames)
    z = np.where(valid, frames.astype(np.float64) * scale, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.nan_to_num(z.sum(axis=0) / k)
    d = np.where(valid, np.abs(z - mean), 0.0)
    mean_error = (k + 1) * U * mean  # k - 1 additions, each sample's product, the quotient
    worst = U * z.max(axis=0) + mean_error  # each deviation's error before its own rounding
    m = {p: (d**p).sum(axis=0) for p in (1, 2, 3, 4)}
    z_weighted = {p: (d**p * z).sum(axis=0) for p in (1, 2, 3)}
    return {"mean_m": mean_error,
            "m2_m2": U * (2 * z_weighted[1] + (k + 2) * m[2]) + k * worst**2,
            "m3_m3": U * (3 * z_weighted[2] + (k + 5) * m[3]) + 3 * mean_error * m[2] + 3 * worst**2 * m[1],
            "m4_m4": U * (4 * z_weighted[3] + (k + 7) * m[4]) + 4 * mean_error * m[3] + 6 * worst**2 * m[2]}


def lag1_bounds(frames: np.ndarray, scale: float) -> np.ndarray:
    """Bound of |accumulator's lag1_m2 - numpy's sum over consecutive valid pairs of (z_t - mean)(z_t-1 - mean)|.

    The accumulator: C1 = (P - a Q + p a^2) s^2 from the exact integer sums P = sum x_t x_t-1, Q = sum (x_t + x_t-1)
    over p pairs, a = S1 / n (one rounding): a Q within 2 u, p a a within 4 u, two sums and two products by s.
    numpy: each deviation's error as in `numpy_bounds` enters each product through the other factor; the mean's
    error enters through sum over pairs of (d_t + d_t-1), which need not vanish; the products round, p - 1 additions."""
    valid, k = _valid(frames)
    first = np.argmax(valid, axis=0)
    shift = np.take_along_axis(frames, first[None], axis=0)[0].astype(np.float64)
    x = np.where(valid, frames.astype(np.float64) - shift, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = np.abs(np.nan_to_num(x.sum(axis=0) / k))
    both = valid[1:] & valid[:-1]
    pairs = both.sum(axis=0)
    big_p = np.abs(np.where(both, x[1:] * x[:-1], 0.0)).sum(axis=0)
    big_q = np.abs(np.where(both, x[1:] + x[:-1], 0.0)).sum(axis=0)
    ours = U * (3 * big_p + 5 * a * big_q + 6 * pairs * a * a) * scale**2
    z = np.where(valid, frames.astype(np.float64) * scale, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.nan_to_num(z.sum(axis=0) / k)
    d = np.where(valid, z - mean, 0.0)
    mean_error = (k + 1) * U * mean
    own = U * (z + np.abs(d))  # each deviation's own rounding error (its sample's product, the difference)
    products = np.where(both, np.abs(d[1:] * d[:-1]), 0.0)
    theirs = (np.where(both, np.abs(d[:-1]) * own[1:] + np.abs(d[1:]) * own[:-1], 0.0).sum(axis=0)
              + mean_error * np.abs(np.where(both, d[1:] + d[:-1], 0.0).sum(axis=0))
              + pairs * U * products.sum(axis=0) + pairs * mean_error**2)
    return ours + theirs
