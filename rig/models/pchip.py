"""The shape-preserving cubic (PCHIP) the empirical terms are drawn with, and its derivative with respect to
the values at the knots (what an empirical term's analytic gradient needs: `rig.models.tangents`)."""

from __future__ import annotations

import numpy as np


def hermite_basis(knots: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each x (clipped to the knots) falls and the cubic Hermite basis there: (interval index i, the (4, n)
    array H00, H10 h, H01, H11 h, h the interval's width). It depends on x and the knots alone, so a fit that
    evaluates a shape thousands of times on the same rows computes it once (`rig.models.empirical`)."""
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
    """The cubic Hermite form H00 y_i + H10 h s_i + H01 y_i+1 + H11 h s_i+1 on a kept basis (`hermite_basis`)."""
    return hb[0] * values[i] + hb[1] * slopes[i] + hb[2] * values[i + 1] + hb[3] * slopes[i + 1]


def pchip_slopes(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The slopes at the knots of scipy's PchipInterpolator (scipy.interpolate._cubic, _find_derivatives)."""
    h = np.diff(x)
    m = np.diff(y) / h
    d = np.zeros_like(y)
    sign = np.sign(m)
    flat = (sign[1:] != sign[:-1]) | (m[1:] == 0) | (m[:-1] == 0)
    w1, w2 = 2 * h[1:] + h[:-1], h[1:] + 2 * h[:-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        harmonic = (w1 / m[:-1] + w2 / m[1:]) / (w1 + w2)
        d[1:-1] = np.where(flat, 0.0, 1.0 / harmonic)
    d[0] = pchip_end(h[0], h[1], m[0], m[1])
    d[-1] = pchip_end(h[-1], h[-2], m[-1], m[-2])
    return d


def pchip_end(h0: float, h1: float, m0: float, m1: float) -> float:
    """scipy's one-sided three-point slope at an end, kept shape-preserving."""
    d = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    if np.sign(d) != np.sign(m0):
        return 0.0
    if np.sign(m0) != np.sign(m1) and abs(d) > abs(3 * m0):
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
    cols = np.arange(i.size)
    g = _hermite(values, slopes, i, hb)
    jac = hb[1] * ds[i].T + hb[3] * ds[i + 1].T
    jac[i, cols] += hb[0]
    jac[i + 1, cols] += hb[2]
    return g, jac


def slopes_jacobian(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """d slope_k / d y_j (K x K) of `pchip_slopes`: interior slopes are weighted harmonic means of the secants
    m (d = (w1 + w2) / (w1 / m0 + w2 / m1), so dd/dm0 = d^2 w1 / ((w1 + w2) m0^2)), zero where flat; the ends
    follow `pchip_end`'s branch; dm_j / dy = (e_j+1 - e_j) / h_j."""
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
    """The derivative of `pchip_end`'s slope, on the branch it takes."""
    d = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    if np.sign(d) != np.sign(m0):
        return np.zeros_like(dm0)
    if np.sign(m0) != np.sign(m1) and abs(d) > abs(3 * m0):
        return 3 * dm0
    return ((2 * h0 + h1) * dm0 - h0 * dm1) / (h0 + h1)
