"""The shape-preserving cubic (PCHIP) the empirical terms are drawn with, and its derivative with respect to
the values at the knots (what an empirical term's analytic gradient needs: `rig.models.parts.tangents`)."""

from __future__ import annotations

import numpy as np
from numba import njit


def hermite_basis(knots: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each x (clipped to the knots) falls and the cubic Hermite basis there: (interval index i, the (4, n)
    array H00, H10 h, H01, H11 h, h the interval's width). It depends on x and the knots alone, so a fit that
    evaluates a shape thousands of times on the same rows computes it once (`rig.models.effects.empirical`)."""
    knots = np.asarray(knots, dtype=float)
    x = np.clip(x, knots[0], knots[-1])
    i = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, len(knots) - 2)
    h = np.diff(knots)[i]
    t = (x - knots[i]) / h
    t2 = t * t
    t3 = t2 * t
    return i, np.array([2 * t3 - 3 * t2 + 1, (t3 - 2 * t2 + t) * h, 3 * t2 - 2 * t3, (t3 - t2) * h])


def smooth(knots: np.ndarray, values: np.ndarray, x: np.ndarray,
           basis: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """A shape-preserving cubic through (knots, values), flat beyond the ends: scipy's PCHIP (the same slopes,
    Fritsch-Butland at the interior knots and its three-point rule at the ends), evaluated directly because a
    fit evaluates it thousands of times on the same few knots. `basis`: `hermite_basis(knots, x)`, if kept."""
    if len(knots) < 3:
        return np.interp(np.clip(x, knots[0], knots[-1]), knots, values)
    values = np.asarray(values, dtype=float)
    slopes = pchip_slopes(np.asarray(knots, dtype=float), values)
    return _hermite(values, slopes, *(basis if basis is not None else hermite_basis(knots, x)))


def _hermite(values: np.ndarray, slopes: np.ndarray, i: np.ndarray, hb: np.ndarray) -> np.ndarray:
    """The cubic Hermite form H00 y_i + H10 h s_i + H01 y_i+1 + H11 h s_i+1 on a kept basis (`hermite_basis`); one
    compiled pass (`_hermite_rows`: numpy's four gathers were ~95 us of 8,192 rows, thousands of times a diagnosis)."""
    out = np.empty(i.size)
    _hermite_rows(np.ascontiguousarray(values, dtype=float), np.ascontiguousarray(slopes, dtype=float),
                  np.ascontiguousarray(i, dtype=np.int64), np.ascontiguousarray(hb, dtype=float), out)
    return out


@njit(cache=True, nogil=True)
def _hermite_rows(values, slopes, i, hb, out):  # pragma: no cover - compiled
    """`_hermite`, row by row, in numpy's order of operations (within 85 u of the terms' size, tests/test_models.py)."""
    for r in range(i.size):
        k = i[r]
        out[r] = hb[0, r] * values[k] + hb[1, r] * slopes[k] + hb[2, r] * values[k + 1] + hb[3, r] * slopes[k + 1]


def pchip_slopes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The slopes at the knots of scipy's PchipInterpolator (scipy.interpolate._cubic, _find_derivatives); compiled
    (`_slopes`), because numpy's overhead on a handful of knots was ~45 us a call."""
    d = np.empty(len(y))
    _slopes(np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(y, dtype=float), d)
    return d


@njit(cache=True, nogil=True)
def _slopes(x, y, d):  # pragma: no cover - compiled
    """Interior knots: 0 where the secants on either side differ in sign or one is 0, else their weighted harmonic
    mean 1 / ((w1 / m0 + w2 / m1) / (w1 + w2)); the ends: `_end`."""
    n = y.size
    for k in range(1, n - 1):
        h0, h1 = x[k] - x[k - 1], x[k + 1] - x[k]
        m0, m1 = (y[k] - y[k - 1]) / h0, (y[k + 1] - y[k]) / h1
        if m0 == 0.0 or m1 == 0.0 or _sign(m0) != _sign(m1):
            d[k] = 0.0
        else:
            w1, w2 = 2 * h1 + h0, h1 + 2 * h0
            d[k] = 1.0 / ((w1 / m0 + w2 / m1) / (w1 + w2))
    ha, hb = x[1] - x[0], x[2] - x[1]
    d[0] = _end(ha, hb, (y[1] - y[0]) / ha, (y[2] - y[1]) / hb)
    ha, hb = x[n - 1] - x[n - 2], x[n - 2] - x[n - 3]
    d[n - 1] = _end(ha, hb, (y[n - 1] - y[n - 2]) / ha, (y[n - 2] - y[n - 3]) / hb)


@njit(cache=True, nogil=True, inline="always")
def _sign(v):  # pragma: no cover - compiled
    return (v > 0.0) - (v < 0.0)


@njit(cache=True, nogil=True, inline="always")
def _end(h0, h1, m0, m1):  # pragma: no cover - compiled
    """scipy's one-sided three-point slope at an end, kept shape-preserving."""
    d = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    if _sign(d) != _sign(m0):
        return 0.0
    if _sign(m0) != _sign(m1) and abs(d) > abs(3 * m0):
        return 3 * m0
    return d


def smooth_jacobian(knots: np.ndarray, values: np.ndarray, x: np.ndarray,
                    basis: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`smooth(knots, values, x)` and its derivative with respect to each knot's value, (K, len(x)): the cubic
    Hermite form g = H00 y_i + H10 h s_i + H01 y_i+1 + H11 h s_i+1, with the slopes' own derivatives
    (`slopes_jacobian`). `basis`: `hermite_basis(knots, x)`, if kept."""
    knots = np.asarray(knots, dtype=float)
    values = np.asarray(values, dtype=float)
    n_k = len(knots)
    if n_k < 3:
        x = np.clip(x, knots[0], knots[-1])
        t = (x - knots[0]) / (knots[1] - knots[0])
        jac = np.zeros((n_k, x.size))
        jac[0], jac[1] = 1 - t, t
        return np.interp(x, knots, values), jac
    slopes = pchip_slopes(knots, values)
    ds = slopes_jacobian(knots, values)
    i, hb = basis if basis is not None else hermite_basis(knots, x)
    g = _hermite(values, slopes, i, hb)
    jac = np.empty((n_k, i.size))
    _jacobian_rows(np.ascontiguousarray(ds), np.ascontiguousarray(i, dtype=np.int64), np.ascontiguousarray(hb, dtype=float), jac)
    return g, jac


@njit(cache=True, nogil=True)
def _jacobian_rows(ds, i, hb, jac):  # pragma: no cover - compiled
    """d g / d y_k per row: H10 h ds_i,k + H11 h ds_i+1,k, plus H00 at k = i and H01 at k = i + 1."""
    for r in range(i.size):
        a = i[r]
        for k in range(jac.shape[0]):
            jac[k, r] = hb[1, r] * ds[a, k] + hb[3, r] * ds[a + 1, k]
        jac[a, r] += hb[0, r]
        jac[a + 1, r] += hb[2, r]


def slopes_jacobian(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """d slope_k / d y_j (K x K) of `pchip_slopes`: interior slopes are weighted harmonic means of the secants
    m (d = (w1 + w2) / (w1 / m0 + w2 / m1), so dd/dm0 = d^2 w1 / ((w1 + w2) m0^2)), zero where flat; the ends
    follow `_end`'s branch; dm_j / dy = (e_j+1 - e_j) / h_j."""
    h = np.diff(x)
    m = np.diff(y) / h
    n_k = len(y)
    dm = np.zeros((n_k - 1, n_k))
    for j in range(n_k - 1):
        dm[j, j], dm[j, j + 1] = -1.0 / h[j], 1.0 / h[j]
    out = np.zeros((n_k, n_k))
    d = pchip_slopes(x, y)
    for k in range(1, n_k - 1):
        m0, m1 = m[k - 1], m[k]
        if np.sign(m0) != np.sign(m1) or m0 == 0 or m1 == 0:
            continue
        w1, w2 = 2 * h[k] + h[k - 1], h[k] + 2 * h[k - 1]
        out[k] = d[k] ** 2 / (w1 + w2) * (w1 / m0**2 * dm[k - 1] + w2 / m1**2 * dm[k])
    out[0] = _end_jacobian(h[0], h[1], m[0], m[1], dm[0], dm[1])
    out[-1] = _end_jacobian(h[-1], h[-2], m[-1], m[-2], dm[-1], dm[-2])
    return out


def _end_jacobian(h0: float, h1: float, m0: float, m1: float, dm0: np.ndarray, dm1: np.ndarray) -> np.ndarray:
    """The derivative of `_end`'s slope, on the branch it takes."""
    d = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    if np.sign(d) != np.sign(m0):
        return np.zeros_like(dm0)
    if np.sign(m0) != np.sign(m1) and abs(d) > abs(3 * m0):
        return 3 * dm0
    return ((2 * h0 + h1) * dm0 - h0 * dm1) / (h0 + h1)
