"""Models that compose, lmfit-style: a base power law plus physical effects.

    model = active + slant_range + noise_floor          # or parse_model("active+slant_range+noise_floor")
    result = model.fit(data)                             # data: ModelData.from_recording(path)
    print(result.report())

A model predicts, for every pixel of every stop, the variance of its range samples (m^2) and
their fourth cumulant (m^4, zero for a normal distribution); effects join at fixed stages
(`rig.models.parts.prediction`), and every model also includes what the file fixes
(`rig.models.effects.file_physics`). What a model is made of is `rig.models.parts.component`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .parts.component import BaseModel, Component, Effect, describe
from .data.model_data import ModelData
from .effects.file_physics import range_transform
from .fitting.likelihood import model_loglik
from .fitting.optimise import fit_model
from .parts.parameters import Param
from .parts.prediction import EffectStage, Prediction
from .parts.tangents import Tangents, plus, scale

if TYPE_CHECKING:
    from .parts.result import ModelFit


@dataclass(frozen=True)
class Model:
    """A base model plus effects. Compose with `+`; fit with `.fit(data)`."""

    base: BaseModel
    effects: tuple[Effect, ...] = ()

    @classmethod
    def of(cls, c: Component | Model) -> Model:
        if isinstance(c, Model):
            return c
        if isinstance(c, BaseModel):
            return cls(c)
        raise TypeError(f"a model starts from a base model (power_law, passive or active), not {c!r}")

    def __add__(self, other: Any) -> Model:
        """This model and the effect `other`, at its stage. The same effect again changes nothing; another effect
        of the same name is an error naming both."""
        if isinstance(other, BaseModel):
            raise ValueError(f"{self.name} already has a base model; add effects, not {other.name}")
        if not isinstance(other, Effect):
            raise TypeError(f"cannot add {other!r} to a model; add an effect such as noise_floor")
        same = [e for e in self.effects if e.name == other.name]
        if same and same[0] is other:
            return self
        if same:
            raise ValueError(f"{self.name} has an effect {other.name} already ({describe(same[0])}); "
                             f"{describe(other)} has the same name: rename one of them")
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

    def predict(self, values: Mapping[str, float], d: ModelData, tangents: Tangents | None = None) -> Prediction:
        """The prediction with parameter `values` (by qualified name); each effect gets its own (`Effect.own`). Given
        `tangents` (`rig.models.parts.tangents`), their derivatives are carried through every stage as well."""
        pred = self.predict_noise(values, d, tangents)
        range_transform(pred, d, tangents)
        for e in self.effects:
            if e.stage > EffectStage.CENSOR:
                self._stage(e, e.own(values), pred, d, tangents)
        return pred

    @staticmethod
    def _stage(e: Effect, p: Any, pred: Prediction, d: ModelData, t: Tangents | None) -> None:
        if t is None:
            e.apply(pred, p, d)
        else:
            e.apply_tangent(pred, p, d, t)

    def predict_noise(self, values: Mapping[str, float], d: ModelData, tangents: Tangents | None = None) -> Prediction:
        """The prediction up to the camera's censoring: the noise of a depth sample before the depth file (its
        format's end, the curvature of Z = f b / d, the depth unit's rounding) and before outliers and the tails'
        shapes. What `rig export` writes and `rig.noise_model` evaluates (docs/noise-model.md)."""
        t = tangents
        own = [e.own(values) for e in self.effects]
        pred = Prediction(self.base.shot(values, d), np.ones(len(d)), np.zeros(len(d)))
        if t is not None:
            t.shot = self.base.shot_tangent(values, d, pred.shot_m2, t)

        def stage(e: Effect, p: Any) -> None:
            self._stage(e, p, pred, d, t)

        for e, p in zip(self.effects, own):
            if e.stage < EffectStage.DISPARITY:
                stage(e, p)
        pred.var_m2 = pred.shot_m2 * pred.illum * (1.0 + pred.image_terms)
        if t is not None:  # var = shot illum (1 + image)
            t.var = plus(scale(t.shot, pred.illum * (1.0 + pred.image_terms)),
                         scale(t.illum, pred.shot_m2 * (1.0 + pred.image_terms)),
                         scale(t.image, pred.shot_m2 * pred.illum))
        for e, p in zip(self.effects, own):
            if EffectStage.DISPARITY <= e.stage <= EffectStage.CENSOR:
                stage(e, p)
        return pred

    def loglik(self, values: Mapping[str, float], d: ModelData) -> float:
        """The composite log-likelihood (`rig.models.fitting.likelihood`), evaluated stop by stop."""
        return model_loglik(self, values, d)

    def check(self, d: ModelData) -> None:
        for e in self.effects:
            why = e.applicable(d)
            if why:
                raise ValueError(why)

    def fit(self, d: ModelData, start: dict[str, float] | None = None, *, errors: bool = True,
            hold: frozenset[str] = frozenset(), grouped: bool = True, exact_loglik: bool = True,
            warm: ModelFit | None = None) -> ModelFit:
        """Maximum likelihood (rig.models.fitting.optimise); `errors=False` skips the standard errors; parameters
        in `hold` stay at their `start` values; `grouped=False` fits every pixel even where grouped nodes
        would do (rig.models.fitting.grouping); `warm`: this model's fit to nearly the same data, to refit from."""
        return fit_model(self, d, start, errors=errors, hold=hold, grouped=grouped, exact_loglik=exact_loglik,
                         warm=warm)
