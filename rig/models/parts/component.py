"""What a model is made of: a base model and effects (`Component`), and the registry effects join.

    @register
    class NoiseFloor(Effect):
        name = "noise_floor"
        stage = EffectStage.DISPARITY
        params = (Param("sigma_px", 0.01, 0.0, 5.0, "px", "disparity noise floor (RMS)"),)
        ...
        def apply(self, pred, p, d):
            pred.add(d.disparity_to_range(p.sigma_px ** 2))   # p: this effect's own parameters

`@register` makes the one instance of the class and registers it by name, where the class is
defined: rig's own modules fill the built-in catalogue (`EFFECTS`), any other module (a file
passed with `--effects`, a test) its own list (`registered_by`). A name registered twice in one
place is an error naming both definitions. `apply` gets its parameters as a named tuple (`own`),
never as string keys into the model's shared dictionary of values.

`ComposedModel` is what fitting and results need of a model (`rig.models.composition.Model` is
one), named here so that the modules below composition refer to it without importing it.
"""

from __future__ import annotations

import sys
from collections import namedtuple
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

from ...runtime.effect_errors import EffectFileError
from .parameters import Param
from .prediction import EffectStage, Prediction

if TYPE_CHECKING:
    import numpy as np

    from ..data.model_data import ModelData


class Component:
    """Base models and effects: a name, parameters, and how they change the prediction.

    role: "base" (the shot-noise power law a model starts from) or "effect" (what it adds).
    """

    name: ClassVar[str] = "component"
    role: ClassVar[str] = "component"
    params: ClassVar[tuple[Param, ...]] = ()

    def __add__(self, other: Any) -> Any:
        raise TypeError(f"a model starts from a base model (power_law, passive or active), not {self!r}")

    def __repr__(self) -> str:
        return self.name


class BaseModel(Component):
    """A base model: the shot-noise variance k^2 Z^(2 lambda) effects build on (`rig.models.bases.Base`).

    lam: lambda when the base fixes it, None when it is fitted; doc: what it is, in words."""

    role = "base"
    lam: float | None = None
    doc: str = ""

    def shot(self, p: Mapping[str, float], d: ModelData) -> np.ndarray:
        raise NotImplementedError

    def shot_tangent(self, p: Mapping[str, float], d: ModelData, shot: np.ndarray, t: Any) -> np.ndarray | None:
        """d(shot variance) / d(parameters) for the rows of `t` (`rig.models.parts.tangents`)."""
        raise NotImplementedError


class Effect(Component):
    """A physical effect the base model leaves out.

    stage: where it joins (see `EffectStage`); needs: the covariates it uses; signature: the residual
    pattern it explains, in plain words; explanation: what it means physically; groupable: its prediction is
    smooth within a small tile of the image, so large data may be fitted on grouped nodes
    (`rig.models.fitting.grouping`); False for what depends on each pixel's own place on the depth grid.
    `apply(pred, p, d)` changes the prediction, with `p` its own parameters (`own`): `p.sigma_px`.
    """

    role = "effect"
    groupable: ClassVar[bool] = True
    stage: ClassVar[EffectStage]
    needs: ClassVar[tuple[str, ...]] = ()
    signature: ClassVar[str] = ""
    explanation: ClassVar[str] = ""
    #: where it was registered ("rig/models/effects/builtin/noise_floor.py:20"), for messages; set by `register`
    defined_at: str = ""
    #: the effect of the simulated camera (fakes/effects.py) that produces what this one predicts, by name: the
    #: blind test hides it and expects the diagnosis to name this effect; None: nothing there simulates it
    twin: ClassVar[str | None] = None
    #: its place in the catalogue (`EFFECTS`): the diagnosis tries effects in this order and `rig simulate --seed N`
    #: draws among them in it; a new built-in effect takes the next free number
    position: ClassVar[int] = 1000
    #: whether the diagnosis tries it among its candidates (`Catalogue.candidates`); False: only a model that names it
    #: has it (`measured_light`, which explains any pattern of light and so would take the place of the effect to find)
    diagnosed: ClassVar[bool] = True

    def scenario(self, rng: np.random.Generator) -> dict[str, float] | None:
        """The parameters of its twin the blind test hides, drawn from `rng` (realistic ranges); None: no scenario."""
        return None

    def applicable(self, d: ModelData) -> str | None:
        """None if the effect can be fitted to these data, else why not (one line)."""
        return None

    def apply(self, pred: Prediction, p: Any, d: ModelData) -> None:
        """Change `pred` (`p`: this effect's parameters, a named tuple made by `own`)."""
        raise NotImplementedError

    def apply_tangent(self, pred: Prediction, p: Any, d: ModelData, t: Any) -> None:
        """`apply`, carrying the derivatives `t` (`rig.models.parts.tangents.Tangents`) through it by the chain rule.
        A model with an effect that has none is fitted with central differences of the whole likelihood instead."""
        raise NotImplementedError

    def start(self, d: ModelData, pred: Prediction) -> dict[str, float]:
        """Starting values by parameter name (they may depend on the data and the base prediction)."""
        return {q.name: q.value for q in self.params}

    def own(self, values: Any) -> Any:
        """This effect's parameters as a named tuple (`p.sigma_px`), from a model's values by qualified name
        ("noise_floor.sigma_px"); given such a tuple already, itself. A fixed parameter missing from `values`
        is its declared value."""
        kind = self._own_type()
        if isinstance(values, kind):
            return values
        out = []
        for q in self.params:
            key = f"{self.name}.{q.name}"
            if key in values:
                out.append(values[key])
            elif not q.vary:
                out.append(q.value)
            else:
                raise KeyError(f"no value for {key}, a free parameter of {self.name}")
        return kind._make(out)

    def _own_type(self) -> type:
        key = (self.name, tuple(q.name for q in self.params))
        cached = self.__dict__.get("_own")
        if cached is None or cached[0] != key:
            kind = namedtuple(f"{type(self).__name__}Params", key[1])  # type: ignore[misc]
            cached = self.__dict__["_own"] = (key, kind)
        return cached[1]


class ComposedModel(Protocol):
    """What fitting (`optimise`), the likelihood and results (`result`) need of a model: a base plus effects."""

    base: BaseModel
    effects: tuple[Effect, ...]

    @property
    def name(self) -> str: ...

    def parameters(self) -> list[tuple[str, Param]]: ...

    def free(self) -> list[tuple[str, Param]]: ...

    def predict(self, values: Mapping[str, float], d: ModelData, tangents: Any = None) -> Prediction: ...

    def loglik(self, values: Mapping[str, float], d: ModelData) -> float: ...

    def check(self, d: ModelData) -> None: ...

    def __add__(self, other: Any) -> ComposedModel: ...


# -- the registry ---------------------------------------------------------------------------------------

#: the built-in effects by name, in the order rig's own modules register them
EFFECTS: dict[str, Effect] = {}
#: effects registered by any other module (a file of effects, a plugin, a test): module name -> name -> effect
_ELSEWHERE: dict[str, dict[str, Effect]] = {}
_ROOT = Path(__file__).resolve().parents[3]


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator: register the one instance of an `Effect` subclass under its `name` (see the module
    docstring). A name the same place has registered already is an `EffectFileError` naming both."""
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise TypeError(f"@register takes a subclass of Effect, not {cls!r}")
    effect = cls()
    caller = sys._getframe(1)
    add(effect, cls.__module__, f"{_short(caller.f_code.co_filename)}:{caller.f_lineno}")
    return cls


def add(effect: Effect, module: str, defined_at: str = "") -> Effect:
    """Register `effect` as defined in `module` (at `defined_at`, "file:line"); see `register`."""
    if defined_at:
        effect.defined_at = defined_at
    table = EFFECTS if _is_builtin(module) else _ELSEWHERE.setdefault(module, {})
    old = table.get(effect.name)
    if old is not None and old is not effect:
        raise EffectFileError(f"effect name {effect.name!r} registered twice: by {describe(old)} and by "
                              f"{describe(effect)}; rename one of them")
    table[effect.name] = effect
    return effect


def order_builtins() -> None:
    """Put the built-in effects in the order of their `position` (then of registration)."""
    ordered = sorted(EFFECTS.values(), key=lambda e: e.position)
    EFFECTS.clear()
    EFFECTS.update((e.name, e) for e in ordered)


def registered_by(module: str) -> list[Effect]:
    """The effects `module` registered, in order (rig's own: the built-in ones)."""
    return list((EFFECTS if _is_builtin(module) else _ELSEWHERE.get(module, {})).values())


def forget(module: str) -> None:
    """Drop what `module` (not one of rig's) registered, before its file is run again."""
    if not _is_builtin(module):
        _ELSEWHERE.pop(module, None)


def describe(e: Effect) -> str:
    """The effect's class and where it was registered, for messages:
    "NoiseFloor (rig/models/effects/builtin/noise_floor.py:20)"."""
    what = type(e).__qualname__
    return f"{what} ({e.defined_at})" if e.defined_at else what


def _is_builtin(module: str) -> bool:
    return module == "rig" or module.startswith("rig.")


def _short(path: str) -> str:
    try:
        return str(Path(path).resolve().relative_to(_ROOT))
    except ValueError:
        return path
