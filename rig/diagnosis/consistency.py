"""Does a fitted model predict every statistic the data measure, each within its own error?

The headline compares sigma only. A model can get sigma right and still be wrong: heavy tails
whose width scales with the noise leave sigma(Z) a pure power law while the kurtosis is three
times too large; noise shared by neighbouring pixels leaves each pixel's sigma right while the
frame's mean wanders far more than independent pixels allow. So the verdict checks every
family of statistics the model predicts, each bin against its own sampling error:

  sigma by range, by radius, by image position (8 x 6 tiles), by IR brightness, by incidence
      z = ln(sigma measured / sigma predicted) / se, se from the bin's degrees of freedom and kurtosis
  kurtosis by range
      z = (measured - predicted) / se, the measured kurtosis model-free (`ModelData.pixel_kurtosis`)
      and its se from the pixels' scatter
  fill rate by stop
      z = (measured - predicted) / se, se binomial over the stop's pixel-frames (the measured share's
      or the model's, the larger)
  frame mean by stop (time): the variance over frames of the frame's mean of 1/z
      predicted: sum(var / Z^4) / n_valid^2 from independent pixels, plus any common wander the
      model has (drift); z = ln(measured / predicted) / sqrt(2 / (frames - 1))
  lag-1 correlation by stop: the frames' pooled lag-1 correlation (rig.models.data.independence)
      predicted: 0 for independent noise, plus a slow common wander's share of the variance (drift);
      z = (measured - predicted) / se; absent for recordings that do not record it (not checked)

Each family is within noise when sum z^2 is consistent with chi^2 on as many degrees of freedom
as it has bins (p >= ALPHA / number of families: the family-wise false alarm rate is ALPHA).
"Within noise" is every family within noise; otherwise the worst family is named, with its
worst bin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models import ModelData
from ..models.data.independence import rho_and_se
from ..models.parts.result import chi2_sf
from .bins import BinComparison
from .stop_sums import StopSums

#: family-wise false-alarm rate of the verdict "within noise"
ALPHA = 1e-3


@dataclass
class Check:
    """One family of statistics: measured against predicted in bins, with z-scores.

    quantity: what is compared ("sigma", "kurtosis", "fill rate", "frame-mean variance");
    covariate: what the bins follow ("range", "radius", "position", "brightness", "incidence",
    "time"); measured, predicted and se are in the quantity's own units (se of the measured value).
    """

    quantity: str
    covariate: str
    labels: list[str]
    center: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    se: np.ndarray
    z: np.ndarray

    @property
    def name(self) -> str:
        return f"{self.quantity} by {self.covariate}" if self.covariate != "time" else "frame mean over time"

    @property
    def chi2(self) -> float:
        return float(np.sum(self.z**2))

    @property
    def dof(self) -> int:
        return len(self.z)

    @property
    def p_value(self) -> float:
        return float(chi2_sf(self.chi2, self.dof)) if self.dof else 1.0

    @property
    def excess_z(self) -> float:
        """How far beyond noise, as one number: (chi^2 - dof) / sqrt(2 dof)."""
        return (self.chi2 - self.dof) / np.sqrt(2 * max(self.dof, 1))

    def worst(self) -> int:
        return int(np.argmax(np.abs(self.z)))

    def describe_worst(self) -> str:
        if not len(self.z):  # e.g. kurtosis in a one-stop recording whose windows are all too small
            return f"{self.name}: no bin to compare"
        i = self.worst()
        fmt = (lambda v: f"{1000 * v:.4g} mm") if self.quantity == "sigma" else (lambda v: f"{v:.4g}")
        return (f"{self.quantity} at {self.labels[i]}: {fmt(self.measured[i])} measured, {fmt(self.predicted[i])} "
                f"predicted (+/- {fmt(self.se[i])}, {self.z[i]:+.1f} standard errors)")


def sigma_check(b: BinComparison, covariate: str) -> Check:
    return Check("sigma", covariate, b.labels, b.center, b.sigma_meas_m, b.sigma_pred_m, b.sigma_meas_m * b.se_log,
                 b.log_ratio / b.se_log)


def kurtosis_check(b: BinComparison) -> Check | None:
    ok = np.isfinite(b.kurt_meas) & np.isfinite(b.se_kurt) & (b.se_kurt > 0)
    if not ok.any():
        return None
    lab = [x for x, k in zip(b.labels, ok) if k]
    return Check("kurtosis", "range", lab, b.center[ok], b.kurt_meas[ok], b.kurt_pred[ok], b.se_kurt[ok],
                 (b.kurt_meas[ok] - b.kurt_pred[ok]) / b.se_kurt[ok])


def fill_check(d: ModelData, stops: StopSums) -> Check:
    """Each stop's fill rate against the model's mean over the stop's pixels, with its binomial standard error
    (the statistic the likelihood weighs, `rig.models.fitting.likelihood`)."""
    keys = sorted(stops.rows)
    rows = np.array([stops.rows[k] for k in keys]).reshape(len(keys), -1)
    count, fill, binomial, frames, predicted, z = (rows[:, i] for i in range(6))
    binomial_model = rows[:, 10]
    measured = fill / count
    # the binomial variance of the measured share and of the model's, the larger: when a model expects a few
    # samples lost of a million and none were, the measured share's variance is 0 (it was floored at one sample,
    # so 6.5 samples expected and none seen read as 6.5 standard errors; under the model it is 6.5 / sqrt(6.5))
    se = np.maximum(np.sqrt(np.maximum(binomial, binomial_model)) / count, 1.0 / frames)
    labels = [_stop_label(d, k) for k in keys]
    return Check("fill rate", "stop", labels, z / count, measured, predicted / count, se, (measured - predicted / count) / se)


def frame_mean_check(d: ModelData, stops: StopSums) -> Check | None:
    """The variance over frames of each stop's frame-mean series against what the model predicts: the sum over
    the stop's pixels of var / Z^4 (times a frame-mean gain) over n_valid^2, plus any common wander (drift)."""
    t = d.stops
    if t is None or not np.isfinite(t.series_var_inv2).any():
        return None
    labels, center, meas, predicted, se, dof = [], [], [], [], [], []
    for s in sorted(stops.rows):
        measured, n_valid, frames = t.series_var_inv2[s], t.n_valid[s], t.frames[s]
        if not (np.isfinite(measured) and np.isfinite(n_valid) and n_valid > 1 and frames > 3 and measured > 0):
            continue
        count, independent, common = stops.rows[s][0], stops.rows[s][6], stops.rows[s][7]
        # pixels that never changed (all samples on one depth level) are not in the data and add nothing
        expected = float(independent) / n_valid**2 + float(common / count)
        labels.append(_stop_label(d, s))
        center.append(d.median_range_by_stop[s])
        meas.append(measured)
        predicted.append(expected)
        se.append(measured * np.sqrt(2.0 / (frames - 1)))
        dof.append(frames - 1.0)
    if not labels:
        return None
    meas_a, pred_a = np.array(meas), np.array(predicted)
    z = np.log(meas_a / pred_a) / np.sqrt(2.0 / np.array(dof))
    return Check("frame-mean variance", "time", labels, np.array(center), meas_a, pred_a, np.array(se), z)


def lag1_check(d: ModelData, stops: StopSums) -> Check | None:
    """Each stop's pooled lag-1 correlation of the frames against the model's: every model's noise is drawn afresh
    each frame (0); a wander common to the stop's pixels (drift), slow against the frame interval, adds its share of
    the variance, sum (n - 1) var_common / sum (n - 1) var, about. None when the recording does not record it."""
    t = d.stops
    if t is None or t.lag1_num is None or not np.isfinite(t.lag1_num).any():
        return None
    labels, center, meas, predicted, se = [], [], [], [], []
    for s in sorted(stops.rows):
        rho, err = rho_and_se(t.lag1_num[s], t.lag1_den[s], t.lag1_pairs[s])
        row = stops.rows[s]
        if not np.isfinite(rho) or not row[9] > 0:
            continue
        labels.append(_stop_label(d, s))
        center.append(float(row[5] / row[0]))
        meas.append(rho)
        predicted.append(float(row[8] / row[9]))
        se.append(err)
    if not labels:
        return None
    m, p, e = np.array(meas), np.array(predicted), np.array(se)
    return Check("lag-1 correlation", "stop", labels, np.array(center), m, p, e, (m - p) / e)


def _stop_label(d: ModelData, s: int) -> str:
    if d.stops is not None and s < len(d.stops.label):
        return d.stops.label[s]
    return f"stop {s}"


@dataclass
class Consistency:
    """Every check of one fitted model."""

    checks: list[Check]
    alpha: float = ALPHA

    @property
    def threshold(self) -> float:
        return self.threshold_with(0)

    def threshold_with(self, extra: int) -> float:
        """The p-value a family needs when `extra` families are tested besides these (Bonferroni)."""
        return self.alpha / max(len(self.checks) + extra, 1)

    def failing(self, extra: int = 0) -> list[Check]:
        """The families beyond noise, worst first."""
        bad = [c for c in self.checks if c.p_value < self.threshold_with(extra)]
        return sorted(bad, key=lambda c: -c.excess_z)

    @property
    def within_noise(self) -> bool:
        return not self.failing()

    def within_noise_with(self, extra: int) -> bool:
        return not self.failing(extra)

    def worst(self, extra: int = 0) -> Check | None:
        bad = self.failing(extra)
        return bad[0] if bad else None

    def find(self, quantity: str, covariate: str) -> Check | None:
        return next((c for c in self.checks if c.quantity == quantity and c.covariate == covariate), None)
