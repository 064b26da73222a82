"""How wrong a fitted model is, in one number a person can follow, and on data it has not seen.

Headline error: bin the pixels by range (0.25 m windows centred on multiples of 0.25 m) and
by image radius (rho = distance from the principal point in units of f: 0-0.3, 0.3-0.6, 0.6+).
In each bin compare the measured sigma (pooled: sqrt(sum M2 / sum (n-1))) with the model's
(sqrt of the degrees-of-freedom-weighted mean predicted variance):
    headline = RMS over bins of ln(sigma_measured / sigma_predicted), in percent.
Sampling noise alone would give an RMS of the bins' standard errors (the "noise level"),
se(ln sigma) = 0.5 * sqrt(sum nu^2 (2/nu + excess/n)) / sum nu, with the bin's measured
kurtosis. The model is "within noise" when sum (ln ratio / se)^2 is consistent with a chi^2
of (bins - free parameters) degrees of freedom (p >= 0.001).

Held-out: leave one stop out (or, for a single-stop recording, one of four vertical strips
of the image), fit on the rest, and score the left-out pixels; reported as negative
log-likelihood per degree of freedom (lower is better).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from ..models import Model, ModelData, ModelFit
from .bins import compare_bins, range_radius_groups


@dataclass
class Headline:
    """The headline error of a fit and the level sampling noise alone would give."""

    error_pct: float
    noise_pct: float
    chi2: float
    dof: int
    p_value: float
    bins: int

    @property
    def within_noise(self) -> bool:
        return self.p_value >= 1e-3

    @property
    def excess_pct(self) -> float:
        """The part of the headline error beyond sampling noise: sqrt(error^2 - noise^2), 0 if none.

        The RMS of ln ratios contains the sampling noise in quadrature; no model can remove
        that part, so "the error halved" is judged on the excess."""
        return float(np.sqrt(max(self.error_pct**2 - self.noise_pct**2, 0.0)))

    def __str__(self) -> str:
        verdict = "within noise" if self.within_noise else "beyond noise"
        return f"{self.error_pct:.2f} % (noise alone: {self.noise_pct:.2f} %; {verdict}, chi2 {self.chi2:.0f}/{self.dof})"


def headline(fit: ModelFit, d: ModelData) -> Headline:
    pred = fit.predict(d)
    groups, labels = range_radius_groups(d)
    b = compare_bins(d, pred, groups, d.z_m, labels)
    stat = float(np.sum((b.log_ratio / b.se_log) ** 2))
    dof = max(1, len(b.log_ratio) - fit.n_free)
    return Headline(
        error_pct=100 * float(np.sqrt(np.mean(b.log_ratio**2))),
        noise_pct=100 * float(np.sqrt(np.mean(b.se_log**2))),
        chi2=stat, dof=dof, p_value=float(chi2.sf(stat, dof)), bins=len(b.log_ratio),
    )


def held_out_nll(model: Model, d: ModelData, full: ModelFit | None = None) -> float:
    """Negative log-likelihood per degree of freedom on left-out stops (or image strips)."""
    stops = np.unique(d.stop)
    if len(stops) >= 3:
        groups = d.stop
    else:
        edges = np.quantile(d.u_px, [0.25, 0.5, 0.75])
        groups = np.digitize(d.u_px, edges)
    start = full.values if full is not None else None
    total, dof = 0.0, 0.0
    for g in np.unique(groups):
        test = groups == g
        train_d, test_d = d.select(~test), d.select(test)
        f = model.fit(train_d, start=start)
        pred = model.predict(f.values, test_d)
        total += -test_d.loglik(pred.var_m2, pred.k4_m4)
        dof += test_d.nu.sum()
    return total / dof
