"""Range-error models: the paper's sigma_Z = k * Z^lambda, and the physical effects it leaves out.

    from rig.models import ModelData, active, slant_range, noise_floor
    data = ModelData.from_recording("run.h5")
    result = (active + slant_range + noise_floor).fit(data)
    print(result.report())

One concept a module, from the bottom up: `data` (the per-pixel statistics models are fitted
to, with `shape_statistics`, their measured kurtosis), `covariates` (what effects need besides
range), `parameters`, `prediction` (the per-pixel prediction and the stages effects join at),
`component` (what a model is made of: base models, effects, and the registry effects join with
@register), `file_physics` (what the depth format fixes for every model), `likelihood`,
`closed_form` (the paper's estimator), `result` (one fitted-model type, one report), `optimise`
(maximum likelihood for any model), `composition` (`Model`: a base plus effects), `bases` (the
power law), `effects` (the built-in physical effects), `rounding` (exact moments of depth rounded
to its unit), `empirical` (free-form terms), `user_effects` (effects written by the user: @effect,
load_effects), `catalogue` (every effect a model can use, by name), `parse` (models from text)
and `paper_fit` (the paper's fit as a fitted model).

Every built-in effect is here by name, as its instance (`noise_floor`) and its class (`NoiseFloor`),
from the registry (`EFFECTS`): adding one to `rig/models/effects.py` adds it here.
"""

from .bases import BASES, Base, active, fixed_lambda, passive, power_law
from .catalogue import Catalogue
from .closed_form import PowerLawEstimate, power_law_mle
from .component import EFFECTS, BaseModel, Component, Effect, EffectFileError, register
from .composition import Model
from .data import ModelData, load_samples
from .empirical import empirical
from .optimise import fit_model, with_errors, with_exact_loglik
from .paper_fit import fit_power_law
from .parameters import Param
from .parse import parse_model
from .prediction import EffectStage, Prediction
from .result import ModelFit, likelihood_ratio
from .user_effects import Covariates, effect, load_effects

__all__ = [
    "BASES", "Base", "active", "fixed_lambda", "passive", "power_law", "BaseModel", "Component", "Param", "Model",
    "parse_model", "PowerLawEstimate", "power_law_mle", "ModelData", "load_samples", "EFFECTS", "Effect", "register",
    "fit_model", "with_errors", "with_exact_loglik", "fit_power_law", "EffectStage", "Prediction", "ModelFit",
    "likelihood_ratio",
    "Catalogue", "empirical", "Covariates", "EffectFileError", "effect", "load_effects",
]


def _builtin(name: str) -> Effect | type[Effect] | None:
    for e in EFFECTS.values():
        if e.name == name:
            return e
        if type(e).__name__ == name:
            return type(e)
    return None


def __getattr__(name: str) -> Effect | type[Effect]:
    """A built-in effect by name (`noise_floor`) or class (`NoiseFloor`), from the registry."""
    found = _builtin(name)
    if found is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return found


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


__all__ += [name for e in EFFECTS.values() for name in (e.name, type(e).__name__)]
