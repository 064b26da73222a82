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
from numba import njit

from ..models import ModelData, Prediction
from ..models.data.model_data import RANGE_BIN_M, range_bin_index
from ..models.data.group_sums import group_sums
from ..models.data.shape_statistics import pooled_from_sums

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


#: the per-pixel columns a bin sums (`pixel_columns`), then the family's own: nu times its covariate
COLUMNS = ("pixels", "nu", "m2", "weight", "n_excess", "n_usable", "w2_nu", "w2_n", "shared",
           "k_count", "k_w", "k_wb", "k_w2", "k_w2b", "k_w2b2")


@njit(cache=True, nogil=True, inline="always")
def pixel_columns(nu_i, m2_i, v, k4_i, has_k4, use, beta_i, n_i, g_shared):  # pragma: no cover - compiled
    """The quantities every bin pools, for one pixel, as a tuple (COLUMNS): pixels, nu, M2; with weight = nu
    var_pred (`v`), the weight, n excess_pred and n where the pixel's kurtosis is usable (`use`); weight^2 (2 / nu)
    shared and weight^2 / n shared for the sampling error; the sharing factor; and the pooling sums of the usable
    pixels' kurtosis estimate b (`beta_i`) with weight w = n (count, w, w b, w^2, w^2 b, w^2 b^2). Noise shared by
    neighbouring pixels (a frame-mean gain A = `g_shared` > 1, rig.models.effects.empirical) makes their variances
    co-vary: for a Gaussian-shaped correlation, the sum over neighbours of rho^2 is about (A - 1) / 2."""
    shared = max(1.0 + (g_shared - 1.0) / 2.0, 1.0)
    weight = nu_i * v
    w2s = weight * weight * shared
    w = n_i if use else 0.0
    b = beta_i if use else 0.0
    wb = w * b
    return (1.0, nu_i, m2_i, weight, w * (k4_i / (v * v) if has_k4 else 0.0), w, w2s * 2.0 / nu_i, w2s / n_i, shared,
            1.0 if use else 0.0, w, wb, w * w, wb * w, wb * wb)


@njit(cache=True, nogil=True, inline="always")
def plus_columns(a, x):  # pragma: no cover - compiled
    """A run's `pixel_columns` sums `a` with one more pixel's `x`, element by element: tuples, which stay in
    registers where a small array would not."""
    return (a[0] + x[0], a[1] + x[1], a[2] + x[2], a[3] + x[3], a[4] + x[4], a[5] + x[5], a[6] + x[6], a[7] + x[7],
            a[8] + x[8], a[9] + x[9], a[10] + x[10], a[11] + x[11], a[12] + x[12], a[13] + x[13], a[14] + x[14])


@njit(cache=True, nogil=True, inline="always")
def add_run(row, a, ax):  # pragma: no cover - compiled
    """A run's summed `pixel_columns` `a` and nu x covariate `ax` into a bin's `row`."""
    for j in range(15):
        row[j] += a[j]
    row[15] += ax


def pixel_inputs(d: ModelData, pred: Prediction) -> tuple:
    """What `pixel_columns` reads of each row of `d` and its prediction, as the compiled passes take it: nu, M2, the
    predicted variance and fourth cumulant (and whether there is one), whether the kurtosis is usable, the kurtosis
    estimate (0 where none), n, and the frame-mean gain (one value, or one a row)."""
    k4 = pred.k4_m4
    return (np.ascontiguousarray(d.nu, dtype=float), np.ascontiguousarray(d.m2_m2, dtype=float),
            np.ascontiguousarray(pred.var_m2, dtype=float),
            np.zeros(1) if k4 is None else np.ascontiguousarray(np.broadcast_to(k4, (len(d),)), dtype=float),
            k4 is not None, np.ascontiguousarray(d.kurtosis_usable),
            np.ascontiguousarray(np.nan_to_num(d.pixel_kurtosis), dtype=float), np.ascontiguousarray(d.n, dtype=float),
            per_row(pred.frame_mean_gain))


def per_row(x: np.ndarray | float | None) -> np.ndarray:
    """A prediction's term as the compiled passes take it: one value for every row (None: 1), or one a row."""
    return np.ascontiguousarray(np.atleast_1d(np.asarray(1.0 if x is None else x, dtype=float)))


@njit(cache=True, nogil=True)
def _group_sums(groups, cov, nu, m2, var, k4, has_k4, usable, beta, n, gain, lo, out, counts):  # pragma: no cover
    """Each row's `pixel_columns`, then nu times its covariate, into `out[groups[i] - lo]` (negative groups left
    out); a run of rows in one bin is summed first, in registers."""
    size = counts.size
    zero15 = (0.0,) * 15
    a, ax, run, count = zero15, 0.0, -1, 0
    for i in range(groups.size):
        g = groups[i] - lo
        if groups[i] < 0 or g >= size:
            continue
        if g != run:
            if count > 0:
                add_run(out[run], a, ax)
                counts[run] += count
            a, ax, run, count = zero15, 0.0, g, 0
        x = pixel_columns(nu[i], m2[i], var[i], k4[i] if has_k4 else 0.0, has_k4, usable[i], beta[i], n[i],
                          gain[i] if gain.size > 1 else gain[0])
        a = plus_columns(a, x)
        ax += nu[i] * cov[i]
        count += 1
    if count > 0:
        add_run(out[run], a, ax)
        counts[run] += count


class BinSums:
    """The sums `compare_bins` pools in each bin (COLUMNS, and nu times the covariate), added chunk by chunk;
    rows with a negative label are left out."""

    def __init__(self) -> None:
        self.sums: dict[int, np.ndarray] = {}

    def add(self, d: ModelData, pred: Prediction, groups: np.ndarray, covariate: np.ndarray) -> None:
        """Add the rows of `d` with their prediction: their bin labels (negative: left out) and covariate, in one
        compiled pass (`_group_sums`)."""
        groups = np.ascontiguousarray(groups, dtype=np.int64)
        valid = groups[groups >= 0]
        if valid.size == 0:
            return
        lo = int(valid.min())
        out = np.zeros((int(valid.max()) - lo + 1, len(COLUMNS) + 1))
        counts = np.zeros(len(out), np.int64)
        _group_sums(groups, np.ascontiguousarray(np.nan_to_num(np.broadcast_to(covariate, groups.shape)), dtype=float),
                    *pixel_inputs(d, pred), lo, out, counts)
        for g in np.flatnonzero(counts).tolist():
            key = lo + g
            self.sums[key] = self.sums[key] + out[g] if key in self.sums else out[g].copy()

    def finish(self, labels_of: dict[int, str] | None = None) -> BinComparison:
        out: dict[str, list] = {k: [] for k in ("labels", "center", "sm", "sp", "lr", "se", "km", "kp", "sk", "px")}
        for g in sorted(self.sums):
            (px, W, m2, nu_var, n_excess, n_use, w2_nu, w2_n, shared, k_count, k_w, k_wb, k_w2, k_w2b, k_w2b2,
             nu_x) = self.sums[g]
            if px < MIN_PIXELS_PER_BIN:
                continue
            var_meas, var_pred = m2 / W, nu_var / W
            kurt, se_kurt = (pooled_from_sums(k_count, k_w, k_wb, k_w2, k_w2b, k_w2b2) if k_count >= MIN_PIXELS_PER_BIN
                             else (np.nan, np.nan))
            excess = (kurt - 3) if np.isfinite(kurt) else 0.0
            # var(pooled variance) / pooled^2; pixels weighted by their predicted variance, so a bin that pools
            # stops of very different sigma gets the few degrees of freedom that dominate it
            var_s2 = (w2_nu + excess * w2_n) / nu_var**2
            out["labels"].append(labels_of.get(int(g), str(g)) if labels_of else str(g))
            out["center"].append(float(nu_x / W))
            out["sm"].append(np.sqrt(var_meas))
            out["sp"].append(np.sqrt(var_pred))
            out["lr"].append(0.5 * np.log(var_meas / var_pred))
            out["se"].append(0.5 * np.sqrt(max(var_s2, 1e-30)))
            out["km"].append(kurt)
            out["kp"].append(3 + float(n_excess / max(n_use, 1e-300)))
            out["sk"].append(se_kurt * np.sqrt(float(shared / px)))
            out["px"].append(int(px))
        a = {k: np.array(v, dtype=float) for k, v in out.items() if k != "labels"}
        return BinComparison(out["labels"], a["center"], a["sm"], a["sp"], a["lr"], a["se"], a["km"], a["kp"], a["sk"],
                             a["px"].astype(int))


def compare_bins(d: ModelData, pred: Prediction, groups: np.ndarray, covariate: np.ndarray,
                 labels_of: dict[int, str] | None = None) -> BinComparison:
    """Pool measured and predicted variance (and kurtosis) within each group (integer labels; negative: left out)."""
    sums = BinSums()
    sums.add(d, pred, np.asarray(groups).astype(np.int64), np.asarray(covariate, dtype=float))
    return sums.finish(labels_of)


def subset(pred: Prediction, mask: np.ndarray) -> Prediction:
    """The prediction for the rows where `mask` is true (scalars stay scalars)."""
    def part(x):
        return x[mask] if isinstance(x, np.ndarray) and x.ndim else x

    return Prediction(part(pred.shot_m2), part(pred.illum), part(pred.image_terms), part(pred.var_m2),
                      part(pred.k4_m4), part(pred.fill), part(pred.common_inv2), part(pred.frame_mean_gain))


def range_labels(windows) -> dict[int, str]:
    """Labels of 0.25 m range windows (`range_bin_index`): '0.875-1.125 m'."""
    return {int(k): f"{(k - 0.5) * RANGE_BIN_M:.3f}-{(k + 0.5) * RANGE_BIN_M:.3f} m" for k in windows}


def range_bins(z_m: np.ndarray) -> tuple[np.ndarray, dict[int, str]]:
    """0.25 m windows centred on multiples of 0.25 m, so a perpendicular stop falls in one window."""
    b = range_bin_index(z_m)
    return b, range_labels(np.unique(b))


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
    w = np.maximum(samples.dof, 0.0)
    keys, sums = group_sums(np.asarray(groups).astype(np.int64), [w, np.where(w > 0, samples.m2_m2, 0.0), w * samples.z_m])
    z, s, se, d, lab = [], [], [], [], []
    for g, (W, M, WZ) in zip(keys.tolist(), sums):
        if W <= 0:
            continue
        sig = np.sqrt(M / W)
        z.append(float(WZ / W))
        s.append(sig)
        se.append(sig / np.sqrt(2 * W))
        d.append(W)
        lab.append(labels[int(g)] if labels is not None else str(g))
    return BinnedSigma(np.array(z), np.array(s), np.array(se), np.array(d), lab)


def sigma_by_range(samples: ModelData, width_m: float = 0.25) -> BinnedSigma:
    """Pooled sigma in range windows of `width_m` (the paper's 0.25 m windows)."""
    idx = np.floor(samples.z_m / width_m).astype(np.int64)
    return pooled_sigma(samples, idx)
