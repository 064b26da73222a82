"""Warm-up: how fast the camera's depth still drifts, judged from the frame mean depth over a sliding window.

A stereo head's depth drifts while it warms up (the projector and the sensor heat it, the baseline and the
rectification move). Before the first stop the runner streams frames with the run's settings into
`wait_until_warm`, which feeds each frame's mean valid depth, in mm, at its device time to a `DriftWindow`; the
camera is warm when the drift of the last `window_s` seconds is shown to be below the threshold.

The rule (`DriftEstimate.warm`): fit mean_mm = a + b t over the window by least squares (scipy.stats.linregress);
inflate the slope's standard error for the residuals' lag-1 autocorrelation r1 (AR(1) residuals: effective
n_e = n (1 - r1) / (1 + r1), s.e. x sqrt((n - 2) / (n_e - 2)); Santer et al. 2008, Int. J. Climatol. 28:1703,
eqs. 3-6), so a temporal filter or a slow wander cannot make the slope look better known than it is; the camera
is warm when the slope's 95 % interval lies inside +-threshold: |b| + t(0.975, n_e - 2) s.e. <= threshold.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from .plan import WarmUp

#: the interval the rule demands inside +-threshold: two-sided 95 %
CONFIDENCE = 0.95
#: fewer effective samples than this: the slope is not judged (the camera is not called warm)
MIN_EFFECTIVE_SAMPLES = 5
#: the drift is judged (and shown) once per this many seconds of the camera's clock
CHECK_S = 1.0

#: what the wait tells a progress display: (kind, text, summary); kind "warm_up" while waiting, "message" when warm
Report = Callable[[str, str, dict], None]


class StillDrifting(Exception):
    """The camera is not warm after the step's max_s; the message says how far it is and what to do."""


@dataclass(frozen=True)
class DriftEstimate:
    """The frame mean depth's drift over one window.

    drift_mm_per_min: the least-squares slope (positive: the depth grows); se_mm_per_min: its standard error,
    inflated for autocorrelation; n_frames: frames in the window; n_effective: n_e of the rule; span_s: the
    window's length in device time.
    """

    drift_mm_per_min: float
    se_mm_per_min: float
    n_frames: int
    n_effective: float
    span_s: float

    @property
    def bound_mm_per_min(self) -> float:
        """The far end of the slope's 95 % interval from zero: |b| + t(0.975, n_e - 2) s.e. (inf when not judged)."""
        if not self.n_effective >= MIN_EFFECTIVE_SAMPLES or not math.isfinite(self.se_mm_per_min):
            return math.inf
        from scipy.stats import t

        return abs(self.drift_mm_per_min) + float(t.ppf(0.5 + CONFIDENCE / 2, self.n_effective - 2)) * self.se_mm_per_min

    def warm(self, threshold_mm_per_min: float) -> bool:
        """The drift is shown to be below the threshold: its 95 % interval lies inside +-threshold."""
        return self.bound_mm_per_min <= threshold_mm_per_min

    def text(self) -> str:
        return f"{self.drift_mm_per_min:+.3g} +/- {self.se_mm_per_min:.2g} mm/min"


def drift_estimate(t_s: np.ndarray, mean_mm: np.ndarray) -> DriftEstimate:
    """The drift of `mean_mm` (mm) sampled at `t_s` (s), by the rule in the module's docstring."""
    from scipy.stats import linregress

    t_s, mean_mm = np.asarray(t_s, float), np.asarray(mean_mm, float)
    n = t_s.size
    span = float(t_s[-1] - t_s[0]) if n else 0.0
    if n < MIN_EFFECTIVE_SAMPLES or span <= 0:
        return DriftEstimate(math.nan, math.inf, n, 0.0, span)
    fit = linregress(t_s, mean_mm)
    residual = mean_mm - (fit.intercept + fit.slope * t_s)
    power = float(np.dot(residual, residual))
    r1 = float(np.dot(residual[1:], residual[:-1])) / power if power > 0 else 0.0
    n_eff = n * (1.0 - r1) / (1.0 + r1) if r1 > 0 else float(n)
    se = fit.stderr * math.sqrt((n - 2) / (n_eff - 2)) if n_eff > 2 else math.inf
    return DriftEstimate(60.0 * fit.slope, 60.0 * se, n, n_eff, span)


class DriftWindow:
    """The last `window_s` seconds of frame means, and their drift once a whole window has passed."""

    def __init__(self, window_s: float):
        self.window_s = window_s
        self.t_s: deque[float] = deque()
        self.mean_mm: deque[float] = deque()
        self.first_s: float | None = None

    def add(self, t_s: float, mean_mm: float) -> None:
        """One frame: its device time in s and its mean valid depth in mm (NaN: no valid pixel, left out)."""
        if not math.isfinite(mean_mm) or not math.isfinite(t_s):
            return
        if self.first_s is None:
            self.first_s = t_s
        self.t_s.append(t_s)
        self.mean_mm.append(mean_mm)
        while self.t_s and self.t_s[0] < t_s - self.window_s:
            self.t_s.popleft()
            self.mean_mm.popleft()

    @property
    def full(self) -> bool:
        """A whole window has passed since the first frame."""
        return self.first_s is not None and self.t_s[-1] - self.first_s >= self.window_s

    def estimate(self) -> DriftEstimate:
        return drift_estimate(np.fromiter(self.t_s, float), np.fromiter(self.mean_mm, float))


def wait_until_warm(frames: Iterable[tuple[float, np.ndarray]], step: WarmUp, depth_scale_m: float, camera: str,
                    report: Report) -> tuple[float, DriftEstimate]:
    """Read (device time in s, depth image in units) until the camera is warm by the module's rule, judged each
    CHECK_S once a whole window has passed; return the wait in s (device clock, from the first frame) and the
    drift it ended with. StillDrifting after `step.max_s`: a run never records a drifting camera unasked.

    A 'warm_up' report each CHECK_S while waiting: text, and summary waited_s, drift_mm_per_min, se_mm_per_min (NaN
    before a whole window), threshold_mm_per_min; a 'message' when warm."""
    window, threshold = DriftWindow(step.window_s), step.drift_mm_per_min
    start_s = next_s = math.nan
    estimate = DriftEstimate(math.nan, math.nan, 0, 0.0, 0.0)
    for t_s, depth in frames:
        if math.isnan(start_s):
            start_s, next_s = t_s, t_s + CHECK_S
        valid = depth[depth > 0]
        window.add(t_s, float(valid.mean()) * depth_scale_m * 1000.0 if valid.size else math.nan)
        if t_s < next_s:
            continue
        next_s += CHECK_S
        waited = t_s - start_s
        if window.full:
            estimate = window.estimate()
            if estimate.warm(threshold):
                report("message", f"warm after {waited:.0f} s: the depth drifts {estimate.text()} (below "
                                  f"{threshold:g} mm/min)", {})
                return waited, estimate
        drift = f"drift {estimate.text()}" if window.full else f"first window of {step.window_s:g} s"
        if waited >= step.max_s:
            raise StillDrifting(
                f"after {waited:.0f} s of warm-up {camera}'s depth is not shown to drift under {threshold:g} mm/min "
                f"({drift if window.full else 'no window with valid depth'}; the 95 % interval must lie inside the "
                "threshold); let it warm longer (--warm-up-max-s), allow more drift (--warm-up-drift-mm-per-min), "
                "or shield it from draughts and sun")
        report("warm_up", f"warming up: {waited:.0f} s of at most {step.max_s:g} s, {drift}, waiting for under "
                          f"{threshold:g} mm/min",
               {"waited_s": waited, "drift_mm_per_min": estimate.drift_mm_per_min,
                "se_mm_per_min": estimate.se_mm_per_min, "threshold_mm_per_min": threshold})
    raise StillDrifting(f"{camera} stopped sending frames during the warm-up; check its cable and run again")
