"""The moments of a normal variable rounded to a grid, given where the rounded samples' mean sits on it.

Depth is stored in whole depth units q. In units of q, a pixel's range X ~ N(mu, s^2) is
recorded as R = round(X), with P(R = k) = Phi((k + 1/2 - mu) / s) - Phi((k - 1/2 - mu) / s).
For s well above 1, R's variance is s^2 + 1/12 (Sheppard's correction). Below that it depends
on where mu sits between two levels: a pixel whose true mean is on a level records one value
(variance 0), one half-way records two values equally often (variance 1/4). The recorded mean
tells where: with mu = L + phi (L a level, |phi| <= 1/2), E[R] = L + h(phi, s), and h is
monotone in phi. So the measured mean's offset f from the nearest level fixes phi = h^-1(f, s),
and with it Var[R] and the fourth central moment.

`rounded_moments(s, f)` interpolates a table of both over s in [S_MIN, S_MAX] (log spaced) and
f in [0, 1/2], computed once from the sums above; beyond S_MAX it uses Sheppard's moments
(var s^2 + 1/12, fourth cumulant -1/120).

A sample variance s2 = M2 / (n - 1) is unbiased for Var[R], but not once its own mean has been
used to place phi: with two levels, s2 = n / (n - 1) f (1 - f) exactly, while Var[R] at the
phi that reproduces f is f (1 - f); and a pixel whose samples are all equal (s2 = 0) is not in
the data at all. `expected_sample_variance` therefore takes, for spreads up to
`rounding_table.S_GRID[-1]` (0.7 q), the exact E[s2 | measured mean, s2 > 0] from
`rig.models.data.rounding_table` (generating functions over the counts on each level, averaged over
where the true mean sits). Above it the conditioning is below 1e-3 of the variance, and
Var[R] (1 + b(s) / (n - 1)) with b(s) = 1 / (1 + (s / 0.18)^6) is used; the two are blended
over 0.55-0.7 q. Against simulated rounded normals (tests/test_rounding.py) this holds pixel by
pixel, in bands of the measured offset, to the simulation's own standard error.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit
from scipy.special import ndtr

from .rounding_table import S_GRID, conditional_variance

S_MIN, S_MAX = 0.02, 3.0
#: spreads (units of q) over which the exact table hands over to the approximation
BLEND = (0.55, 0.7)
_N_S, _N_F = 120, 101


def conditioning(s: np.ndarray) -> np.ndarray:
    """b(s): how much of the n / (n - 1) of two-level data a spread of s (units of q) keeps."""
    return 1.0 / (1.0 + (np.asarray(s, dtype=float) / 0.18) ** 6)


def _moments_at(phi: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean offset h, variance, fourth central moment) of round(N(phi, s^2)), for an array of phi."""
    k = np.arange(-int(np.ceil(6 * s)) - 2, int(np.ceil(6 * s)) + 3)[:, None]
    p = ndtr((k + 0.5 - phi) / s) - ndtr((k - 0.5 - phi) / s)
    mean = np.sum(k * p, axis=0)
    dev = k - mean
    return mean, np.sum(dev**2 * p, axis=0), np.sum(dev**4 * p, axis=0)


@lru_cache(maxsize=1)
def _table() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """log s grid, f grid, and Var[R], E[(R - E R)^4] on them."""
    log_s = np.linspace(np.log(S_MIN), np.log(S_MAX), _N_S)
    f_grid = np.linspace(0.0, 0.5, _N_F)
    t = np.linspace(0.0, 1.0, 1201)
    phi = 0.5 * (1.0 - (1.0 - t) ** 3)  # dense near 1/2, where h climbs steeply for small s
    var = np.empty((_N_S, _N_F))
    mu4 = np.empty((_N_S, _N_F))
    for i, s in enumerate(np.exp(log_s)):
        h, v, m4 = _moments_at(phi, float(s))
        h = np.maximum.accumulate(h)  # monotone against rounding error in the sums
        at = np.interp(f_grid, h, phi)  # phi whose rounded mean sits at offset f
        _, var[i], mu4[i] = _moments_at(at, float(s))
    return log_s, f_grid, var, mu4


def rounded_moments(s: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Var[R] and the fourth central moment of R (both in units of q), for spread s (units of q) and the
    measured mean's offset f from the nearest level (units of q, |f| <= 1/2)."""
    var, mu4 = _lookup(np.asarray(s, dtype=float), np.asarray(f, dtype=float), np.zeros(1), False)
    return var, mu4


def _lookup(s: np.ndarray, f: np.ndarray, n: np.ndarray, conditioned: bool) -> tuple[np.ndarray, np.ndarray]:
    """`rounded_moments` on broadcast s, f (and, `conditioned`, Var[R] (1 + b(s) / (n - 1)) in place of Var[R])."""
    log_s, f_grid, var_t, mu4_t = _table()
    s_b, f_b, n_b = np.broadcast_arrays(s, f, n if conditioned else 0.0)
    shape = s_b.shape
    var, mu4 = np.empty(shape), np.empty(shape)
    _moments(np.ascontiguousarray(s_b, dtype=float).ravel(), np.ascontiguousarray(f_b, dtype=float).ravel(),
             np.ascontiguousarray(n_b, dtype=float).ravel(), conditioned, float(log_s[0]), float(log_s[1] - log_s[0]),
             float(f_grid[1] - f_grid[0]), var_t, mu4_t, var.reshape(-1), mu4.reshape(-1))
    return var, mu4


@njit(cache=True, nogil=True)
def _moments(s, f, n, conditioned, log_s0, dlog_s, df, var_t, mu4_t, var, mu4):  # pragma: no cover - compiled
    """Per element: the table's bilinear interpolation in (ln s, |f|) up to S_MAX, Sheppard's moments beyond;
    with `conditioned`, the variance times 1 + b(s) / max(n - 1, 1) (`conditioning`)."""
    ns, nf = var_t.shape
    for e in range(s.size):
        se = s[e]
        if se > S_MAX:
            v = se * se + 1.0 / 12.0
            m4 = 3 * v * v - 1.0 / 120.0
        else:
            ls = np.log(max(se, 1e-300))
            ls = min(max(ls, log_s0), log_s0 + dlog_s * (ns - 1))
            x = (ls - log_s0) / dlog_s
            i = min(max(int(x), 0), ns - 2)
            wx = x - i
            y = min(max(abs(f[e]), 0.0), 0.5) / df
            j = min(max(int(y), 0), nf - 2)
            wy = y - j
            v = ((1 - wx) * (1 - wy) * var_t[i, j] + wx * (1 - wy) * var_t[i + 1, j]
                 + (1 - wx) * wy * var_t[i, j + 1] + wx * wy * var_t[i + 1, j + 1])
            m4 = ((1 - wx) * (1 - wy) * mu4_t[i, j] + wx * (1 - wy) * mu4_t[i + 1, j]
                  + (1 - wx) * wy * mu4_t[i, j + 1] + wx * wy * mu4_t[i + 1, j + 1])
        if conditioned:
            v *= 1.0 + 1.0 / (1.0 + (se / 0.18) ** 6) / max(n[e] - 1.0, 1.0)
        var[e] = v
        mu4[e] = m4


def grid_offset(mean_units: np.ndarray) -> np.ndarray:
    """The offset of a mean (in units of q) from the nearest grid level, in [-1/2, 1/2]."""
    return mean_units - np.round(mean_units)


def expected_sample_variance(s: np.ndarray, f: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E[s2 | measured offset f, s2 > 0] of a pixel (units of q^2), and the fourth central moment (q^4)."""
    s = np.asarray(s, dtype=float)
    n = np.asarray(n, dtype=float)
    approx, mu4 = _lookup(s, np.asarray(f, dtype=float), n, True)  # Var[R] (1 + b(s) / (n - 1))
    s_b, f_b, n_b = np.broadcast_arrays(s, f, n)
    narrow = s_b < S_GRID[-1]
    if not np.any(narrow):
        return approx, mu4
    s_n = s_b[narrow]
    exact = conditional_variance(s_n, f_b[narrow], n_b[narrow])
    # blend over BLEND (ln s) so the prediction stays smooth where the table ends; above it (the weight 1) the
    # approximation is kept as it is, so only the narrow rows are blended
    lo, hi = np.log(BLEND[0]), np.log(S_GRID[-1])
    w = np.clip((np.log(np.maximum(s_n, 1e-300)) - lo) / (hi - lo), 0.0, 1.0)
    approx[narrow] = (1.0 - w) * exact + w * approx[narrow]  # `_lookup` made it, in the broadcast shape: no copy
    return approx, mu4
