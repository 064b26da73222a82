"""A per-pixel prediction, built stage by stage, and the stages at which effects join it.

Effects join at fixed stages, whatever order they are written in, so adding one never
requires changing another (see `rig.models.composition.Model.predict`):

  base          shot-noise variance k^2 Z^(2 lambda)          (paper, eq. error_prop_*)
  ILLUMINATION  multiply it: the light falls faster than 1/Z^2 at some pixels
  IMAGE_NOISE   add image noise relative to the pattern's shot noise: var *= 1 + terms
  DISPARITY     add disparity noise independent of light
  DRIFT         add the variance of the stop's mean over time
  CENSOR        truncate the disparity error (the camera drops unconfident matches)
  (all models)  the deepest range the depth format holds, and the curvature of Z = f b / d
  QUANTIZE      add rounding: q^2 / 12
  OUTLIERS      mix in uniform mismatches
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np


class EffectStage(IntEnum):
    """Where an effect joins the prediction (see the module docstring)."""

    ILLUMINATION = 10
    IMAGE_NOISE = 20
    DISPARITY = 30
    DRIFT = 40
    CENSOR = 50
    QUANTIZE = 60
    OUTLIERS = 70


@dataclass
class Prediction:
    """Per-pixel prediction, built stage by stage."""

    shot_m2: np.ndarray  # shot-noise variance of the base model
    illum: np.ndarray  # multiplier of the shot variance from illumination effects (1 / relative light)
    image_terms: np.ndarray  # image noise relative to the pattern's shot noise
    var_m2: np.ndarray | None = None
    k4_m4: np.ndarray | None = None  # fourth cumulant; None = normal
    fill: np.ndarray | None = None  # predicted fraction of frames with a valid sample

    def add(self, var_m2: np.ndarray | float, k4_m4: np.ndarray | float | None = None) -> None:
        """Add an independent component of variance (and fourth cumulant)."""
        self.var_m2 = self.var_m2 + var_m2
        if k4_m4 is not None:
            self.k4_m4 = (self.k4_m4 if self.k4_m4 is not None else 0.0) + k4_m4
