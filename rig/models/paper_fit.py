"""The paper's fit of sigma_Z = k * Z^lambda on all pixels and frames, as a fitted model.

The estimator is `rig.models.fitting.closed_form.power_law_mle` (closed-form k, a 1-D search for
lambda, Cramer-Rao errors); this gives its result the same type and report as every
composed model: the power law is a model with no effects.
"""

from __future__ import annotations

import math

from .bases import fixed_lambda, power_law
from .fitting.closed_form import power_law_mle
from .composition import Model
from .data.model_data import ModelData
from .data.independence import error_inflation
from .parts.result import ModelFit


def fit_power_law(samples: ModelData, *, lam: float | None = None) -> ModelFit:
    """Maximum-likelihood k and lambda (or k alone, with lambda fixed at `lam`) from pixel samples."""
    e = power_law_mle(samples.z_m, samples.m2_m2, samples.n, lam=lam)
    model = Model(fixed_lambda(e.lam)) if e.lam_fixed else Model(power_law)
    grow = error_inflation(samples)  # sqrt(n / n_eff) when the frames are not independent, else 1
    cov = e.covariance * grow**2
    se_k = math.sqrt(cov[0, 0])
    errors = {"k": se_k} if e.lam_fixed else {"k": se_k, "lambda": math.sqrt(cov[1, 1])}
    covariance = cov[:1, :1] if e.lam_fixed else cov
    return ModelFit(model, {"k": e.k, "lambda": e.lam}, errors, e.loglik, n_obs=e.n_pixels, n_samples=e.n_samples,
                    dof=e.dof, z_range_m=e.z_range_m, covariance=covariance,
                    likelihood="Gaussian, of the samples, as in the paper")
