"""Range-error models: the paper's sigma_Z = k * Z^lambda, and the physical effects it leaves out.

    from rig.models import ModelData, active, slant_range, noise_floor
    data = ModelData.from_recording("run.h5")
    result = (active + slant_range + noise_floor).fit(data)
    print(result.report())

One concept a module, from the bottom up: `data` (the per-pixel statistics models are fitted
to, and their likelihood), `covariates` (what effects need besides range), `parameters`,
`prediction` (the per-pixel prediction and the stages effects join at), `file_physics` (what
the depth format fixes for every model), `closed_form` (the paper's estimator), `result` (one
fitted-model type, one report), `optimise` (maximum likelihood for any model), `composition`
(components and `base + effect`), `bases` (the power law), `effects` (the built-in physical
effects), `rounding` (exact moments of depth rounded to its unit), `empirical` (free-form terms),
`user_effects` (effects written by the user: @effect, load_effects), `catalogue` (every effect a
model can use, by name), `parse` (models from text) and `paper_fit` (the paper's fit as a fitted
model).
"""

from .bases import BASES, Base, active, fixed_lambda, passive, power_law
from .catalogue import Catalogue
from .closed_form import PowerLawEstimate, power_law_mle
from .composition import Component, Model
from .data import ModelData, load_samples
from .effects import (
                      EFFECTS,
                      Ambient,
                      Censoring,
                      Drift,
                      Effect,
                      Incidence,
                      NoiseFloor,
                      Outliers,
                      Quantization,
                      ReadNoise,
                      SlantRange,
                      ambient,
                      censoring,
                      drift,
                      incidence,
                      noise_floor,
                      outliers,
                      quantization,
                      read_noise,
                      slant_range,
)
from .empirical import empirical
from .optimise import fit_model, with_errors
from .paper_fit import fit_power_law
from .parameters import Param
from .parse import parse_model
from .prediction import EffectStage, Prediction
from .result import ModelFit, likelihood_ratio
from .user_effects import Covariates, EffectFileError, effect, load_effects

__all__ = [
    "BASES", "Base", "active", "fixed_lambda", "passive", "power_law", "Component", "Param", "Model", "parse_model", "PowerLawEstimate", "power_law_mle",
    "ModelData", "load_samples", "EFFECTS", "Effect", "Ambient", "Censoring", "Drift", "Incidence", "NoiseFloor",
    "Outliers", "Quantization", "ReadNoise", "SlantRange", "ambient", "censoring", "drift", "incidence", "noise_floor",
    "outliers", "quantization", "read_noise", "slant_range", "fit_model", "with_errors", "fit_power_law", "EffectStage", "Prediction",
    "ModelFit", "likelihood_ratio", "Catalogue", "empirical", "Covariates", "EffectFileError", "effect", "load_effects",
]
