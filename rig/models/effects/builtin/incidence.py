"""`incidence`: a matte wall returns the projected light as cos(incidence): the shot variance is divided by it.

Simulated by the fake camera's `incidence` (fakes/effects.py); `scenario` draws what the blind test hides."""

from __future__ import annotations

import numpy as np

from ..projector import need_projector
from ...parts.component import Effect, register
from ...parts.prediction import EffectStage
from ...parts.tangents import scale


@register
class Incidence(Effect):
    """A matte wall returns the projected light as cos(incidence): the shot variance is divided by it.

    The angle is between each pixel's ray and the normal of a plane fitted to the stop's mean depth. No free parameter.
    """

    name = "incidence"
    stage = EffectStage.ILLUMINATION
    signature = "the error grows with the angle at which the rays meet the wall"
    explanation = "the wall returns the projected light as the cosine of the incidence angle (a matte surface)"

    twin = "incidence"
    position = 5

    def scenario(self, rng):
        return {}

    def applicable(self, d):
        return need_projector(d, "incidence")

    def apply(self, pred, p, d):
        pred.illum = pred.illum * np.where(d.projector_on, 1.0 / np.clip(d.cos_inc, 0.05, 1.0), 1.0)

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)
        t.illum = scale(t.illum, np.where(d.projector_on, 1.0 / np.clip(d.cos_inc, 0.05, 1.0), 1.0))
