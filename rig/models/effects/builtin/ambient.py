"""`ambient`: ambient light adds photon noise but no pattern contrast: var_shot *= 1 + A / P.

Simulated by the fake camera's `ambient` (fakes/effects.py); `scenario` draws what the blind test hides."""

from __future__ import annotations

import numpy as np

from ..projector import need_projector
from ...parts.component import Effect, register
from ...parts.prediction import EffectStage


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

    twin = "ambient"
    position = 3

    def scenario(self, rng):
        return {"ambient_e_per_ms": rng.uniform(10.0, 40.0)}

    def applicable(self, d):
        if not np.isfinite(d.ambient_ratio).any():
            return "ambient needs frames with the projector off at each stop (capture them with ambient_frames > 0)"
        return need_projector(d, "ambient")

    def apply(self, pred, p, d):
        r = np.where(np.isfinite(d.ambient_ratio) & d.projector_on, d.ambient_ratio, 0.0)
        pred.image_terms = pred.image_terms + r

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)  # a measured term: its derivative is zero
