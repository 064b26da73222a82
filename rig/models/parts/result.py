"""A fitted model, whether the paper's power law or a composed one: one result type, one report.

The paper's fit of sigma_Z = k * Z^lambda (`rig.models.paper_fit`) is a model with no
effects; its result reads the same as any other, with shortcuts for its two parameters
(`k`, `lam`, `se_k`, `se_lam`, `corr`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import chdtrc

if TYPE_CHECKING:
    from .component import ComposedModel
    from ..data.model_data import ModelData
    from .prediction import Prediction


@dataclass
class ModelFit:
    """A fitted model: values, Cramer-Rao standard errors (and covariance), likelihood and information criteria.

    n_obs: pixel-stops (each contributes one sample variance); dof: the variances' degrees of
    freedom, sum of (n - 1); z_range_m: the range the fitted pixels span, m.
    covariance: of the free parameters, in the order of `model.free()` (None if not computed).
    """

    model: ComposedModel
    values: dict[str, float]
    errors: dict[str, float]
    loglik: float
    n_obs: int
    n_samples: int
    converged: bool = True
    message: str = ""
    dof: float = float("nan")
    z_range_m: tuple[float, float] = (float("nan"), float("nan"))
    covariance: np.ndarray | None = field(default=None, repr=False)
    #: what the log-likelihood is of: the paper's fit uses the samples' Gaussian likelihood, composed models
    #: the Gamma likelihood of the pixel variances (rig.models.data.model_data); they differ by terms of the data alone,
    #: so compare BICs only between fits of the same kind
    likelihood: str = "Gamma, of the pixel variances"
    #: for each free parameter without a standard error (NaN), why, in words (`rig.models.parts.error_notes`)
    error_notes: dict[str, str] = field(default_factory=dict)
    #: the optimiser's inverse-Hessian estimate at the optimum, in its free coordinates, with the names it is over
    #: (`rig.models.fitting.optimise._metric`): what a refit on nearly the same data starts from (`warm`)
    metric: tuple[tuple[str, ...], np.ndarray] | None = field(default=None, repr=False, compare=False)

    # -- criteria ----------------------------------------------------------------------------
    @property
    def n_free(self) -> int:
        return len(self.model.free())

    @property
    def bic(self) -> float:
        return -2 * self.loglik + self.n_free * math.log(self.n_obs)

    @property
    def aic(self) -> float:
        return -2 * self.loglik + 2 * self.n_free

    def predict(self, d: ModelData) -> Prediction:
        return self.model.predict(self.values, d)

    # -- the power law's two parameters --------------------------------------------------------
    @property
    def k(self) -> float:
        """Scale of the range error, m^(1 - lambda)."""
        return self.values["k"]

    @property
    def lam(self) -> float:
        """Exponent of range."""
        return self.values["lambda"]

    @property
    def se_k(self) -> float:
        return self.errors.get("k", float("nan"))

    @property
    def se_lam(self) -> float:
        """Standard error of lambda (0 when lambda is fixed)."""
        return self.errors.get("lambda", 0.0 if self.lam_fixed else float("nan"))

    @property
    def lam_fixed(self) -> bool:
        return self.model.base.lam is not None

    @property
    def corr(self) -> float:
        """Correlation of the k and lambda estimates (0 when lambda is fixed)."""
        return self.correlation("k", "lambda")

    def correlation(self, a: str, b: str) -> float:
        names = [n for n, _ in self.model.free()]
        if self.covariance is None or a not in names or b not in names:
            return 0.0
        i, j = names.index(a), names.index(b)
        c = self.covariance
        denominator = math.sqrt(c[i, i] * c[j, j]) if c[i, i] > 0 and c[j, j] > 0 else 0.0
        return float(c[i, j] / denominator) if denominator > 0 else 0.0

    @property
    def n_pixels(self) -> int:
        return self.n_obs

    @property
    def z_min_m(self) -> float:
        return self.z_range_m[0]

    @property
    def z_max_m(self) -> float:
        return self.z_range_m[1]

    def sigma_m(self, z_m: np.ndarray | float) -> np.ndarray:
        """The base model's sigma_Z = k Z^lambda in m at range z_m (effects not included)."""
        return self.k * np.asarray(z_m, dtype=float) ** self.lam

    # -- report --------------------------------------------------------------------------------
    def report(self) -> str:
        """Parameters with standard errors and units, the data they came from, and the likelihood."""
        b = self.model.base
        effects = f"; plus {', '.join(e.name for e in self.model.effects)}" if self.model.effects else ""
        lines = [f"[[Model: {self.model.name}]]  sigma_Z = k * Z^lambda, {b.doc}{effects}",
                 f"    samples: {self.n_samples:,} in {self.n_obs:,} pixel-stops ({self.dof:,.0f} degrees of freedom); "
                 f"range {self.z_min_m:.3f} - {self.z_max_m:.3f} m",
                 f"    log-likelihood {self.loglik:.6g} ({self.likelihood}); BIC {self.bic:.6g}" +
                 ("" if self.converged else f"  (NOT CONVERGED: {self.message})")]
        width = max(len(name) for name, _ in self.model.parameters())
        for name, p in self.model.parameters():
            v = self.values[name]
            unit = "" if p.unit == "1" else p.unit
            if p.vary:
                se = self.errors.get(name, float("nan"))
                at = "  (at bound)" if p.at_bound(v) else ("  (no error: see below)" if name in self.error_notes else "")
                lines.append(f"    {name:<{width}} = {v:.6g} +/- {se:.2g} {unit}".rstrip() + at)
            else:
                lines.append(f"    {name:<{width}} = {v:.6g} {unit}".rstrip() + " (fixed)")
        for why, names in _grouped(self.error_notes).items():
            lines.append(f"    no standard error for {', '.join(names)}: {why}")
        if not self.lam_fixed:
            lines.append(f"    corr(k, lambda) = {self.corr:+.3f}")
        for e in self.model.effects:
            if not e.params or not any(p.vary for p in e.params):
                lines.append(f"    {e.name}: no free parameter ({e.explanation})")
        return "\n".join(lines)


def _grouped(notes: dict[str, str]) -> dict[str, list[str]]:
    """The parameters of each distinct note, in order."""
    out: dict[str, list[str]] = {}
    for name, why in notes.items():
        out.setdefault(why, []).append(name)
    return out


def likelihood_ratio(base: ModelFit, extended: ModelFit) -> tuple[float, int, float]:
    """(2 * delta loglik, degrees of freedom, p-value). Effects without free parameters count as one."""
    stat = max(0.0, 2 * (extended.loglik - base.loglik))
    df = max(1, extended.n_free - base.n_free)
    return stat, df, float(chi2_sf(stat, df))


def chi2_sf(x: float, dof: float) -> float:
    """P(chi^2_dof > x) (scipy.special, without importing scipy.stats: a third of a second at start-up)."""
    return float(chdtrc(dof, x))
