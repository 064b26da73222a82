"""`quantization`: rounding to the depth unit q (and to the matcher's disparity step, if given).

Simulated by the recording's own depth unit; `scenario` draws what the blind test hides."""

from __future__ import annotations

import numpy as np

from ...data.rounding import expected_sample_variance
from ...parts.component import Effect, register
from ...parts.parameters import Param
from ...parts.prediction import EffectStage
from ...parts.tangents import plus, scale


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

    twin = None  # the recording's own depth unit simulates it (rig.simulation.scenarios)
    position = 7

    def scenario(self, rng):
        return {"depth_unit_mm": rng.uniform(0.3, 0.6)}

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
