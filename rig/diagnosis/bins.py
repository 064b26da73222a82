"""Measured sigma and kurtosis pooled in bins (by stop, range, radius, brightness, incidence), against a model.

Within a bin the measured variance is pooled, sum M2 / sum (n - 1), and so is the predicted one
(weighted by degrees of freedom); their ratio's sampling error uses the bin's measured kurtosis.

Kurtosis: the bin's is the samples-weighted mean of its pixels' unbiased estimates
(`ModelData.pixel_kurtosis`, standardised by what the neighbours measure, not by a model);
its standard error comes from their scatter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models import ModelData, Prediction
from ..models.data import RANGE_BIN_M, range_bin_index
from ..models.shape_statistics import pooled_kurtosis

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
    """Pool measured and predicted variance (and kurtosis) within each group (integer labels)."""
    nu, n = d.nu, d.n
    m2 = d.s2_m2 * nu
    var_p = pred.var_m2
    excess_p = (pred.k4_m4 / var_p**2) if pred.k4_m4 is not None else np.zeros(len(d))
    beta = d.pixel_kurtosis
    usable = d.kurtosis_usable
    # noise shared by neighbouring pixels (a frame-mean gain A > 1, rig.models.empirical) makes their variances
    # co-vary: for a Gaussian-shaped correlation, sum over neighbours of rho^2 is about (A - 1) / 2
    shared = 1.0 + (np.broadcast_to(np.asarray(pred.frame_mean_gain, dtype=float), var_p.shape) - 1.0) / 2.0
    shared = np.maximum(shared, 1.0)
    out: dict[str, list] = {k: [] for k in ("labels", "center", "sm", "sp", "lr", "se", "km", "kp", "sk", "px")}
    for g in np.unique(groups):
        m = groups == g
        if m.sum() < MIN_PIXELS_PER_BIN:
            continue
        W = nu[m].sum()
        var_meas = m2[m].sum() / W
        var_pred = (nu[m] * var_p[m]).sum() / W
        mk = m & usable
        kurt, se_kurt = pooled_kurtosis(beta[mk], n[mk]) if mk.sum() >= MIN_PIXELS_PER_BIN else (np.nan, np.nan)
        excess = (kurt - 3) if np.isfinite(kurt) else 0.0
        # var(pooled variance) / pooled^2; pixels weighted by their predicted variance, so a bin that pools
        # stops of very different sigma gets the few degrees of freedom that dominate it
        weight = nu[m] * var_p[m]
        var_s2 = np.sum(weight**2 * (2 / nu[m] + excess / n[m]) * shared[m]) / np.sum(weight) ** 2
        out["labels"].append(labels_of.get(int(g), str(g)) if labels_of else str(g))
        out["center"].append(float((nu[m] * covariate[m]).sum() / W))
        out["sm"].append(np.sqrt(var_meas))
        out["sp"].append(np.sqrt(var_pred))
        out["lr"].append(0.5 * np.log(var_meas / var_pred))
        out["se"].append(0.5 * np.sqrt(max(var_s2, 1e-30)))
        out["km"].append(kurt)
        out["kp"].append(3 + float((n[mk] * excess_p[mk]).sum() / max(n[mk].sum(), 1e-300)))
        out["sk"].append(se_kurt * np.sqrt(float(np.mean(shared[m]))))
        out["px"].append(int(m.sum()))
    a = {k: np.array(v) for k, v in out.items() if k != "labels"}
    return BinComparison(out["labels"], a["center"], a["sm"], a["sp"], a["lr"], a["se"], a["km"], a["kp"], a["sk"], a["px"])


def range_bins(z_m: np.ndarray) -> tuple[np.ndarray, dict[int, str]]:
    """0.25 m windows centred on multiples of 0.25 m, so a perpendicular stop falls in one window."""
    b = range_bin_index(z_m)
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
class BinnedSigma:
    """Measured sigma_Z per range bin (or per stop) with its standard error."""

    z_m: np.ndarray  # degrees-of-freedom-weighted mean range of the bin, m
    sigma_m: np.ndarray  # pooled sigma = sqrt(sum M / sum w), m
    se_sigma_m: np.ndarray  # sigma / sqrt(2 sum w): Cramer-Rao bound under normality
    dof: np.ndarray
    label: list[str]


def pooled_sigma(samples: ModelData, groups: np.ndarray, labels: list[str] | None = None) -> BinnedSigma:
    """Pool the variance within each group (e.g. stop index or range bin)."""
    keys = np.unique(groups)
    z, s, se, d, lab = [], [], [], [], []
    for g in keys:
        m = (groups == g) & (samples.dof > 0)
        w = samples.dof[m]
        W = w.sum()
        if W <= 0:
            continue
        sig = np.sqrt(samples.m2_m2[m].sum() / W)
        z.append(float(np.sum(w * samples.z_m[m]) / W))
        s.append(sig)
        se.append(sig / np.sqrt(2 * W))
        d.append(W)
        lab.append(labels[int(g)] if labels is not None else str(g))
    return BinnedSigma(np.array(z), np.array(s), np.array(se), np.array(d), lab)


def sigma_by_range(samples: ModelData, width_m: float = 0.25) -> BinnedSigma:
    """Pooled sigma in range windows of `width_m` (the paper's 0.25 m windows)."""
    idx = np.floor(samples.z_m / width_m).astype(np.int64)
    return pooled_sigma(samples, idx)
