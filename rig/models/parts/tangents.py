"""Forward derivatives of a prediction: what makes the likelihood's gradient analytic.

A fit asks for the log-likelihood and its gradient over the free parameters theta. The likelihood is
a sum over rows of functions of each row's predicted variance, fourth cumulant and fill
(`rig.models.fitting.likelihood`), so its gradient is sum_rows (dL/dvar dvar/dtheta + dL/dk4 dk4/dtheta +
dL/dfill dfill/dtheta). `Tangents` carries d(quantity)/d(theta_j) for every quantity the prediction
is built from (shot variance, illumination, image terms, variance, fourth cumulant, fill), one row
per parameter, and every stage that changes the prediction changes them by the chain rule:
`Model.predict(values, d, tangents)` calls each effect's `apply_tangent` (the effect's own derivative,
written next to its formula) instead of `apply`.

A quantity whose derivative is zero for every parameter is None (most are: fill until censoring or
the mixture, illumination for every built-in effect). A user's effect (`rig.models.effects.user_effects`)
differences its own function per row for its parameters; an `Effect` subclass without `apply_tangent`
makes the model fall back to central differences of the whole likelihood (`rig.models.fitting.optimise`).
`tests/test_gradients.py` checks every built-in, empirical and user term's gradient against those
differences.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .component import BaseModel, Component, Effect


@dataclass
class Tangents:
    """d(quantity) / d(parameter) for the parameters `names` (qualified: "k", "noise_floor.sigma_px"), over
    `n` rows; each field is an (m, n) array, or None where it is zero (see the module docstring)."""

    names: Sequence[str]
    n: int
    shot: np.ndarray | None = None
    illum: np.ndarray | None = None
    image: np.ndarray | None = None
    var: np.ndarray | None = None
    k4: np.ndarray | None = None
    fill: np.ndarray | None = None
    #: censoring's cut (standard deviations) and the variance before it: their derivatives (`Prediction.censor`)
    censor: tuple[np.ndarray | None, np.ndarray | None] | None = None
    _rows: dict[str, int] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self._rows = {name: i for i, name in enumerate(self.names)}

    @property
    def m(self) -> int:
        return len(self.names)

    def row(self, owner: Component, param: str) -> int | None:
        """Which row differentiates `owner`'s parameter `param` (None: it is held or fixed)."""
        key = param if owner.role == "base" else f"{owner.name}.{param}"
        return self._rows.get(key)

    def own_rows(self, owner: Component) -> list[tuple[int, str]]:
        """(row, parameter name) for each of `owner`'s parameters being differentiated."""
        out = []
        for q in owner.params:
            i = self.row(owner, q.name)
            if i is not None:
                out.append((i, q.name))
        return out

    def seeded(self, rows: list[tuple[int, np.ndarray]]) -> np.ndarray | None:
        """An (m, n) array zero but for the given rows (None if there are none)."""
        if not rows:
            return None
        out = np.zeros((self.m, self.n))
        for i, values in rows:
            out[i] = values
        return out


def scale(t: np.ndarray | None, factor: Any) -> np.ndarray | None:
    """t * factor (factor per row, or one value), None staying None."""
    return None if t is None else t * factor


def plus(*terms: np.ndarray | None) -> np.ndarray | None:
    """The sum of the terms that are not None (None if none is; the term itself if it is the only one).

    Tangents are never changed in place (every stage makes new arrays, as this does), so a lone term is returned
    as it is, not copied (array copies were 1.3 s of a 15 s profile of a blind trial; not all were these)."""
    present = [t for t in terms if t is not None]
    if not present:
        return None
    if len(present) == 1:
        return present[0]
    out = present[0] + present[1]
    for t in present[2:]:
        out += t
    return out


def has_tangent(e: Effect) -> bool:
    """Whether the effect carries its own derivatives (`apply_tangent`): every built-in and empirical one does."""

    return type(e).apply_tangent is not Effect.apply_tangent


def analytic(model: Any) -> bool:
    """Whether `model`'s likelihood has an analytic gradient: its base and every effect carry derivatives."""

    return type(model.base).shot_tangent is not BaseModel.shot_tangent and all(has_tangent(e) for e in model.effects)
