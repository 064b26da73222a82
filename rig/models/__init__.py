"""Range-error models: the paper's sigma_Z = k * Z^lambda, and the physical effects it leaves out.

    from rig.models import ModelData, active, slant_range, noise_floor
    data = ModelData.from_recording("run.h5")
    result = (active + slant_range + noise_floor).fit(data)
    print(result.report())

Four subpackages, from the bottom up, and the model algebra on top of them:

- `data`: what the data are: `ModelData` (the per-pixel statistics models are fitted to) read from a recording
  (`loading`), the covariates effects need besides range, order statistics, checks of stops and of the frames'
  independence, the measured kurtosis (`shape_statistics`), and the exact moments of depth rounded to its unit
  (`rounding`, `rounding_table`);
- `parts`: what every model is made of: `Param`, the components (`BaseModel`, `Effect`) and the registry effects
  join with @register, the per-pixel `Prediction` and the stages effects join at, its derivatives (`tangents`),
  one fitted-model type with one report (`result`);
- `fitting`: the likelihood and its gradient, maximum likelihood for any model (`optimise`), grouped nodes for
  large data, the paper's closed-form estimator, when to stop;
- `effects`: the built-in physical effects (`builtin/`, one module each), the free-form empirical shapes, effects
  written as a term of the covariates (`TermEffect`, load_effects) and what the depth format fixes for every model (`file_physics`);
- on top: `composition` (`Model`: a base plus effects), `bases` (the power law), `catalogue` (every effect a model
  can use, by name), `parse` (models from text), `paper_fit` (the paper's fit as a fitted model), `parallel`
  (fits in worker processes) and `export` (a fit as a file, `rig.noise-model/1`).

Every built-in effect is here by name, as its instance (`noise_floor`) and its class (`NoiseFloor`),
from the registry (`EFFECTS`).
"""

from .bases import BASES, Base, active, fixed_lambda, passive, power_law
from .catalogue import Catalogue
from .composition import Model
from .data.model_data import ModelData, load_samples
from .effects.empirical import empirical
from .effects.user_effects import Covariates, TermEffect, load_effects
from .fitting.closed_form import PowerLawEstimate, power_law_mle
from .fitting.information import undetermined
from .fitting.optimise import fit_model, with_errors, with_exact_loglik
from .paper_fit import fit_power_law
from .parse import parse_model
from .parts.component import EFFECTS, BaseModel, Component, Effect, EffectFileError, register
from .parts.parameters import Param
from .parts.prediction import EffectStage, Prediction
from .parts.result import ModelFit, likelihood_ratio

__all__ = [
    "BASES", "Base", "active", "fixed_lambda", "passive", "power_law", "BaseModel", "Component", "Param", "Model",
    "parse_model", "PowerLawEstimate", "power_law_mle", "ModelData", "load_samples", "EFFECTS", "Effect", "register",
    "fit_model", "undetermined", "with_errors", "with_exact_loglik", "fit_power_law", "EffectStage", "Prediction", "ModelFit",
    "likelihood_ratio",
    "Catalogue", "empirical", "Covariates", "EffectFileError", "TermEffect", "load_effects",
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
