"""`read_noise`: sensor read noise, independent of light, added to the photon noise of the image.

Simulated by the fake camera's `read_noise` (fakes/effects.py); `scenario` draws what the blind test hides."""

from __future__ import annotations

import numpy as np

from ..projector import need_projector
from ...parts.component import Effect, register
from ...parts.parameters import Param
from ...parts.prediction import EffectStage
from ...parts.tangents import plus, scale


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

    twin = "read_noise"
    position = 2

    def scenario(self, rng):
        return {"read_e": rng.uniform(8.0, 20.0)}

    def applicable(self, d):
        return need_projector(d, "read_noise") or None

    def apply(self, pred, p, d):
        term = p.ratio_at_1m * d.z0_m**2 * pred.illum
        pred.image_terms = pred.image_terms + np.where(d.projector_on, term, 0.0)

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)
        z2_on = np.where(d.projector_on, d.z0_m**2, 0.0)
        own = [(i, z2_on * pred.illum)] if (i := t.row(self, "ratio_at_1m")) is not None else []
        t.image = plus(t.image, scale(t.illum, p.ratio_at_1m * z2_on), t.seeded(own))
