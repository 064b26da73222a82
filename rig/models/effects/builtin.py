"""The physical effects the paper's model leaves out: the built-in catalogue, `EFFECTS`.

Each effect is one class here, registered by `@register` (`rig.models.parts.component`): it says where
it joins the prediction (`stage`, see `rig.models.parts.prediction`), its parameters with units and
bounds, the residual pattern it explains (`signature`) and what it means physically
(`explanation`); `apply(pred, p, d)` gets its own parameters as `p` (`p.sigma_px`). Registered,
it composes with a base model (`active + slant_range`; the instance is `rig.models.slant_range`),
parses (`--model active+slant_range`) and is a candidate of the diagnosis. Nothing else to edit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..parts.component import EFFECTS, Effect, register, registered_by
from ..data.model_data import ModelData
from .file_physics import MAX_DEPTH_UNITS, truncated_normal_moments
from ..parts.parameters import Param
from ..parts.prediction import EffectStage
from ..data.rounding import expected_sample_variance
from ..parts.tangents import plus, scale

__all__ = ["EFFECTS", "Effect", "register"]


def _need_projector(d: ModelData, what: str) -> str | None:
    return None if d.projector_on.any() else f"{what} needs the projector on (it changes the projected light)"


@register
class NoiseFloor(Effect):
    """Disparity noise independent of brightness (matcher / subpixel limit), added in quadrature.

    var_Z += (Z^2 / (f b))^2 sigma_px^2 (eq. error_prop_unassisted): it grows as Z^2 in range.
    """

    name = "noise_floor"
    stage = EffectStage.DISPARITY
    params = (Param("sigma_px", 0.01, 0.0, 5.0, "px", "disparity noise floor (RMS)"),)
    signature = "the measured error exceeds k Z^lambda most at short range, where the projected light is brightest"
    explanation = "a noise floor in disparity that does not depend on brightness (the matcher's subpixel limit)"

    def apply(self, pred, p, d):
        pred.add(d.disparity_to_range(p.sigma_px ** 2))

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)
        if (i := t.row(self, "sigma_px")) is not None:
            t.var = plus(t.var, t.seeded([(i, d.disparity_to_range(2.0 * p.sigma_px))]))


@register
class ReadNoise(Effect):
    """Sensor read noise, independent of light, added to the photon noise of the image.

    var_shot *= 1 + r^2 / I with I the pattern's photo-electrons; with the projector on
    I ~ 1 / (Z^2 h) (h: other illumination losses), so the term is ratio_at_1m * Z^2 * h.
    """

    name = "read_noise"
    stage = EffectStage.IMAGE_NOISE
    params = (Param("ratio_at_1m", 0.05, 0.0, 1e3, "1", "read-noise variance / pattern shot-noise variance at 1 m on axis"),)
    signature = "the error grows faster than k Z^lambda at long range, where the projected light is faint"
    explanation = "sensor read noise: noise that does not fall with the light, so its share grows as the pattern fades"

    def applicable(self, d):
        return _need_projector(d, "read_noise") or None

    def apply(self, pred, p, d):
        term = p.ratio_at_1m * d.z0_m**2 * pred.illum
        pred.image_terms = pred.image_terms + np.where(d.projector_on, term, 0.0)

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)
        z2_on = np.where(d.projector_on, d.z0_m**2, 0.0)
        own = [(i, z2_on * pred.illum)] if (i := t.row(self, "ratio_at_1m")) is not None else []
        t.image = plus(t.image, scale(t.illum, p.ratio_at_1m * z2_on), t.seeded(own))


@register
class Ambient(Effect):
    """Ambient light adds photon noise but no pattern contrast: var_shot *= 1 + A / P.

    A / P (ambient over pattern brightness) is measured per pixel from the frames captured with
    the projector off; no free parameter.
    """

    name = "ambient"
    stage = EffectStage.IMAGE_NOISE
    needs = ("ambient_ratio",)
    signature = "the error is larger where the ambient light (measured with the projector off) is strong against the pattern"
    explanation = "ambient light: it adds photon noise to the image but no pattern contrast to match on"

    def applicable(self, d):
        if not np.isfinite(d.ambient_ratio).any():
            return "ambient needs frames with the projector off at each stop (capture them with ambient_frames > 0)"
        return _need_projector(d, "ambient")

    def apply(self, pred, p, d):
        r = np.where(np.isfinite(d.ambient_ratio) & d.projector_on, d.ambient_ratio, 0.0)
        pred.image_terms = pred.image_terms + r

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)  # a measured term: its derivative is zero


@register
class SlantRange(Effect):
    """The projected light falls with the slant range r along each ray, not with Z.

    I ~ 1/r^2 = 1 / (Z^2 (1 + rho^2)), rho^2 = ((u-cx)/fx)^2 + ((v-cy)/fy)^2 (paper, "Further
    effects"), so the shot variance is multiplied by 1 + rho^2. No free parameter.
    """

    name = "slant_range"
    stage = EffectStage.ILLUMINATION
    signature = "the error grows with distance from the image centre"
    explanation = "the illumination falls with the slant range along each pixel's ray, not with Z"

    def applicable(self, d):
        return _need_projector(d, "slant_range")

    def apply(self, pred, p, d):
        pred.illum = pred.illum * np.where(d.projector_on, 1.0 + d.rho2, 1.0)

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)
        t.illum = scale(t.illum, np.where(d.projector_on, 1.0 + d.rho2, 1.0))


@register
class Incidence(Effect):
    """A matte wall returns the projected light as cos(incidence): the shot variance is divided by it.

    The angle is between each pixel's ray and the normal of a plane fitted to the stop's mean depth. No free parameter.
    """

    name = "incidence"
    stage = EffectStage.ILLUMINATION
    signature = "the error grows with the angle at which the rays meet the wall"
    explanation = "the wall returns the projected light as the cosine of the incidence angle (a matte surface)"

    def applicable(self, d):
        return _need_projector(d, "incidence")

    def apply(self, pred, p, d):
        pred.illum = pred.illum * np.where(d.projector_on, 1.0 / np.clip(d.cos_inc, 0.05, 1.0), 1.0)

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)
        t.illum = scale(t.illum, np.where(d.projector_on, 1.0 / np.clip(d.cos_inc, 0.05, 1.0), 1.0))


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


@register
class Quantization(Effect):
    """Rounding to the depth unit q (and to the matcher's disparity step, if given).

    Exactly, whatever the noise against q (`rig.models.data.rounding`): a pixel's rounded samples have
    the variance and fourth moment of a rounded normal whose true mean sits where the pixel's
    measured mean says it does between two depth levels: from 0 to q^2 / 4 when the noise is
    below q, q^2 / 12 more than the noise (Sheppard's correction) when it is well above. A
    disparity step s adds s^2 / 12 in disparity. The depth unit comes from the recording, so
    there is no free parameter.
    """

    name = "quantization"
    stage = EffectStage.QUANTIZE
    by_grid_offset = True  # its prediction turns on each pixel's own place on the depth grid (rig.models.fitting.grouping)
    params = (Param("step_px", 0.0, 0.0, 1.0, "px", "disparity step of the matcher (0: continuous)", vary=False),)
    signature = "the error levels off at short range near the size of the depth unit"
    explanation = ("quantization: depth is rounded to the depth unit (and disparity to the matcher's step), "
                   "adding q^2/12, or less for a noise below the unit")

    def apply(self, pred, p, d, t=None):
        q = d.depth_unit_m
        var_in, k4_step = pred.var_m2, 0.0
        if p.step_px:  # the matcher's step in range, m^2; none (the default) adds nothing: no pass over the pixels
            step2 = d.disparity_to_range(p.step_px ** 2)
            var_in, k4_step = var_in + step2 / 12, (step2**2) / 120
        s = np.sqrt(var_in) / q
        var_u, mu4_u = expected_sample_variance(s, d.grid_offset, d.n)
        k4_rounding = (mu4_u - 3 * var_u**2) * q**4 - k4_step
        pred.var_m2 = var_u * q**2
        pred.k4_m4 = k4_rounding if pred.k4_m4 is None else pred.k4_m4 + k4_rounding
        if t is None:
            return
        # d/ds of the rounded moments (a table and its blend, `rig.models.data.rounding`): central differences of each
        # row's own value; ds = d var_in / (2 s q^2); the step is fixed (no parameter of this effect is fitted)
        h = 1e-6 * s
        vp, mp = expected_sample_variance(s + h, d.grid_offset, d.n)
        vm, mm = expected_sample_variance(s - h, d.grid_offset, d.n)
        ds_dvar = 1.0 / (2.0 * s * q * q)
        dv = (vp - vm) / (2 * h) * q**2 * ds_dvar
        dk = ((mp - mm) - 3 * (vp**2 - vm**2)) / (2 * h) * q**4 * ds_dvar
        t.k4 = plus(t.k4, scale(t.var, dk))
        t.var = scale(t.var, dv)

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d, t)


@register
class Drift(Effect):
    """The mean depth wanders during a stop (warm-up): var += D, measured from the per-frame series. No free parameter."""

    name = "drift"
    stage = EffectStage.DRIFT
    needs = ("drift_var_m2",)
    signature = "the mean depth wanders during a stop: per-pixel variance exceeds the model by what the per-frame series moves"
    explanation = "drift: the camera's depth scale changes during a stop (warm-up), adding the wander to every pixel's variance"

    def applicable(self, d):
        return None if (d.drift_var_m2 > 0).any() else "drift: the per-frame series shows no wander beyond noise"

    def apply(self, pred, p, d):
        pred.add(d.drift_var_m2)
        pred.common_inv2 = pred.common_inv2 + d.drift_var_m2 / d.z_m**4

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)  # a measured wander: its derivative is zero


@register
class Censoring(Effect):
    """The camera invalidates matches with a large matching error: the disparity error is truncated at +-threshold.

    With c = threshold / sigma_d: var *= E[x^2 | |x| < c], fill = 2 Phi(c) - 1, and the
    distribution becomes lighter-tailed (a truncated normal).
    """

    name = "censoring"
    stage = EffectStage.CENSOR
    params = (Param("threshold_px", 0.3, 0.005, 20.0, "px", "largest disparity error the camera keeps"),)
    signature = "the error grows slower than k Z^lambda at long range while the fill rate falls"
    explanation = "censoring: the camera discards the matches it is least sure of, so at long range the worst samples are missing"

    def start(self, d, pred):
        sigma_d = np.sqrt(pred.var_m2) * d.fb_px_m / d.z0_m**2
        return {"threshold_px": float(2.0 * np.quantile(sigma_d, 0.95))}

    def apply(self, pred, p, d):
        sigma_d = np.sqrt(pred.var_m2) * d.fb_px_m / d.z0_m**2
        c = p.threshold_px / sigma_d
        kept, m2, m4 = truncated_normal_moments(c)
        var = pred.var_m2
        k4_old = pred.k4_m4 if pred.k4_m4 is not None else 0.0
        pred.var_m2 = var * m2
        pred.k4_m4 = var**2 * (m4 - 3 * m2**2) + k4_old * m2**2
        pred.fill = kept
        pred.censor = (c, var)  # the cut and the variance before it, for the exact range transform near the format's end
        return c, kept, m2, m4

    def apply_tangent(self, pred, p, d, t):
        var, dvar, dk4_old = pred.var_m2, t.var, t.k4
        k4_old = pred.k4_m4 if pred.k4_m4 is not None else 0.0
        c, kept, m2, m4 = self.apply(pred, p, d)  # the cut and its moments, computed once
        # c = T / sigma_d, sigma_d ~ sqrt(var): dc = c (dT / T - dvar / (2 var)); with K = 2 Phi(c) - 1 and
        # phi the normal density, dK/dc = 2 phi, dm2/dc = -2 phi ((1 - c^2) K - 2 c phi) / K^2,
        # dm4/dc = -2 phi ((3 - c^4) K - 2 (c^3 + 3 c) phi) / K^2 (`truncated_normal_moments`)
        phi = np.exp(-0.5 * c * c) / math.sqrt(2 * math.pi)
        dm2 = -2 * phi * ((1 - c * c) * kept - 2 * c * phi) / kept**2
        dm4 = -2 * phi * ((3 - c**4) * kept - 2 * (c**3 + 3 * c) * phi) / kept**2
        i = t.row(self, "threshold_px")
        dc = plus(scale(dvar, -0.5 * c / var), t.seeded([(i, c / p.threshold_px)] if i is not None else []))
        t.var = plus(scale(dvar, m2), scale(dc, var * dm2))
        t.k4 = plus(scale(dvar, 2 * var * (m4 - 3 * m2**2)), scale(dc, var**2 * (dm4 - 6 * m2 * dm2) + 2 * k4_old * m2 * dm2),
                    scale(dk4_old, m2**2))
        t.fill = scale(dc, 2 * phi)
        t.censor = (dc, dvar)


def __getattr__(name: str) -> Effect:
    """The built-in effects' instances by name: `rig.models.effects.builtin.noise_floor` (one per registered class)."""
    for e in registered_by(__name__):
        if e.name == name:
            return e
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
