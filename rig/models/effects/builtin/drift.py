"""`drift`: the mean depth wanders during a stop (warm-up): var += D, measured from the per-frame series. No free
parameter.

Simulated by the fake camera's `drift` (fakes/effects.py); `scenario` draws what the blind test hides."""

from __future__ import annotations

from ...parts.component import Effect, register
from ...parts.prediction import EffectStage
from ...parts.tangents import scale


@register
class Drift(Effect):
    """The mean depth wanders during a stop (warm-up): var += D, measured from the per-frame series. No free parameter."""

    name = "drift"
    stage = EffectStage.DRIFT
    needs = ("drift_var_m2",)
    signature = "the mean depth wanders during a stop: per-pixel variance exceeds the model by what the per-frame series moves"
    explanation = "drift: the camera's depth scale changes during a stop (warm-up), adding the wander to every pixel's variance"

    twin = "drift"
    position = 8

    def scenario(self, rng):
        return {"amplitude_px": rng.uniform(0.05, 0.15), "tau_s": rng.uniform(5.0, 15.0)}

    def applicable(self, d):
        return None if (d.drift_var_m2 > 0).any() else "drift: the per-frame series shows no wander beyond noise"

    def apply(self, pred, p, d):
        pred.add(d.drift_var_m2)
        pred.common_inv2 = pred.common_inv2 + d.drift_var_m2 / d.z_m**4

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)  # a measured wander: its derivative is zero
