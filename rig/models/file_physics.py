"""What every model includes because the depth file fixes it: the deepest range a uint16 depth
image holds, and the curvature of Z = f b / d (paper, eq. dist_to_disp).

Far from the format's end (the usual case) both are corrections in closed form: the cut as a
one-sided truncation of a normal disparity error, the curvature to second order. Where the
noise reaches the end (within NEAR_LIMIT_SIGMA standard deviations), the two interact, and
`range_transform` computes the range's moments exactly instead: by Gauss-Legendre quadrature
of Z = f b / (d0 + sigma_d x) over the normal x, cut below at the format's end and, if the
camera censors, at +-c."""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.special import ndtr

from .data import ModelData
from .prediction import Prediction

#: the largest value a uint16 depth image holds; 0 means no data
MAX_DEPTH_UNITS = 65535
SQRT_2PI = math.sqrt(2 * math.pi)
#: pixels whose disparity error reaches the format's end within this many standard deviations get the exact transform
NEAR_LIMIT_SIGMA = 6.0
#: Gauss-Legendre nodes of the exact transform: 32 give the variance and fourth moment within 1e-9 of 64's
#: wherever the cut falls (checked from 0.5 to 6 standard deviations)
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(32)


def range_transform(pred: Prediction, d: ModelData) -> None:
    """The format's end and the curvature of Z = f b / d: closed-form corrections far from the end,
    exact moments by quadrature near it (see the module docstring); one compiled pass (`_transform`)."""
    var_lin = np.ascontiguousarray(pred.var_m2, dtype=float)
    n = var_lin.size
    base_var = var_lin if pred.censor is None else np.ascontiguousarray(pred.censor[1], dtype=float)
    k4_in = np.zeros(1) if pred.k4_m4 is None else np.ascontiguousarray(np.broadcast_to(pred.k4_m4, var_lin.shape), dtype=float)
    cut = np.zeros(1) if pred.censor is None else np.ascontiguousarray(np.broadcast_to(pred.censor[0], var_lin.shape), dtype=float)
    var_out, k4_out, fill = np.empty(n), np.empty(n), np.empty(n)
    near = _transform(var_lin, base_var, k4_in, pred.k4_m4 is not None, cut, pred.censor is not None,
                      np.ascontiguousarray(d.z0_m, dtype=float), float(d.fb_px_m), MAX_DEPTH_UNITS * d.depth_unit_m,
                      NEAR_LIMIT_SIGMA, _NODES, _WEIGHTS, var_out, k4_out, fill)
    pred.var_m2 = var_out
    pred.k4_m4 = k4_out
    if near:
        pred.fill = (pred.fill if pred.fill is not None else 1.0) * fill


@njit(cache=True, nogil=True)
def _transform(var_lin, base_var, k4_in, has_k4, cut, censored, z0, fb, z_max, near_sigma, nodes, weights,
               var_out, k4_out, fill):  # pragma: no cover - compiled
    """Per pixel: far from the end (the disparity error a > -near_sigma of its own standard deviations from it),
    `curvature`'s closed form; near it, Gauss-Legendre quadrature of Z = f b / (d0 + sigma_d x) over the normal x
    on [max(a, -c), min(c, 8)] (c the censoring cut, 8 without). Returns whether any pixel was near."""
    any_near = False
    inv_root_2pi = 1.0 / math.sqrt(2.0 * math.pi)
    w_at = np.empty(nodes.size)  # a near pixel's quadrature weights and ranges, made once for both passes
    z_at = np.empty(nodes.size)
    for i in range(var_lin.size):
        z = z0[i]
        v = var_lin[i]
        k4 = k4_in[i] if has_k4 else 0.0
        sigma_d = math.sqrt(base_var[i]) * fb / (z * z)
        a = (fb / z_max - fb / z) / sigma_d
        if not a > -near_sigma:
            rel = v / (z * z)
            var_out[i] = v * (1.0 + 8.0 * rel)
            k4_out[i] = k4 + 72.0 * rel * v * v
            fill[i] = 1.0
            continue
        any_near = True
        c = cut[i] if censored else 8.0
        lo, hi = max(a, -c), min(c, 8.0)
        kept_before = math.erf(c / math.sqrt(2.0)) if censored else 1.0  # 2 Phi(c) - 1
        half, mid = 0.5 * (hi - lo), 0.5 * (hi + lo)
        d0 = fb / z
        mass = total = 0.0
        for j in range(nodes.size):
            x = mid + half * nodes[j]
            w = half * weights[j] * math.exp(-0.5 * x * x) * inv_root_2pi
            den = max(d0 + sigma_d * x, 1e-12)
            w_at[j], z_at[j] = w, fb / den
            mass += w
            total += w * fb / den
        mass = max(mass, 1e-300)
        mean = total / mass
        m2 = m4 = 0.0
        for j in range(nodes.size):
            dev = z_at[j] - mean
            dev2 = dev * dev
            m2 += w_at[j] * dev2
            m4 += w_at[j] * dev2 * dev2
        var_near = m2 / mass
        var_out[i] = var_near
        k4_out[i] = m4 / mass - 3.0 * var_near * var_near
        fill[i] = mass / kept_before
    return any_near


def curvature(pred: Prediction, d: ModelData) -> None:
    """Z = f b / d is curved: to second order var Z = var_lin (1 + 8 var_lin / Z^2) (eq. dist_to_disp
    expanded one order beyond eq. error_prop_*); 0.7 % at 3 m for a 3 % error.

    The curve also gives the range error tails a normal disparity error does not have: with
    e = var_lin / Z^2, Z / Z0 = 1 - x + x^2 - x^3 (x the relative disparity error) has fourth
    cumulant 72 e^3 Z0^4 to leading order (48 from the x, x^2 terms, 24 from x, x^3), an excess
    kurtosis of 72 e: 0.016 at a 1.5 % error."""
    var_lin = pred.var_m2
    rel = var_lin / d.z0_m**2
    pred.var_m2 = var_lin * (1.0 + 8.0 * rel)
    k4 = 72.0 * rel * var_lin**2
    pred.k4_m4 = k4 if pred.k4_m4 is None else pred.k4_m4 + k4


def truncated_normal_moments(c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For N(0,1) truncated to [-c, c]: (fraction kept, E[x^2], E[x^4])."""
    kept = np.maximum(2 * ndtr(c) - 1, 1e-300)
    phi = np.exp(-0.5 * c * c) / SQRT_2PI
    m2 = 1 - 2 * c * phi / kept
    m4 = 3 - 2 * phi * (c**3 + 3 * c) / kept
    return kept, m2, m4
