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

from .models import Model, ModelData, ModelFit, Prediction

RANGE_BIN_M = 0.25
RADIUS_EDGES = (0.0, 0.3, 0.6, np.inf)
MIN_PIXELS_PER_BIN = 20


@dataclass
class BinComparison:
    """Measured against predicted sigma in bins of one or two covariates."""

    labels: list[str]
    center: np.ndarray  # the covariate's dof-weighted mean in each bin
    sigma_meas_m: np.ndarray
    sigma_pred_m: np.ndarray
    log_ratio: np.ndarray  # ln(measured / predicted)
    se_log: np.ndarray  # sampling standard error of ln(measured sigma)
    kurt_meas: np.ndarray  # pooled kurtosis of the samples
    kurt_pred: np.ndarray
    se_kurt: np.ndarray
    pixels: np.ndarray

    @property
    def flagged(self) -> np.ndarray:
        """Bins where the model is off by more than 3 standard errors."""
        return np.abs(self.log_ratio) > 3 * self.se_log


def compare_bins(d: ModelData, pred: Prediction, groups: np.ndarray, covariate: np.ndarray,
                 labels_of: dict[int, str] | None = None) -> BinComparison:
    """Pool measured and predicted variance within each group (integer labels)."""
    nu, n = d.nu, d.n
    m2 = d.s2_m2 * nu
    var_p = pred.var_m2
    excess_p = (pred.k4_m4 / var_p**2) if pred.k4_m4 is not None else np.zeros(len(d))
    out: dict[str, list] = {k: [] for k in ("labels", "center", "sm", "sp", "lr", "se", "km", "kp", "sk", "px")}
    for g in np.unique(groups):
        m = groups == g
        if m.sum() < MIN_PIXELS_PER_BIN:
            continue
        W = nu[m].sum()
        var_meas = m2[m].sum() / W
        var_pred = (nu[m] * var_p[m]).sum() / W
        # kurtosis of the samples about their pixel means, each pixel standardised by the model's
        # variance (pixels of different sigma would otherwise inflate it), rescaled to the bin's measured variance
        if np.isfinite(d.m4_m4[m]).any():
            kurt = float(np.nansum(d.m4_m4[m] / var_p[m] ** 2) / n[m].sum() * (var_pred / var_meas) ** 2)
            n_mean = float(n[m].mean())
            kurt *= (n_mean + 1) / (n_mean - 1)  # about the sample mean, a normal's kurtosis reads 3 (n-1)/(n+1)
        else:
            kurt = np.nan
        excess = (kurt - 3) if np.isfinite(kurt) else 0.0
        var_s2 = np.sum(nu[m] ** 2 * (2 / nu[m] + excess / n[m])) / W**2  # var(pooled s2) / var^2
        out["labels"].append(labels_of.get(int(g), str(g)) if labels_of else str(g))
        out["center"].append(float((nu[m] * covariate[m]).sum() / W))
        out["sm"].append(np.sqrt(var_meas))
        out["sp"].append(np.sqrt(var_pred))
        out["lr"].append(0.5 * np.log(var_meas / var_pred))
        out["se"].append(0.5 * np.sqrt(max(var_s2, 1e-30)))
        out["km"].append(kurt)
        out["kp"].append(3 + float((nu[m] * excess_p[m]).sum() / W))
        out["sk"].append(np.sqrt(24.0 / n[m].sum()) if np.isfinite(kurt) else np.nan)  # normal theory
        out["px"].append(int(m.sum()))
    a = {k: np.array(v) for k, v in out.items() if k != "labels"}
    return BinComparison(out["labels"], a["center"], a["sm"], a["sp"], a["lr"], a["se"], a["km"], a["kp"], a["sk"], a["px"])


def range_bins(z_m: np.ndarray) -> tuple[np.ndarray, dict[int, str]]:
    """0.25 m windows centred on multiples of 0.25 m, so a perpendicular stop falls in one window."""
    b = np.round(z_m / RANGE_BIN_M).astype(np.int64)
    return b, {int(k): f"{(k - 0.5) * RANGE_BIN_M:.3f}-{(k + 0.5) * RANGE_BIN_M:.3f} m" for k in np.unique(b)}


def range_radius_groups(d: ModelData) -> tuple[np.ndarray, dict[int, str]]:
    r_bin, r_labels = range_bins(d.z_m)
    rho = np.sqrt(d.rho2)
    q_bin = np.digitize(rho, RADIUS_EDGES[1:-1])
    g = r_bin * 10 + q_bin
    labels = {}
    for gg in np.unique(g):
        rb, qb = divmod(int(gg), 10)
        hi = RADIUS_EDGES[qb + 1]
        labels[int(gg)] = f"{r_labels[rb]}, rho {RADIUS_EDGES[qb]:.1f}-" + ("" if np.isinf(hi) else f"{hi:.1f}")
    return g, labels


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
