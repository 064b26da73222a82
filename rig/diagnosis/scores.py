"""How wrong a fitted model is, in one number a person can follow, and on data it has not seen.

Headline error: bin the pixels by range (0.25 m windows centred on multiples of 0.25 m) and
by image radius (rho = distance from the principal point in units of f: 0-0.3, 0.3-0.6, 0.6+).
In each bin compare the measured sigma (pooled: sqrt(sum M2 / sum (n-1))) with the model's
(sqrt of the degrees-of-freedom-weighted mean predicted variance):
    headline = RMS over bins of ln(sigma_measured / sigma_predicted), in percent.
Sampling noise alone would give an RMS of the bins' standard errors (the "noise level"),
se(ln sigma) = 0.5 * sqrt(sum nu^2 (2/nu + excess/n)) / sum nu, with the bin's measured
kurtosis. The headline bins are "within noise" when sum (ln ratio / se)^2 is consistent with a
chi^2 of (bins - free parameters) degrees of freedom (p >= 0.001); the model is within noise
when, beyond that, every other statistic it predicts is too (`rig.diagnosis.consistency`), and
the headline names the worst one that is not. A model that fits lambda to data that do not
determine it (`rig.models.data.determinacy`: fewer than three ranges, or a span under 1.5 x) is not
judged at all: its verdict says "lambda NOT DETERMINED" and why.

Held-out: leave one stop out (or, for a single-stop recording, one of four vertical strips
of the image), fit on the rest, and score the left-out pixels; reported as negative
log-likelihood per degree of freedom (lower is better).
"""

from __future__ import annotations

import gc
from dataclasses import dataclass, field

import numpy as np

from ..models import Model, ModelData, ModelFit
from ..models.fitting.optimise import fit_data
from ..models.data.model_data import stops_of
from ..models.fitting.grouping import whole_stops
from ..models.fitting.likelihood import gamma_constant_by_stop, loglik
from ..models.parallel import forked_map
from ..models.parts.result import chi2_sf
from ..models.data.determinacy import LambdaStatus, lambda_status
from ..models.fitting.progress import ProgressCounter
from .consistency import ALPHA, Consistency
from .bins import MIN_PIXELS_PER_BIN
from .residuals import Residuals, residuals


@dataclass
class Headline:
    """The headline error of a fit and the level sampling noise alone would give."""

    error_pct: float
    noise_pct: float
    chi2: float
    dof: int
    p_value: float
    bins: int
    consistency: Consistency | None = None
    #: does the data determine lambda (when the model fits it)? A fit whose lambda is not determined is
    #: never called "within noise" in words (`verdict`, `state`), whatever the statistics say
    lambda_status: LambdaStatus | None = None
    #: the comparison the headline was computed from (every family's bins), for whoever shows it next
    residuals: Residuals | None = field(default=None, repr=False, compare=False)

    @property
    def determined(self) -> bool:
        return self.lambda_status is None or self.lambda_status.determined

    @property
    def judged(self) -> bool:
        """Some range-and-radius bin holds enough pixels (`bins.MIN_PIXELS_PER_BIN`) to compare sigma in."""
        return self.bins > 0

    @property
    def state(self) -> str:
        """In two words: "within noise", "beyond noise", "not determined" (lambda free, the data too narrow), or
        "not judged" (no bin holds enough pixels)."""
        if not self.judged:
            return "not judged"
        if not self.determined:
            return "not determined"
        return "within noise" if self.within_noise else "beyond noise"

    @property
    def sigma_within_noise(self) -> bool:
        """The headline bins (sigma by range and radius) agree within sampling noise: p >= ALPHA, or, with
        the other checks, at the same family-wise threshold as each of them."""
        return self.p_value >= (ALPHA if self.consistency is None else self.consistency.threshold_with(1))

    @property
    def within_noise(self) -> bool:
        """Every statistic the model predicts agrees within its own error (the headline bins included); never where
        nothing was judged."""
        return self.judged and self.sigma_within_noise and (self.consistency is None or self.consistency.within_noise_with(1))

    @property
    def misfit(self) -> float:
        """How far beyond noise, all statistics together: the chi^2 above its degrees of freedom, summed over
        the headline bins and every other check."""
        extra = sum(max(0.0, c.chi2 - c.dof) for c in self.consistency.checks) if self.consistency else 0.0
        return max(0.0, self.chi2 - self.dof) + extra

    def verdict(self) -> str:
        if not self.judged:
            return (f"NOT JUDGED: no range-and-radius bin holds {MIN_PIXELS_PER_BIN} pixels to compare sigma in; "
                    "record a larger image or more frames a stop")
        if not self.determined:
            return f"lambda NOT DETERMINED: {self.lambda_status.reason.removeprefix('lambda is not determined: ')}"
        if self.within_noise:
            return "every statistic within noise" if self.consistency is not None else "within noise"
        worst = self.consistency.worst(extra=1) if self.consistency is not None else None
        if worst is None or (not self.sigma_within_noise and self.chi2 / self.dof > worst.chi2 / worst.dof):
            return f"beyond noise; worst: sigma by range and radius, chi2 {self.chi2:.4g}/{self.dof}"
        return f"beyond noise; worst: {worst.describe_worst()}"

    @property
    def excess_pct(self) -> float:
        """The part of the headline error beyond sampling noise: sqrt(error^2 - noise^2), 0 if none.

        The RMS of ln ratios contains the sampling noise in quadrature; no model can remove
        that part, so "the error halved" is judged on the excess."""
        return float(np.sqrt(max(self.error_pct**2 - self.noise_pct**2, 0.0)))

    def __str__(self) -> str:
        return f"{self.error_pct:.2f} % (noise alone: {self.noise_pct:.2f} %; {self.verdict()})"


def headline(fit: ModelFit, d: ModelData, *, checks: bool = True) -> Headline:
    """The headline error of `fit`; with `checks`, also the verdict on every other statistic it predicts. One
    pass over the data (`rig.diagnosis.residuals`) gives both."""
    r = residuals(fit, d)
    b = r.by_range_radius
    stat = float(np.sum((b.log_ratio / b.se_log) ** 2))
    dof = max(1, len(b.log_ratio) - fit.n_free)
    rms = (lambda x: 100 * float(np.sqrt(np.mean(x**2)))) if len(b.log_ratio) else (lambda x: float("nan"))
    return Headline(
        error_pct=rms(b.log_ratio),
        noise_pct=rms(b.se_log),
        chi2=stat, dof=dof, p_value=float(chi2_sf(stat, dof)), bins=len(b.log_ratio),
        consistency=r.consistency if checks else None,
        lambda_status=lambda_status(d, free=not fit.lam_fixed),
        residuals=r,
    )


def held_out_folds(d: ModelData) -> np.ndarray:
    """The part each pixel is left out with: its stop, or (fewer than three stops) one of four vertical strips."""
    if len(stops_of(d)) >= 3:
        return d.stop
    edges = np.quantile(d.u_px, [0.25, 0.5, 0.75])
    return np.digitize(d.u_px, edges)


def held_out_nll(model: Model, d: ModelData, full: ModelFit | None = None, *,
                 counter: ProgressCounter | None = None, jobs: int = 1) -> float:
    """Negative log-likelihood per degree of freedom on left-out stops (or image strips); `counter`, if given,
    is told of each refit (`rig.models.fitting.progress`). Left-out stops share the whole data's per-pixel statistics
    and grouped nodes (`rig.models.fitting.grouping.whole_stops`); the parts are fitted in up to `jobs` worker processes."""
    groups = held_out_folds(d)
    by_stop = groups is d.stop
    start = full.values if full is not None else None
    if by_stop:
        fit_data(model, d)  # the whole data's nodes, which the folds share, made once before any fork
        d.fill_by_stop, gamma_constant_by_stop(d)  # noqa: B018 (computed once here, not in every worker)
    parts = stops_of(d) if by_stop else np.unique(groups)

    def one(i: int) -> tuple[float, float]:
        test = groups == parts[i]
        if by_stop:
            train_d, test_d = whole_stops(d, ~test, statistics=False), whole_stops(d, test)
        else:
            train_d, test_d = d.select(~test), d.select(test)
        # from the whole data's fit: a fold is 1/parts of the data away from its optimum
        f = model.fit(train_d, start=start, errors=False, exact_loglik=False, warm=full)
        pred = model.predict(f.values, test_d)
        score = -loglik(test_d, pred.var_m2, pred.k4_m4, pred.fill), float(test_d.nu.sum())
        # a part's nodes point back at its data (GroupedData.full), a cycle only the collector frees, and it
        # counts objects, not bytes: without this, every part's copies (about 350 MB on a full sweep) stayed
        del train_d, test_d, pred
        gc.collect()
        return score

    finished = [0]

    def done(i: int) -> None:  # parts finish in any order when refitted in parallel: count them
        finished[0] += 1
        if counter is not None:
            counter.step(f"held-out score of {model.name}: {finished[0]} of {len(parts)} refits with a part left out")

    scores = forked_map(one, len(parts), jobs=jobs, done=done)
    return sum(t for t, _ in scores) / sum(n for _, n in scores)
