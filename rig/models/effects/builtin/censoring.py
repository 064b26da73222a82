"""`censoring`: the camera invalidates matches with a large matching error: the disparity error is truncated at
+-threshold.

Simulated by the fake camera's `censoring` (fakes/effects.py); `scenario` draws what the blind test hides."""

from __future__ import annotations

import math

import numpy as np

from ..file_physics import truncated_normal_moments
from ...parts.component import Effect, register
from ...parts.parameters import Param
from ...parts.prediction import EffectStage
from ...parts.tangents import plus, scale


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

    twin = "censoring"
    position = 9

    def scenario(self, rng):
        return {"threshold_px": rng.uniform(0.15, 0.3)}

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
