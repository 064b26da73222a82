"""`slant_range`: the projected light falls with the slant range r along each ray, not with Z.

Simulated by the fake camera's `slant_range` (fakes/effects.py); `scenario` draws what the blind test hides."""

from __future__ import annotations

import numpy as np

from ..projector import need_projector
from ...parts.component import Effect, register
from ...parts.prediction import EffectStage
from ...parts.tangents import scale


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

    twin = "slant_range"
    position = 4

    def scenario(self, rng):
        return {}

    def applicable(self, d):
        return need_projector(d, "slant_range")

    def apply(self, pred, p, d):
        pred.illum = pred.illum * np.where(d.projector_on, 1.0 + d.rho2, 1.0)

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)
        t.illum = scale(t.illum, np.where(d.projector_on, 1.0 + d.rho2, 1.0))
