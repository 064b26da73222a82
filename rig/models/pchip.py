"""The shape-preserving cubic (PCHIP) the empirical terms are drawn with, and its derivative with respect to
the values at the knots (what an empirical term's analytic gradient needs: `rig.models.tangents`)."""

from __future__ import annotations

import numpy as np


def smooth(knots: np.ndarray, values: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A shape-preserving cubic through (knots, values), flat beyond the ends: scipy's PCHIP (the same slopes,
    Fritsch-Butland at the interior knots and its three-point rule at the ends), evaluated directly because a
    fit evaluates it thousands of times on the same few knots."""
    x = np.clip(x, knots[0], knots[-1])
    if len(knots) < 3:
        return np.interp(x, knots, values)
    slopes = pchip_slopes(np.asarray(knots, dtype=float), np.asarray(values, dtype=float))
    i = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, len(knots) - 2)
    h = np.diff(knots)[i]
    t = (x - knots[i]) / h
    t2 = t * t
    t3 = t2 * t
    return ((2 * t3 - 3 * t2 + 1) * values[i] + (t3 - 2 * t2 + t) * h * slopes[i]
            + (3 * t2 - 2 * t3) * values[i + 1] + (t3 - t2) * h * slopes[i + 1])


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


def smooth_jacobian(knots: np.ndarray, values: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`smooth(knots, values, x)` and its derivative with respect to each knot's value, (K, len(x)): the cubic
    Hermite form g = H00 y_i + H10 h s_i + H01 y_i+1 + H11 h s_i+1, with the slopes' own derivatives
    (`slopes_jacobian`)."""
    knots = np.asarray(knots, dtype=float)
    values = np.asarray(values, dtype=float)
    x = np.clip(x, knots[0], knots[-1])
    n_k = len(knots)
    cols = np.arange(x.size)
    if n_k < 3:
        t = (x - knots[0]) / (knots[1] - knots[0])
        jac = np.zeros((n_k, x.size))
        jac[0], jac[1] = 1 - t, t
        return np.interp(x, knots, values), jac
    slopes = pchip_slopes(knots, values)
    ds = slopes_jacobian(knots, values)
    i = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, n_k - 2)
    h = np.diff(knots)[i]
    t = (x - knots[i]) / h
    t2, t3 = t * t, t * t * t
    h00, h10, h01, h11 = 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, 3 * t2 - 2 * t3, t3 - t2
    g = h00 * values[i] + h10 * h * slopes[i] + h01 * values[i + 1] + h11 * h * slopes[i + 1]
    jac = (h10 * h) * ds[i].T + (h11 * h) * ds[i + 1].T
    jac[i, cols] += h00
    jac[i + 1, cols] += h01
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
