"""What a spec is checked against, measured from one recording with rig's own estimators, as plain data (what a
worker process sends back: `measure`).

- sigma at a range: the paper's fit of `rig fit` (rig.analysis.fit_recording), sigma_Z = k Z^lambda, its error
  propagated from the fit's covariance of k and lambda (`sigma_at`); and, to check the fit against, each stop's own
  pooled sigma with its error (rig.diagnosis.bins.pooled_sigma, as `rig fit --plot` draws it);
- each stop's fill: the share of the frame's pixels with a valid depth over the stop's frames (every pixel counts,
  those never valid too), with the binomial error of the fit's fill term (rig.models.data.model_data.mean_fill);
- each stop's depth accuracy and its error: `rig fit`'s (rig.accuracy.stop_figures).

A stop's range is where the stage put the wall (its truth: measured, commanded or planned), else the median of its
pixels' mean range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from protocols.recording import Recording, RecordingError

from ..accuracy import accuracy_of
from ..analysis import fit_recording
from ..models.data.determinacy import lambda_status
from ..models.data.model_data import mean_fill


@dataclass(frozen=True)
class StopFigures:
    stop: str
    z_m: float  # the stop's range (see the module), m
    fill: float  # share of the frame's samples with a valid depth, 0-1
    fill_se: float
    depth_accuracy_pct: float = math.nan  # signed median of (Z - truth) / truth, % (NaN: truth unknown)
    depth_accuracy_se_pct: float = math.nan


@dataclass
class RecordingFigures:
    """One recording's figures, or why it has none (`error`)."""

    path: str
    error: str = ""
    notes: list[str] = field(default_factory=list)
    k: float = math.nan  # m^(1 - lambda)
    lam: float = math.nan
    covariance: list[list[float]] = field(default_factory=list)  # of (k, lambda)
    z_range_m: tuple[float, float] = (math.nan, math.nan)  # the fitted pixels' ranges, m
    lambda_problem: str = ""  # why lambda is not determined, and the fix ("" when it is)
    stops: list[StopFigures] = field(default_factory=list)
    #: each stop's (or, with one stop, each 0.25 m window's) measured sigma: (label, range m, sigma m, its error m)
    measured_sigma: list[tuple[str, float, float, float]] = field(default_factory=list)
    accuracy_why_not: str = ""  # why the accuracy is not measured ("" when it is)


def measure(path: str) -> RecordingFigures:
    """The figures of the recording at `path` (in a worker: plain data back; a recording that cannot be read or
    fitted is a one-line `error`)."""
    try:
        return _measure(path)
    except (ValueError, RecordingError, OSError) as e:
        return RecordingFigures(path, error=str(e).splitlines()[0] if str(e) else type(e).__name__)


def _measure(path: str) -> RecordingFigures:
    r = fit_recording(path)
    d = r.samples
    status = lambda_status(d)
    with Recording(path) as rec:
        protocol, params = rec.protocol, rec.protocol_params
        fills = {label: _frame_fill(rec, label) for label in d.stops.label}
    acc = accuracy_of(d, None, protocol, params)
    by_label = {s.stop: s for s in acc.stops}
    medians = {d.stops.label[s]: z for s, z in d.median_range_by_stop.items()}
    stops = []
    for i, label in enumerate(d.stops.label):
        truth = float(d.stops.truth_m[i]) if d.stops.truth_m is not None else math.nan
        z = truth if math.isfinite(truth) and truth > 0 else medians.get(label, math.nan)
        a = by_label.get(label)
        accuracy = (a.depth_accuracy_pct, a.depth_accuracy_se_pct) if a else ()
        stops.append(StopFigures(label, z, *fills[label], *accuracy))
    cov = r.fit.covariance if r.fit.covariance is not None else np.full((2, 2), np.nan)
    return RecordingFigures(
        path, notes=list(r.notes), k=r.fit.k, lam=r.fit.lam, covariance=np.asarray(cov, float).tolist(),
        z_range_m=tuple(float(z) for z in r.fit.z_range_m),
        lambda_problem="" if status.determined else f"{status.reason}; record stops over a wider range",
        stops=stops, measured_sigma=[(label, float(z), float(sg), float(se)) for label, z, sg, se in
                                     zip(r.measured.label, r.measured.z_m, r.measured.sigma_m, r.measured.se_sigma_m)],
        accuracy_why_not=acc.why_not or ("" if acc.stops else "no stop says where the wall was"))


def _frame_fill(rec: Recording, label: str) -> tuple[float, float]:
    """(fill, its error) of one stop: every pixel of the frame, its share of the stop's frames with a valid depth."""
    s = rec.stop(label, third_moment=False)
    frames = max(s.n_frames, 1)
    count = np.asarray(s.stats.count, float).ravel()
    fill, se = mean_fill(count / frames, np.full(count.shape, float(frames)), np.zeros(count.shape, np.intp), 1)
    return float(fill[0]), float(se[0])


def sigma_at(f: RecordingFigures, z_m: float) -> tuple[float, float]:
    """(sigma_Z, its standard error) at range `z_m`, m, from the fit: sigma = k Z^lambda (the paper's eq. for the
    range error), and by the delta method on ln sigma = ln k + lambda ln Z, var(ln sigma) = var k / k^2
    + 2 ln Z cov(k, lambda) / k + ln^2 Z var lambda."""
    sigma = f.k * z_m**f.lam
    c = np.asarray(f.covariance, float)
    if c.shape not in ((1, 1), (2, 2)):
        return sigma, math.nan
    ln_z = math.log(z_m)
    var_ln = c[0, 0] / f.k**2  # lambda fixed: k's alone
    if c.shape == (2, 2):
        var_ln += 2 * ln_z * c[0, 1] / f.k + ln_z**2 * c[1, 1]
    return sigma, sigma * math.sqrt(var_ln) if var_ln >= 0 else math.nan
