"""The composite log-likelihood of a model's prediction, evaluated stop by stop.

Three parts:
- Each pixel's sample variance s2 is Gamma-distributed with mean sigma^2 (the model's variance)
  and var(s2) = sigma^4 (2 / nu + excess / n), the excess kurtosis measured (model-free) in the
  pixel's range window; with excess = 0 this is exactly the paper's Gaussian likelihood of the
  samples about the pixel means (paper, "Experimental parameter estimation"). Per pixel, with shape
  a: a ln(a s2 / sigma^2) - a s2 / sigma^2 - ln Gamma(a) - ln s2; the terms of the data alone are
  summed once (`gamma_constant`).
- The measured kurtosis of each range window is normal about the kurtosis the model predicts
  (3 plus its fourth cumulant over sigma^4, averaged over the window's usable pixels by their
  samples), with its own standard error: heavy tails (outliers) or truncation (censoring) show
  there, and a model cannot buy tolerance for a wrong variance by claiming a scatter the data do
  not have.
- Each stop's fill rate (the share of its pixel-frames with a sample) is normal about the model's
  mean over the stop's pixels, with its binomial standard error: samples a model says are dropped
  (censoring) must be missing.

Every part is a sum over pixels (or a ratio of sums per window and per stop), so a model is
evaluated stop by stop (`model_loglik`) with arrays the size of one stop, and the same sums serve
grouped data (`rig.models.fitting.grouping`), whose rows carry the weights of the pixels they stand for:
`likelihood_weights` gives, per row, a (the Gamma shape), b (a s2), the kurtosis weight (n where
the pixel's kurtosis is usable) and the pixel count.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numba import njit
from scipy.special import gammaln

from ..parts.tangents import Tangents

if TYPE_CHECKING:
    from ..parts.component import ComposedModel
    from ..data.model_data import ModelData
    from ..parts.prediction import Prediction


def likelihood_weights(d: ModelData) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | float]:
    """Per row: (a, b, kurtosis weight, pixels); grouped data carry their own (`rig.models.fitting.grouping`)."""
    own = getattr(d, "weights", None)
    if own is not None:
        return own
    return d.gamma_shape, d.gamma_b, d.kurtosis_weight, 1.0


def pixel_weights(d: ModelData) -> np.ndarray | float:
    """How many pixels each row stands for: 1 for pixels, the node weights for grouped data."""
    own = getattr(d, "weights", None)
    return own[3] if own is not None else 1.0


def gamma_constant(d: ModelData) -> float:
    """The data-only terms of the Gamma log-likelihood: sum of a ln a - ln Gamma(a) + (a - 1) ln s2."""
    own = getattr(d, "constant", None)
    if own is not None:
        return own
    cached = d.__dict__.get("gamma_constant")
    if cached is None:
        a = d.gamma_shape
        cached = d.__dict__["gamma_constant"] = float(np.sum(a * np.log(a) - gammaln(a) + (a - 1) * np.log(d.s2_m2)))
    return cached


def gamma_constant_by_stop(d: ModelData) -> tuple[np.ndarray, np.ndarray]:
    """(stops, each stop's share of `gamma_constant`), kept with `d`: the constant of some of its stops is a sum."""
    cached = d.__dict__.get("gamma_constant_by_stop")
    if cached is None:
        a = d.gamma_shape
        terms = a * np.log(a) - gammaln(a) + (a - 1) * np.log(d.s2_m2)
        sums = np.bincount(d.stop, weights=terms)
        present = np.bincount(d.stop) > 0
        cached = d.__dict__["gamma_constant_by_stop"] = (np.flatnonzero(present), sums[present])
    return cached


class LoglikSums:
    """The sums the composite log-likelihood is made of, added chunk by chunk (see the module docstring).

    `data` is the whole data: its measured kurtosis by range window and fill rate by stop are what the
    predictions are compared with."""

    def __init__(self, data: ModelData):
        self.windows, self.kurt_measured, self.kurt_se = data.kurtosis_by_range
        self.stops, self.fill_measured, self.fill_se = _fill_table(data)
        self.gamma = 0.0
        self.constant = 0.0
        self.kurt_num = np.zeros(len(self.windows))
        self.kurt_den = np.zeros(len(self.windows))
        self.fill_sum = np.zeros(len(self.stops))
        self.fill_count = np.zeros(len(self.stops))

    def add(self, d: ModelData, var: np.ndarray, k4: np.ndarray | None, fill: np.ndarray | float | None,
            *, constant: bool = False) -> None:
        """Add the rows of `d` (a chunk of the data, or all of it) with their predicted variance, fourth
        cumulant and fill; with `constant`, also their data-only Gamma terms."""
        self._add(d, var, k4, fill, constant, None)

    def _add(self, d: ModelData, var: np.ndarray, k4: np.ndarray | None, fill: np.ndarray | float | None,
             constant: bool, t: Tangents | None) -> None:
        a, b, kw, pw = likelihood_weights(d)
        if constant:
            self.constant += gamma_constant(d)
        window_pos, stop_pos = self._positions(d)
        var = np.ascontiguousarray(var, dtype=float)
        none = _NO_TANGENT
        tv, tk4, tf = (none, none, none) if t is None else (_rows(t.var, var.size), _rows(t.k4, var.size), _rows(t.fill, var.size))
        self.gamma += _accumulate(
            np.ascontiguousarray(a, dtype=float), np.ascontiguousarray(b, dtype=float), var,
            _ONE if k4 is None else np.ascontiguousarray(np.broadcast_to(k4, var.shape), dtype=float), k4 is not None,
            np.atleast_1d(np.asarray(1.0 if fill is None else fill, dtype=float)), np.ascontiguousarray(kw, dtype=float),
            np.atleast_1d(np.asarray(pw, dtype=float)), window_pos, stop_pos,
            self.kurt_num, self.kurt_den, self.fill_sum, self.fill_count,
            tv, tk4, tf, self.g_gamma if t is not None else _NO_SUM, self.g_num if t is not None else none,
            self.g_fill if t is not None else none)

    def add_with_tangent(self, d: ModelData, pred: Prediction, t: Tangents) -> None:
        """`add` the rows of `d` with their prediction, and their share of the gradient: the prediction's derivatives
        `t` (`rig.models.parts.tangents`) times the likelihood's own, d/d var of the Gamma terms, and the kurtosis windows'
        and stops' sums' derivatives; one compiled pass over the rows (`_accumulate`)."""
        if not hasattr(self, "g_gamma"):
            self.g_gamma = np.zeros(t.m)
            self.g_num = np.zeros((t.m, len(self.windows)))
            self.g_fill = np.zeros((t.m, len(self.stops)))
        self._add(d, pred.var_m2, pred.k4_m4, pred.fill, False, t)

    def gradient(self) -> np.ndarray:
        """d `total()` / d parameters, from the sums `add_with_tangent` made."""
        g = self.g_gamma.copy()
        if len(self.windows):
            den = np.maximum(self.kurt_den, 1e-300)
            predicted = 3.0 + self.kurt_num / den
            z = (self.kurt_measured - predicted) / self.kurt_se
            g += self.g_num @ (z / self.kurt_se / den)  # d(-z^2 / 2) = z / se d predicted
        seen = self.fill_count > 0
        if seen.any():
            z = (self.fill_measured[seen] - self.fill_sum[seen] / self.fill_count[seen]) / self.fill_se[seen]
            g += self.g_fill[:, seen] @ (z / self.fill_se[seen] / self.fill_count[seen])
        return g

    def _positions(self, d: ModelData) -> tuple[np.ndarray, np.ndarray]:
        """Each row's index among the measured kurtosis windows (-1: none) and among the stops; kept with `d`."""
        key = (id(self.windows), len(self.windows), id(self.stops))
        cached = d.__dict__.get("loglik_positions")
        if cached is not None and cached[0] == key:
            return cached[1], cached[2]
        if len(self.windows):
            pos = np.minimum(np.searchsorted(self.windows, d.range_group), len(self.windows) - 1)
            window_pos = np.where(self.windows[pos] == d.range_group, pos, -1).astype(np.int64)
        else:
            window_pos = np.full(len(d), -1, np.int64)
        stop_pos = np.searchsorted(self.stops, d.stop).astype(np.int64)
        d.__dict__["loglik_positions"] = (key, window_pos, stop_pos)
        return window_pos, stop_pos

    def total(self) -> float:
        kurt = 0.0
        if len(self.windows):
            predicted = 3.0 + self.kurt_num / np.maximum(self.kurt_den, 1e-300)
            z = (self.kurt_measured - predicted) / self.kurt_se
            kurt = float(-0.5 * np.sum(z * z))
        fill = 0.0
        seen = self.fill_count > 0
        if seen.any():
            z = (self.fill_measured[seen] - self.fill_sum[seen] / self.fill_count[seen]) / self.fill_se[seen]
            fill = float(-0.5 * np.sum(z * z))
        return self.gamma + self.constant + kurt + fill


_ONE = np.ones(1)
#: a tangent that is zero for every parameter (None in `Tangents`), and the sums of no gradient: one compiled variant
_NO_TANGENT = np.zeros((0, 0))
_NO_SUM = np.zeros(0)


def _rows(t: np.ndarray | None, n: int) -> np.ndarray:
    """A tangent as the (parameters, rows) C-contiguous float array `_accumulate` takes; `_NO_TANGENT` for None."""
    if t is None:
        return _NO_TANGENT
    return np.ascontiguousarray(t, dtype=float) if t.shape[-1] == n else np.ascontiguousarray(np.broadcast_to(t, (t.shape[0], n)), dtype=float)


@njit(cache=True, nogil=True)
def _accumulate(a, b, var, k4, has_k4, fill, kw, pw, window_pos, stop_pos, kurt_num, kurt_den, fill_sum,
                fill_count, tv, tk4, tf, g_gamma, g_num, g_fill):  # pragma: no cover - compiled
    """One pass over the rows: returns sum(-a ln var - b / var) and adds into the kurtosis windows' sums of kw
    k4 / var^2 and kw, and the stops' sums of pixels x fill and pixels (`fill`, `pw`: one value, or one per row).

    With tangents (`tv`, `tk4`, `tf`: d var, d k4, d fill per parameter and row; empty when zero), also the
    gradient's sums: g_gamma += d var (b / var - a) / var (d/d var of -(a ln var + b / var)); per window,
    g_num += kw (d k4 / var^2 - 2 k4 d var / var^3) (d of kw k4 / var^2); per stop, g_fill += pixels x d fill."""
    gamma = 0.0
    lost = 0.0  # Neumaier's compensation: a plain running sum's rounding would be noise to the optimiser
    m = g_gamma.size
    has_tv, has_tk4, has_tf = tv.shape[0] > 0, tk4.shape[0] > 0, tf.shape[0] > 0
    for i in range(var.size):
        v = var[i]
        term = -(a[i] * np.log(v) + b[i] / v)
        t = gamma + term
        if abs(gamma) >= abs(term):
            lost += (gamma - t) + term
        else:
            lost += (term - t) + gamma
        gamma = t
        if has_tv:
            coef = (b[i] / v - a[i]) / v
            for j in range(m):
                g_gamma[j] += tv[j, i] * coef
        w = window_pos[i]
        if w >= 0:  # grouped nodes may carry negative weights (a quadrature rule)
            kurt_den[w] += kw[i]
            if has_k4:
                kurt_num[w] += kw[i] * k4[i] / (v * v)
            if m > 0 and kw[i] != 0.0:
                if has_tk4:
                    c4 = kw[i] / (v * v)
                    for j in range(m):
                        g_num[j, w] += tk4[j, i] * c4
                if has_tv and has_k4:
                    cv = -2.0 * kw[i] * k4[i] / (v * v * v)
                    for j in range(m):
                        g_num[j, w] += tv[j, i] * cv
        p = pw[i] if pw.size > 1 else pw[0]
        s = stop_pos[i]
        fill_sum[s] += p * (fill[i] if fill.size > 1 else fill[0])
        fill_count[s] += p
        if has_tf:
            for j in range(m):
                g_fill[j, s] += tf[j, i] * p
    return gamma + lost


def _fill_table(d: ModelData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stop indices, measured fill, its standard error), one entry per stop, from the whole data."""
    own = d.__dict__.get("fill_table")  # grouped data carry the whole data's
    if own is None:
        _, measured, se = d.fill_by_stop
        own = d.__dict__["fill_table"] = (np.unique(d.stop), measured, se)
    return own


def loglik(d: ModelData, var: np.ndarray, k4: np.ndarray | None, fill: np.ndarray | float | None = None) -> float:
    """The composite log-likelihood of one prediction for every row of `d`."""
    sums = LoglikSums(d)
    sums.add(d, var, k4, fill, constant=False)
    return sums.total() + gamma_constant(d)


def model_loglik(model: ComposedModel, values: dict[str, float], d: ModelData) -> float:
    """The composite log-likelihood of `model` with parameter `values`, evaluated stop by stop."""
    prepare(d)
    sums = LoglikSums(d)
    for c in d.pieces():
        pred: Prediction = model.predict(values, c)
        sums.add(c, pred.var_m2, pred.k4_m4, pred.fill)
    return sums.total() + gamma_constant(d)


def model_loglik_gradient(model: ComposedModel, values: dict[str, float], d: ModelData,
                          names: list[str]) -> tuple[float, np.ndarray]:
    """`model_loglik` and its gradient over the parameters `names`, analytic (`rig.models.parts.tangents`): the model's
    base and every effect must carry their derivatives (`tangents.analytic`)."""
    prepare(d)
    sums = LoglikSums(d)
    for c in d.pieces():
        t = Tangents(names, len(c))
        pred: Prediction = model.predict(values, c, t)
        sums.add_with_tangent(c, pred, t)
    if not hasattr(sums, "g_gamma"):
        return sums.total() + gamma_constant(d), np.zeros(len(names))
    return sums.total() + gamma_constant(d), sums.gradient()


def prepare(d: ModelData) -> None:
    """Compute, once, what every evaluation uses, so the chunks of `d` share it instead of each making its own."""
    if getattr(d, "weights", None) is not None:
        return
    for name in ("nu", "s2_m2", "z0_m", "ln_z0_m", "range_group", "kurtosis_usable", "gamma_shape", "gamma_b",
                 "kurtosis_weight", "kurtosis_by_range", "fill_by_stop"):
        getattr(d, name)
    _fill_table(d)
    # the rows' positions among the windows and stops, for all of `d`: its pieces take slices of them (ModelData._taken)
    # instead of searching again in every evaluation (on a sweep, 548 new pieces an exact log-likelihood)
    LoglikSums(d)._positions(d)
