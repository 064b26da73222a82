"""What every model includes because the depth file fixes it: the deepest range a uint16 depth
image holds, and the curvature of Z = f b / d (paper, eq. dist_to_disp).

Far from the format's end (the usual case) both are corrections in closed form: the cut as a
one-sided truncation of a normal disparity error, the curvature to second order. Where the
noise reaches the end (within NEAR_LIMIT_SIGMA standard deviations), the two interact, and
`range_transform` computes the range's moments exactly instead: by Gauss-Legendre quadrature
of Z = f b / (d0 + sigma_d x) over the normal x, cut below at the format's end and, if the
camera censors, at +-c; or, where the camera does not censor, the cut is not inside the bulk
(a <= SERIES_MAX_CUT) and the relative disparity error r = sigma_d / d0 is small (<= SERIES_MAX_R),
by the series Z / Z0 = 1 / (1 + r x) over the truncated normal's moments (`_series`: the same
moments to 1e-12, at a fifth of the quadrature's cost)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..data.model_data import ModelData
from ..parts.prediction import Prediction
from ..parts.tangents import Tangents, plus, scale

#: the largest value a uint16 depth image holds; 0 means no data
MAX_DEPTH_UNITS = 65535
SQRT_2PI = math.sqrt(2 * math.pi)
#: pixels whose disparity error reaches the format's end within this many standard deviations get the exact transform
NEAR_LIMIT_SIGMA = 6.0
#: Gauss-Legendre nodes of the exact transform: 32 give the variance and fourth moment within 1e-9 of 64's
#: wherever the cut falls (checked from 0.5 to 6 standard deviations)
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(32)
#: the series serves near rows whose cut is at most this many standard deviations below the mean ...
SERIES_MAX_CUT = -1.0
#: ... and whose relative disparity error is at most this: there its terms beyond SERIES_TERMS are below 1e-12 of the
#: variance (r^n (n-1)!! n^3 / 6 at n = 24, r = 0.05); against the quadrature 1e-13 at r = 0.02, 2e-10 at 0.04
SERIES_MAX_R = 0.05
SERIES_TERMS = 24


def range_transform(pred: Prediction, d: ModelData, t: Tangents | None = None) -> None:
    """The format's end and the curvature of Z = f b / d: closed-form corrections far from the end,
    exact moments by quadrature near it (see the module docstring); one compiled pass (`_transform`).
    Given tangents (`rig.models.parts.tangents`), carries them through: analytic far from the end, where the
    correction is a formula; near it, by central differences of each row's own quadrature."""
    var_lin = np.ascontiguousarray(pred.var_m2, dtype=float)
    n = var_lin.size
    base_var = var_lin if pred.censor is None else np.ascontiguousarray(pred.censor[1], dtype=float)
    k4_in = np.zeros(1) if pred.k4_m4 is None else _per_row(pred.k4_m4, var_lin.shape)
    cut = np.zeros(1) if pred.censor is None else _per_row(pred.censor[0], var_lin.shape)
    var_out, k4_out, fill = np.empty(n), np.empty(n), np.empty(n)
    partials = np.empty((9, n) if t is not None else (9, 1))  # one contiguous row per partial: scaled below
    near = _transform(var_lin, base_var, k4_in, pred.k4_m4 is not None, cut, pred.censor is not None,
                      np.ascontiguousarray(d.z0_m, dtype=float), float(d.fb_px_m), MAX_DEPTH_UNITS * d.depth_unit_m,
                      NEAR_LIMIT_SIGMA, _NODES, _WEIGHTS, var_out, k4_out, fill, t is not None, partials)
    fill_before = pred.fill
    pred.var_m2 = var_out
    pred.k4_m4 = k4_out
    if near:
        pred.fill = (pred.fill if pred.fill is not None else 1.0) * fill
    if t is None:
        return
    # partials: d var / d (var_lin, base, cut), d k4 / d (var_lin, base, cut), d fill / d (base, cut), d k4 / d k4_in
    # (1 far from the end; 0 near it, where the quadrature does not use the cumulant the row came with)
    dv_lin, dv_base, dv_cut, dk_lin, dk_base, dk_cut, df_base, df_cut, dk_k4 = partials
    d_base = t.var if pred.censor is None else t.censor[1]
    d_cut = None if pred.censor is None else t.censor[0]
    new_var = plus(scale(t.var, dv_lin), scale(d_base, dv_base), scale(d_cut, dv_cut))
    new_k4 = plus(scale(t.k4, dk_k4) if near else t.k4, scale(t.var, dk_lin), scale(d_base, dk_base), scale(d_cut, dk_cut))
    if near:
        t.fill = plus(scale(t.fill, fill), scale(plus(scale(d_base, df_base), scale(d_cut, df_cut)),
                                                 1.0 if fill_before is None else fill_before))
    t.var, t.k4 = new_var, new_k4


def _per_row(a: np.ndarray | float, shape: tuple[int, ...]) -> np.ndarray:
    """`a` as a C-contiguous, writeable float64 array of `shape`: as it is when it is one, else a copy (numba compiles
    a read-only array, such as a broadcast, as another variant of `_transform`)."""
    a = np.asarray(a, dtype=float)
    return np.require(a if a.shape == shape else np.broadcast_to(a, shape), dtype=float, requirements=["C", "W"])


@njit(cache=True, nogil=True, inline="always")
def _near(z, base_var, c, censored, fb, z_max, nodes, weights, w_at, z_at, dw_at, dz_at, derivatives, out, sums):  # pragma: no cover - compiled
    """(variance, fourth cumulant, fill) of one row near the format's end: Gauss-Legendre quadrature of
    Z = f b / (d0 + sigma_d x) over the normal x on [max(a, -c), min(c, 8)] (c the censoring cut, 8 without),
    a = (f b / z_max - d0) / sigma_d; with `derivatives`, also d (variance, cumulant, fill) / d base_var and / d c.

    The derivatives follow the quadrature itself (the moments of the nodes, with the nodes moving with the ends
    of the interval): for a direction D that moves sigma_d and the ends lo, hi, D x_j = D mid + node_j D half,
    D w_j = w_j (D half / half - x_j D x_j), D Z_j = -Z_j^2 (x_j D sigma_d + sigma_d D x_j) / (f b); then the
    mass, mean and central sums follow by the product rule. Directions: base_var (D sigma_d = sigma_d / (2 base),
    D lo = -(a / sigma_d) D sigma_d where the format's end is the lower limit) and c (D lo = -1 where the cut is,
    D hi = 1 below 8; the fill's divisor 2 Phi(c) - 1 grows by 2 phi(c)). Fills `out` (9) and uses `sums` (5 x 2) as
    scratch, both the caller's (allocating them here, per row, was ~a quarter of a near row's time)."""
    inv_root_2pi = 1.0 / math.sqrt(2.0 * math.pi)
    sigma_d = math.sqrt(base_var) * fb / (z * z)
    a = (fb / z_max - fb / z) / sigma_d
    if not censored:
        c = 8.0
    lo, hi = max(a, -c), min(c, 8.0)
    kept_before = math.erf(c / math.sqrt(2.0)) if censored else 1.0  # 2 Phi(c) - 1
    half, mid = 0.5 * (hi - lo), 0.5 * (hi + lo)
    d0 = fb / z
    out[:] = 0.0
    sums[:, :] = 0.0
    dmass, dtotal, dm2, dm4, dmean = sums[0], sums[1], sums[2], sums[3], sums[4]
    n_dir = 2 if derivatives else 0
    # per direction: (D sigma_d, D lo, D hi)
    dsig = (0.5 * sigma_d / base_var, 0.0)
    dlo = ((-a / sigma_d) * dsig[0] if a > -c else 0.0, -1.0 if -c >= a and censored else 0.0)
    dhi = (0.0, 1.0 if c < 8.0 and censored else 0.0)
    mass = total = 0.0
    for j in range(nodes.size):
        x = mid + half * nodes[j]
        w = half * weights[j] * math.exp(-0.5 * x * x) * inv_root_2pi
        den = max(d0 + sigma_d * x, 1e-12)
        zj = fb / den
        w_at[j], z_at[j] = w, zj
        mass += w
        total += w * zj
        for k in range(n_dir):
            dhalf, dmid = 0.5 * (dhi[k] - dlo[k]), 0.5 * (dhi[k] + dlo[k])
            dx = dmid + nodes[j] * dhalf
            dw = w * (dhalf / half - x * dx)
            dz = -zj * zj * (x * dsig[k] + sigma_d * dx) / fb
            dw_at[k, j], dz_at[k, j] = dw, dz
            dmass[k] += dw
            dtotal[k] += dw * zj + w * dz
    mass = max(mass, 1e-300)
    mean = total / mass
    m2 = m4 = 0.0
    for k in range(n_dir):
        dmean[k] = (dtotal[k] - mean * dmass[k]) / mass
    for j in range(nodes.size):
        dev = z_at[j] - mean
        dev2 = dev * dev
        m2 += w_at[j] * dev2
        m4 += w_at[j] * dev2 * dev2
        for k in range(n_dir):
            ddev = dz_at[k, j] - dmean[k]
            dm2[k] += dw_at[k, j] * dev2 + 2.0 * w_at[j] * dev * ddev
            dm4[k] += dw_at[k, j] * dev2 * dev2 + 4.0 * w_at[j] * dev2 * dev * ddev
    var_near = m2 / mass
    out[0], out[1], out[2] = var_near, m4 / mass - 3.0 * var_near * var_near, mass / kept_before
    for k in range(n_dir):
        dvar = (dm2[k] - var_near * dmass[k]) / mass
        out[3 + 3 * k] = dvar
        out[4 + 3 * k] = (dm4[k] - m4 / mass * dmass[k]) / mass - 6.0 * var_near * dvar
        out[5 + 3 * k] = dmass[k] / kept_before
    if derivatives and censored:
        out[8] -= mass / kept_before**2 * 2.0 * math.exp(-0.5 * c * c) * inv_root_2pi
    return out


@njit(cache=True, nogil=True, inline="always")
def _series(z, v, fb, z_max, out):  # pragma: no cover - compiled
    """(variance, fourth cumulant, fill, and their derivatives d / d v) of Z = f b / (d0 + sigma_d x), x ~ N(0, 1) cut
    below at a (the format's end, in units of sigma_d; sigma_d^2 = v (f b / z^2)^2, the range variance v carried to
    disparity): Z / Z0 - 1 = sum_{n>=1} (-r x)^n with r = sigma_d / d0, so its j-th power is
    sum_{n>=j} C(n - 1, j - 1) (-r x)^n (the negative binomial series) and its raw moments m_j = sum_n C(n - 1, j - 1)
    (-r)^n E[x^n | x > a], with E[x^n | x > a] = (n - 1) E[x^(n-2) | x > a] + a^(n-1) lam, lam = phi(a) / (1 - Phi(a)).
    The derivatives follow the same sums: d r / d v = r / 2v, d a / d v = -a / 2v, d lam / d a = lam (lam - a).
    Fills `out[:6]`."""
    sigma_d = math.sqrt(v) * fb / (z * z)
    a = (fb / z_max - fb / z) / sigma_d
    r = sigma_d * z / fb
    kept = 0.5 * math.erfc(a / math.sqrt(2.0))
    phi = math.exp(-0.5 * a * a) / math.sqrt(2.0 * math.pi)
    lam = phi / kept
    da = -0.5 * a / v
    dlam = lam * (lam - a) * da
    drn = -0.5 * r / v  # d(-r) / d v
    e_prev, e_cur = 1.0, lam  # E[x^(n-2)], E[x^(n-1)] (n = 2 next)
    de_prev, de_cur = 0.0, dlam
    a_pow = 1.0  # a^(n-2)
    rn = -r  # (-r)^n, n = 1
    m1 = m2 = m3 = m4 = dm1 = dm2 = dm3 = dm4 = 0.0
    for n in range(1, SERIES_TERMS + 1):
        if n == 1:
            e_n, de_n = e_cur, de_cur
        else:
            a_next = a_pow * a  # a^(n-1)
            e_n = (n - 1) * e_prev + a_next * lam
            de_n = (n - 1) * de_prev + (n - 1) * a_pow * lam * da + a_next * dlam
            e_prev, e_cur, de_prev, de_cur = e_cur, e_n, de_cur, de_n
            a_pow = a_next
        t = rn * e_n
        dt = n * (rn / -r) * drn * e_n + rn * de_n  # d (-r)^n = n (-r)^(n-1) d(-r)
        c1, c2, c3 = n - 1.0, (n - 1.0) * (n - 2.0) / 2.0, (n - 1.0) * (n - 2.0) * (n - 3.0) / 6.0
        m1 += t
        dm1 += dt
        m2 += c1 * t
        dm2 += c1 * dt
        m3 += c2 * t
        dm3 += c2 * dt
        m4 += c3 * t
        dm4 += c3 * dt
        rn *= -r
    var = m2 - m1 * m1
    dvar = dm2 - 2.0 * m1 * dm1
    mu4 = m4 - 4.0 * m1 * m3 + 6.0 * m1 * m1 * m2 - 3.0 * m1**4
    dmu4 = dm4 - 4.0 * (dm1 * m3 + m1 * dm3) + 6.0 * (2.0 * m1 * dm1 * m2 + m1 * m1 * dm2) - 12.0 * m1**3 * dm1
    z2 = z * z
    out[0], out[1], out[2] = z2 * var, z2 * z2 * (mu4 - 3.0 * var * var), kept
    out[3], out[4], out[5] = z2 * dvar, z2 * z2 * (dmu4 - 6.0 * var * dvar), -phi * da
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _transform(var_lin, base_var, k4_in, has_k4, cut, censored, z0, fb, z_max, near_sigma, nodes, weights,
               var_out, k4_out, fill, with_partials, partials):  # pragma: no cover - compiled
    """Per pixel: far from the end (the disparity error a > -near_sigma of its own standard deviations from it),
    `curvature`'s closed form; near it, `_near`'s quadrature. Returns whether any pixel was near. With
    `with_partials`, fills `partials` (9 x rows, see `range_transform`)."""
    any_near = False
    w_at = np.empty(nodes.size)  # a near pixel's quadrature weights and ranges (and their derivatives), made once
    z_at = np.empty(nodes.size)
    dw_at = np.empty((2, nodes.size))
    dz_at = np.empty((2, nodes.size))
    out = np.empty(9)
    sums = np.empty((5, 2))
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
            if with_partials:
                for r in range(8):
                    partials[r, i] = 0.0
                partials[0, i] = 1.0 + 16.0 * rel
                partials[3, i] = 216.0 * rel * v
                partials[8, i] = 1.0
            continue
        any_near = True
        if not censored and a <= SERIES_MAX_CUT and sigma_d * z / fb <= SERIES_MAX_R:
            r = _series(z, base_var[i], fb, z_max, out)
            var_out[i], k4_out[i], fill[i] = r[0], r[1] + k4, r[2]
            if with_partials:  # uncensored: the base is the variance itself; k4_in passes through, as far from the end
                for row in range(9):
                    partials[row, i] = 0.0
                partials[1, i], partials[4, i], partials[6, i], partials[8, i] = r[3], r[4], r[5], 1.0
            continue
        c = cut[i] if censored else 8.0
        r = _near(z, base_var[i], c, censored, fb, z_max, nodes, weights, w_at, z_at, dw_at, dz_at, with_partials, out, sums)
        var_out[i], k4_out[i], fill[i] = r[0], r[1], r[2]
        if with_partials:  # d/d var_lin: 0 (near the end the quadrature starts again from the base variance)
            partials[0, i], partials[3, i], partials[8, i] = 0.0, 0.0, 0.0
            partials[1, i], partials[4, i], partials[6, i] = r[3], r[4], r[5]
            partials[2, i], partials[5, i], partials[7, i] = r[6], r[7], r[8]
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
    """For N(0,1) truncated to [-c, c] (c >= 0): (fraction kept K = 2 Phi(c) - 1 = erf(c / sqrt 2), E[x^2] =
    1 - 2 c phi(c) / K, E[x^4] = 3 - 2 phi(c) (c^3 + 3 c) / K); one compiled pass (`_truncated`): with scipy's
    ndtr and numpy's temporaries it was 9 of the 80 s of a censoring diagnosis (noisy_confidence, 106x60 px)."""
    c = np.asarray(c, dtype=float)
    flat = np.require(c.reshape(-1), dtype=float, requirements=["C", "W"])
    kept, m2, m4 = np.empty(flat.size), np.empty(flat.size), np.empty(flat.size)
    _truncated(flat, kept, m2, m4)
    return kept.reshape(c.shape), m2.reshape(c.shape), m4.reshape(c.shape)


@njit(cache=True, nogil=True)
def _truncated(c, kept, m2, m4):  # pragma: no cover - compiled
    """`truncated_normal_moments` row by row (erf(c / sqrt 2) is 2 Phi(c) - 1 without its cancellation near 0)."""
    for i in range(c.size):
        x = c[i]
        k = max(math.erf(x / math.sqrt(2.0)), 1e-300)
        phi = math.exp(-0.5 * x * x) / SQRT_2PI
        kept[i] = k
        m2[i] = 1.0 - 2.0 * x * phi / k
        m4[i] = 3.0 - 2.0 * phi * (x * x * x + 3.0 * x) / k
