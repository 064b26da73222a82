"""Models that compose, lmfit-style: a base power law plus physical effects.

    model = active + slant_range + noise_floor          # or parse_model("active+slant_range+noise_floor")
    result = model.fit(data)                             # data: ModelData.from_recording(path)
    print(result.report())

A model predicts, for every pixel of every stop, the variance of its range samples (m^2) and
their fourth cumulant (m^4, zero for a normal distribution); effects join at fixed stages
(`rig.models.prediction`), and every model also includes what the file fixes
(`rig.models.file_physics`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from .data import ModelData
from .file_physics import range_transform
from .likelihood import model_loglik
from .optimise import fit_model
from .parameters import Param
from .prediction import EffectStage, Prediction

if TYPE_CHECKING:
    from .bases import Base
    from .effects import Effect
    from .result import ModelFit


class Component:
    """Base models and effects: a name, parameters, and how they change the prediction.

    role: "base" (the shot-noise power law a model starts from) or "effect" (what it adds).
    """

    name: ClassVar[str] = "component"
    role: ClassVar[str] = "component"
    params: ClassVar[tuple[Param, ...]] = ()

    def __add__(self, other: "Component") -> "Model":
        return Model.of(self) + other

    def __repr__(self) -> str:
        return self.name


@dataclass(frozen=True)
class Model:
    """A base model plus effects. Compose with `+`; fit with `.fit(data)`."""

    base: Base
    effects: tuple[Effect, ...] = ()

    @classmethod
    def of(cls, c: Component) -> "Model":
        if isinstance(c, Model):
            return c
        if getattr(c, "role", None) == "base":
            return cls(c)  # type: ignore[arg-type]
        raise TypeError(f"a model starts from a base model (power_law, passive or active), not {c!r}")

    def __add__(self, other: Any) -> "Model":
        if getattr(other, "role", None) == "base":
            raise ValueError(f"{self.name} already has a base model; add effects, not {other.name}")
        if getattr(other, "role", None) != "effect":
            raise TypeError(f"cannot add {other!r} to a model; add an effect such as noise_floor")
        if other.name in (e.name for e in self.effects):
            return self
        return Model(self.base, tuple(sorted((*self.effects, other), key=lambda e: e.stage)))

    @property
    def name(self) -> str:
        return "+".join([self.base.name, *(e.name for e in self.effects)])

    def parameters(self) -> list[tuple[str, Param]]:
        """(qualified name, Param) for every parameter: base ones plain, effect ones as effect.param."""
        out = [(p.name, p) for p in self.base.params]
        for e in self.effects:
            out += [(f"{e.name}.{p.name}", p) for p in e.params]
        return out

    def free(self) -> list[tuple[str, Param]]:
        return [(n, p) for n, p in self.parameters() if p.vary]

    def predict(self, values: dict[str, float], d: ModelData) -> Prediction:
        pred = Prediction(self.base.shot(values, d), np.ones(len(d)), np.zeros(len(d)))
        for e in self.effects:
            if e.stage < EffectStage.DISPARITY:
                e.apply(pred, values, d)
        pred.var_m2 = pred.shot_m2 * pred.illum * (1.0 + pred.image_terms)
        for e in self.effects:
            if EffectStage.DISPARITY <= e.stage <= EffectStage.CENSOR:
                e.apply(pred, values, d)
        range_transform(pred, d)
        for e in self.effects:
            if e.stage > EffectStage.CENSOR:
                e.apply(pred, values, d)
        return pred

    def loglik(self, values: dict[str, float], d: ModelData) -> float:
        """The composite log-likelihood (`rig.models.likelihood`), evaluated stop by stop."""
        return model_loglik(self, values, d)

    def check(self, d: ModelData) -> None:
        for e in self.effects:
            why = e.applicable(d)
            if why:
                raise ValueError(why)

    def fit(self, d: ModelData, start: dict[str, float] | None = None, *, errors: bool = True,
            hold: frozenset[str] = frozenset(), grouped: bool = True, exact_loglik: bool = True) -> "ModelFit":
        """Maximum likelihood (rig.models.optimise); `errors=False` skips the standard errors; parameters
        in `hold` stay at their `start` values; `grouped=False` fits every pixel even where grouped nodes
        would do (rig.models.grouping)."""
        return fit_model(self, d, start, errors=errors, hold=hold, grouped=grouped, exact_loglik=exact_loglik)
