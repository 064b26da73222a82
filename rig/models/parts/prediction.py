"""A per-pixel prediction, built stage by stage, and the stages at which effects join it.

Effects join at fixed stages, whatever order they are written in, so adding one never
requires changing another (see `rig.models.composition.Model.predict`):

  base          shot-noise variance k^2 Z^(2 lambda)          (paper, eq. error_prop_*)
  ILLUMINATION  multiply it: the light falls faster than 1/Z^2 at some pixels
  IMAGE_NOISE   add image noise relative to the pattern's shot noise: var *= 1 + terms
  DISPARITY     add disparity noise independent of light
  DRIFT         add the variance of the stop's mean over time
  EMPIRICAL     multiply the variance by a free-form shape (rig.models.effects.empirical)
  CENSOR        truncate the disparity error (the camera drops unconfident matches)
  (all models)  the deepest range the depth format holds, and the curvature of Z = f b / d
  QUANTIZE      round to the depth unit
  OUTLIERS      mix in uniform mismatches
  TAILS         change the tails, the frame mean's or the fill rate's shape, measured or free-form
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
    EMPIRICAL = 45
    CENSOR = 50
    QUANTIZE = 60
    OUTLIERS = 70
    TAILS = 80


@dataclass
class Prediction:
    """Per-pixel prediction, built stage by stage."""

    shot_m2: np.ndarray  # shot-noise variance of the base model
    illum: np.ndarray  # multiplier of the shot variance from illumination effects (1 / relative light)
    image_terms: np.ndarray  # image noise relative to the pattern's shot noise
    var_m2: np.ndarray | None = None
    k4_m4: np.ndarray | None = None  # fourth cumulant; None = normal
    fill: np.ndarray | None = None  # predicted fraction of frames with a valid sample
    #: variance over frames of a wander common to all pixels of a stop, in (1/m)^2 of 1/Z (drift); the
    #: per-frame series measures it (rig.models.data.model_data.StopTable.series_var_inv2)
    common_inv2: np.ndarray | float = 0.0
    #: the variance over frames of the frame's mean, against what independent pixels give (1: independent)
    frame_mean_gain: np.ndarray | float = 1.0
    #: censoring's cut (in standard deviations of the disparity error) and the variance before it, if censored
    censor: tuple[np.ndarray, np.ndarray] | None = None

    def add(self, var_m2: np.ndarray | float, k4_m4: np.ndarray | float | None = None) -> None:
        """Add an independent component of variance (and fourth cumulant)."""
        self.var_m2 = self.var_m2 + var_m2
        if k4_m4 is not None:
            self.k4_m4 = (self.k4_m4 if self.k4_m4 is not None else 0.0) + k4_m4
