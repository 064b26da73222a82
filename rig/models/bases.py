"""The base models: sigma_Z = k * Z^lambda (paper, eq. error_prop_*), with lambda free or fixed."""

from __future__ import annotations

from typing import Any

import numpy as np

from .parts.component import BaseModel
from .composition import Model
from .data.model_data import ModelData
from .parts.parameters import Param


class Base(BaseModel):
    """sigma_Z = k * Z^lambda (paper, eq. error_prop_*); lambda free or fixed."""

    def __init__(self, name: str, lam: float | None, doc: str):
        self.name = name  # type: ignore[misc]
        self.lam = lam
        self.doc = doc
        self.params = (  # type: ignore[misc]
            Param("k", 0.002, 1e-9, 10.0, "m^(1-lambda)", "scale of the range error"),
            Param("lambda", 3.0 if lam is None else lam, -2.0, 8.0, "1", "exponent of range", vary=lam is None),
        )

    def shot(self, p: dict[str, float], d: ModelData) -> np.ndarray:
        """k^2 Z^(2 lambda) (m^2), as exp(2 lambda ln Z): a power with a non-integer exponent costs several times
        an exponential, and ln Z is kept with the data (`ModelData.ln_z0_m`)."""
        return p["k"] ** 2 * np.exp(2.0 * p["lambda"] * d.ln_z0_m)

    def shot_tangent(self, p: dict[str, float], d: ModelData, shot: np.ndarray, t: Any) -> np.ndarray | None:
        """d shot / d k = 2 shot / k; d shot / d lambda = 2 ln(Z) shot."""
        rows = []
        if (i := t.row(self, "k")) is not None:
            rows.append((i, 2.0 * shot / p["k"]))
        if (i := t.row(self, "lambda")) is not None:
            rows.append((i, 2.0 * d.ln_z0_m * shot))
        return t.seeded(rows)

    def __add__(self, other: Any) -> Model:
        return Model.of(self) + other


power_law = Base("power_law", None, "the paper's model: k and lambda free")
passive = Base("passive", 2.0, "passive stereo: lambda fixed at 2 (constant light)")
active = Base("active", 3.0, "active stereo: lambda fixed at 3 (projected light falls as 1/Z^2)")
BASES = {b.name: b for b in (power_law, passive, active)}


def fixed_lambda(lam: float) -> Base:
    """The base with lambda fixed at `lam`: `active` for 3, `passive` for 2, else a power law of its own."""
    for b in (active, passive):
        if b.lam == lam:
            return b
    return Base(f"power_law(lambda={lam:g})", lam, f"the paper's model with lambda fixed at {lam:g}")
