"""`noise_floor`: disparity noise independent of brightness (matcher / subpixel limit), added in quadrature.

Simulated by the fake camera's `noise_floor` (fakes/effects.py); `scenario` draws what the blind test hides."""

from __future__ import annotations

from ...parts.component import Effect, register
from ...parts.parameters import Param
from ...parts.prediction import EffectStage
from ...parts.tangents import plus


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

    twin = "noise_floor"
    position = 1

    def scenario(self, rng):
        return {"sigma_px": rng.uniform(0.02, 0.05)}

    def apply(self, pred, p, d):
        pred.add(d.disparity_to_range(p.sigma_px ** 2))

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)
        if (i := t.row(self, "sigma_px")) is not None:
            t.var = plus(t.var, t.seeded([(i, d.disparity_to_range(2.0 * p.sigma_px))]))
