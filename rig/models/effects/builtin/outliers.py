"""`outliers`: mismatches: a fraction of samples is uniform within +-width_px of the true disparity (Gaussian + uniform
mixture).

Simulated by the fake camera's `outliers` (fakes/effects.py); `scenario` draws what the blind test hides."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..file_physics import MAX_DEPTH_UNITS
from ...parts.component import Effect, register
from ...parts.parameters import Param
from ...parts.prediction import EffectStage
from ...parts.tangents import plus, scale


@register
class Outliers(Effect):
    """Mismatches: a fraction of samples is uniform within +-width_px of the true disparity (Gaussian + uniform mixture).

    An outlier's range is Z_o = f b / (d0 + u), u uniform on [-w, w], d0 = f b / Z, so exactly
    E[Z_o] = f b ln((d0 + w) / (d0 - w)) / (2 w) and E[Z_o^2] = (f b)^2 / (d0^2 - w^2) (eq. dist_to_disp).
    Mixture about its mean: var = (1 - f) (var0 + (Z - m)^2) + f (var_o + (E[Z_o] - m)^2),
    m = (1 - f) Z + f E[Z_o]. The fourth moment uses the linearised outlier spread a = w Z^2 / (f b):
    E[x^4] = (1 - f) (3 var0^2 + k4) + f a^4 / 5, scaled to the exact variance. Outliers beyond
    the deepest range the depth format can hold (65535 depth units) are missing, not recorded.
    """

    name = "outliers"
    stage = EffectStage.OUTLIERS
    params = (
        Param("fraction", 0.005, 0.0, 0.5, "1", "fraction of samples that are mismatches"),
        Param("width_px", 1.0, 0.01, 50.0, "px", "half-width of the mismatch distribution"),
    )
    signature = "the errors are heavy-tailed: pixel variances scatter more than a normal distribution allows (kurtosis above 3)"
    explanation = "outliers: occasional mismatches far from the true disparity (the paper's kurtosis of 4-8)"

    twin = "outliers"
    position = 6

    def scenario(self, rng):
        return {"fraction": rng.uniform(0.005, 0.03), "width_px": rng.uniform(0.2, 0.6)}

    def apply(self, pred, p, d, t=None):
        f, w = p.fraction, p.width_px
        z = np.asarray(d.z0_m, dtype=np.float64)
        var0 = np.broadcast_to(np.asarray(pred.var_m2, dtype=np.float64), z.shape)
        k40 = np.broadcast_to(np.asarray(0.0 if pred.k4_m4 is None else pred.k4_m4, dtype=np.float64), z.shape)
        partials = np.empty((9, z.size) if t is not None else (9, 1))
        var, k4, kept_fill = _outlier_mixture(z, var0, k40, float(f), float(w), float(d.fb_px_m),
                                              float(MAX_DEPTH_UNITS * d.depth_unit_m), t is not None, partials)
        fill_before = pred.fill if pred.fill is not None else 1.0
        pred.fill = fill_before * kept_fill
        pred.var_m2 = var
        pred.k4_m4 = k4
        if t is None:
            return
        # partials: d (var, k4, kept) / d var0, d f, d w; d k4 / d k40 (`_outlier_mixture`)
        dv_v, dv_f, dv_w, dk_v, dk_f, dk_w, dkept_f, dkept_w, dk_k4 = partials
        i_f, i_w = t.row(self, "fraction"), t.row(self, "width_px")
        own_var = t.seeded([(i, x) for i, x in ((i_f, dv_f), (i_w, dv_w)) if i is not None])
        own_k4 = t.seeded([(i, x) for i, x in ((i_f, dk_f), (i_w, dk_w)) if i is not None])
        own_kept = t.seeded([(i, x) for i, x in ((i_f, dkept_f), (i_w, dkept_w)) if i is not None])
        t.fill = plus(scale(t.fill, kept_fill), scale(own_kept, fill_before))
        t.k4 = plus(scale(t.var, dk_v), scale(t.k4, dk_k4), own_k4)
        t.var = plus(scale(t.var, dv_v), own_var)

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d, t)


@njit(cache=True, nogil=True, inline="always")
def _outlier_row(zi, v0, k40, f_all, w, fb, deepest_m, dv0, df_all, dw):  # pragma: no cover - compiled
    """Outliers.apply's formulas (its docstring) for one pixel: (variance, fourth cumulant, share of samples
    kept), their derivatives along the direction (dv0, df_all, dw) in (var0, fraction, width_px), by the
    chain rule through each line, and d k4 / d k40 = (1 - f) (var / var_lin)^2 (k40 enters m4_lin linearly,
    and nothing else). Mismatches beyond the deepest range the depth format holds (65535 units)
    read as no data."""
    d0 = fb / zi
    a = max(-w, fb / deepest_m - d0)
    da = -dw if -w >= fb / deepest_m - d0 else 0.0
    u_lo, du = (a, da) if a < w - 1e-9 else (w - 1e-9, dw)
    span, dspan = w - u_lo, dw - du
    log_ratio = math.log((d0 + w) / (d0 + u_lo))
    dlog = dw / (d0 + w) - du / (d0 + u_lo)
    mean_o = fb * log_ratio / span
    dmean_o = fb * (dlog * span - log_ratio * dspan) / (span * span)
    inv = 1.0 / (d0 + u_lo) - 1.0 / (d0 + w)
    dinv = -du / (d0 + u_lo) ** 2 + dw / (d0 + w) ** 2
    e2 = fb * fb * inv / span
    de2 = fb * fb * (dinv * span - inv * dspan) / (span * span)
    var_o, dvar_o = e2 - mean_o * mean_o, de2 - 2.0 * mean_o * dmean_o
    kept = span / (2.0 * w)
    dkept = (dspan * w - span * dw) / (2.0 * w * w)
    kept_all = 1.0 - f_all + f_all * kept
    dkept_all = df_all * (kept - 1.0) + f_all * dkept
    f = f_all * kept / kept_all
    df = (df_all * kept + f_all * dkept) / kept_all - f * dkept_all / kept_all
    w_eff, dw_eff = span / 2.0, dspan / 2.0
    m = (1.0 - f) * zi + f * mean_o
    dm = df * (mean_o - zi) + f * dmean_o
    var = (1.0 - f) * (v0 + (zi - m) ** 2) + f * (var_o + (mean_o - m) ** 2)
    dvar = (-df * (v0 + (zi - m) ** 2) + (1.0 - f) * (dv0 - 2.0 * (zi - m) * dm)
            + df * (var_o + (mean_o - m) ** 2) + f * (dvar_o + 2.0 * (mean_o - m) * (dmean_o - dm)))
    c = (zi * zi / fb) ** 2
    a2, da2 = c * w_eff * w_eff, 2.0 * c * w_eff * dw_eff  # disparity_to_range(w_eff^2): (Z^2 / (f b))^2 var_d
    m4_lin = (1.0 - f) * (3.0 * v0 * v0 + k40) + f * a2 * a2 / 5.0
    dm4_lin = -df * (3.0 * v0 * v0 + k40) + (1.0 - f) * 6.0 * v0 * dv0 + df * a2 * a2 / 5.0 + f * 2.0 * a2 * da2 / 5.0
    var_lin = (1.0 - f) * v0 + f * a2 / 3.0
    dvar_lin = -df * v0 + (1.0 - f) * dv0 + df * a2 / 3.0 + f * da2 / 3.0
    r = var / var_lin
    dr = (dvar - r * dvar_lin) / var_lin
    k4 = m4_lin * r * r - 3.0 * var * var
    dk4 = dm4_lin * r * r + 2.0 * m4_lin * r * dr - 6.0 * var * dvar
    return var, k4, kept_all, dvar, dk4, dkept_all, (1.0 - f) * r * r


@njit(cache=True, nogil=True)
def _outlier_mixture(z, var0, k40, f_all, w, fb, deepest_m, with_partials, partials):  # pragma: no cover - compiled
    """`_outlier_row` pixel by pixel in one pass: (variance, fourth cumulant, share kept). With `with_partials`,
    fills `partials` (9 x pixels): d (var, k4, kept) / d var0, d fraction, d width and d k4 / d k40, all from the
    row's own chain rule (`_outlier_row`)."""
    n = z.shape[0]
    var_out, k4_out, kept_out = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        zi, v0, k4i = z[i], var0[i], k40[i]
        var, k4, kept, dv, dk, _, dk_k40 = _outlier_row(zi, v0, k4i, f_all, w, fb, deepest_m, 1.0, 0.0, 0.0)
        var_out[i], k4_out[i], kept_out[i] = var, k4, kept
        if not with_partials:
            continue
        partials[0, i], partials[3, i], partials[8, i] = dv, dk, dk_k40
        _, _, _, dv, dk, de, _ = _outlier_row(zi, v0, k4i, f_all, w, fb, deepest_m, 0.0, 1.0, 0.0)
        partials[1, i], partials[4, i], partials[6, i] = dv, dk, de
        _, _, _, dv, dk, de, _ = _outlier_row(zi, v0, k4i, f_all, w, fb, deepest_m, 0.0, 0.0, 1.0)
        partials[2, i], partials[5, i], partials[7, i] = dv, dk, de
    return var_out, k4_out, kept_out
