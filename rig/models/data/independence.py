"""Are a recording's frames independent samples? Their lag-1 correlation, measured model-free.

Every model assumes each frame is a fresh draw of the noise. A temporal filter (RealSense's or
OAK-D's post-processing, exponential smoothing out_t = alpha in_t + (1 - alpha) out_{t-1}), a
recorder that saves a frame twice, or a matcher with memory make consecutive frames correlated:
each pixel's sample variance is then biased low (a smoothed series varies less than its input),
and the frames carry fewer independent samples than their number.

The recording keeps, per pixel, the number of consecutive valid pairs p and
C1 = sum over them of (z_t - mean)(z_{t-1} - mean) (`protocols.stats`). Pooled over the pixels of a
stop, with v = M2 / (n - 1) each pixel's sample variance:

    rho_1 = sum (C1 + p v / n) / sum (p v)

the standard lag-1 estimator c_1 / c_0 (Box & Jenkins) as a ratio of sums over pixels, its bias under
independence removed: deviations from a mean estimated from the same n samples have covariance
-sigma^2 / n, so E[C1] = -p sigma^2 / n. Under independence its sampling error is about
1 / sqrt(sum p); neighbouring pixels share their matching window, so they are not independent
samples, and the error is taken as no smaller than SE_FLOOR.

A correlation rho makes a variance estimated from n frames worth n_eff = n (1 - rho^2) / (1 + rho^2)
independent ones (Bartlett's variance of the lag-0 autocovariance of an AR(1) series; for the mean of the
series it would be n (1 - rho) / (1 + rho)): the fit's standard errors grow by sqrt(n / n_eff) when the
frames are measured not independent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

#: the pooled correlation's sampling error is taken as at least this (pixels sharing a matching window)
SE_FLOOR = 0.02
#: frames are called not independent when rho exceeds this many standard errors
Z_CALL = 5.0
#: near-constant frames: at least this share of the pixels never change ...
CONSTANT_SHARE = 0.5
#: ... and at least half the frames repeat their predecessor, or the rest correlate at least this much
CONSTANT_RHO = 0.5
#: the fix, in words
FIX = ("record without the camera's post-processing filters (temporal, spatial; RealSense Viewer, realsense-ros "
       "and OAK-D presets turn them on) and without duplicated frames")


def pooled_lag1(stats: Any) -> tuple[float, float, float]:
    """(sum (C1 + p v / n), sum p v, sum p) over the pixels of one stop's `PixelStats` with a pair and two samples, in
    m^2, m^2 and pairs; (nan, nan, 0) when the stop does not record them (not checked)."""
    if getattr(stats, "lag1_pairs", None) is None or getattr(stats, "lag1_m2", None) is None:
        return float("nan"), float("nan"), 0.0
    num, den, pairs = _lag1_sums(*(np.ascontiguousarray(a).ravel() for a in
                                   (stats.count, stats.lag1_pairs, stats.m2_m2, stats.lag1_m2)))
    return num, den, pairs


@njit(cache=True, nogil=True)
def _lag1_sums(count, pairs, m2, lag1):  # pragma: no cover - compiled
    """`pooled_lag1`'s sums in one pass over the pixels (no temporary images): over those with a pair p > 0 and
    n > 1 samples, with v = M2 / (n - 1): sum (C1 + p v / n), sum p v and sum p."""
    num, den, total = 0.0, 0.0, 0.0
    for i in range(count.size):
        n, p = np.float64(count[i]), np.float64(pairs[i])
        if p > 0 and n > 1:
            v = m2[i] / (n - 1.0)
            num += lag1[i] + p * v / n
            den += p * v
            total += p
    return num, den, total


def rho_and_se(num: float, den: float, pairs: float) -> tuple[float, float]:
    """The pooled lag-1 correlation and its standard error (see the module docstring); NaN when not checked."""
    if not (np.isfinite(num) and np.isfinite(den)) or den <= 0 or pairs <= 0:
        return float("nan"), float("nan")
    return num / den, math.sqrt(1.0 / pairs + SE_FLOOR**2)


@dataclass(frozen=True)
class Independence:
    """The recording's frames, pooled over stops: lag-1 correlation rho (+/- se), frames repeating their predecessor
    out of the pairs of frames, and the share of pixels that never change. rho NaN: not checked."""

    rho: float
    se: float
    frames_repeated: int
    frame_pairs: int
    constant_share: float

    @property
    def checked(self) -> bool:
        return bool(np.isfinite(self.rho))

    @property
    def correlated(self) -> bool:
        """Measured not independent: rho beyond Z_CALL standard errors."""
        return self.checked and self.rho > Z_CALL * self.se

    @property
    def n_eff_fraction(self) -> float:
        """n_eff / n = (1 - rho^2) / (1 + rho^2) when correlated (Bartlett, AR(1)); 1 otherwise."""
        if not self.correlated or not self.rho > 0:
            return 1.0
        r2 = min(self.rho, 0.99) ** 2
        return (1 - r2) / (1 + r2)

    @property
    def error_inflation(self) -> float:
        """What the standard errors are multiplied by: sqrt(n / n_eff)."""
        return 1.0 / math.sqrt(self.n_eff_fraction)

    def sentence(self) -> str:
        """In words: not checked, independent, or not independent with the measured correlation, causes and fix."""
        if not self.checked:
            return "Frame independence: not checked (the recording predates the lag-1 statistics)."
        if not self.correlated:
            return f"Frames independent: lag-1 correlation {self.rho:+.3f} +/- {self.se:.3f}."
        rep = (f"; {self.frames_repeated} of {self.frame_pairs} frames repeat the previous one exactly"
               if self.frames_repeated else "")
        return (f"Frames not independent: lag-1 correlation {self.rho:.2f} +/- {self.se:.2f}{rep}. A temporal filter, "
                "repeated frames or a recorder that duplicates them make consecutive frames alike, so each pixel's "
                "variance is biased low (a smoothed series varies less than its input) and the frames hold about "
                f"{100 * self.n_eff_fraction:.0f} % as many independent samples as their number: the standard errors "
                f"are widened by {self.error_inflation:.2f}, but sigma itself is too small. Fix: {FIX}.")

    def identical_problem(self) -> str | None:
        """One line when the frames are identical or nearly constant (nothing to fit); None otherwise."""
        if not self.checked or self.constant_share < CONSTANT_SHARE:
            return None
        repeats = self.frame_pairs > 0 and self.frames_repeated >= self.frame_pairs / 2
        if not (repeats or self.rho >= CONSTANT_RHO):
            return None  # many constant pixels from a coarse depth unit, with independent frames
        return (f"the frames are not independent: {100 * self.constant_share:.0f} % of the pixels never change, "
                f"{self.frames_repeated} of {self.frame_pairs} frames repeat the previous one exactly, and the rest "
                f"correlate {self.rho:.2f} frame to frame, so there is no temporal noise to fit; {FIX}")


def independence(stops: Any) -> Independence:
    """Pooled over a `StopTable`'s stops (rig.models.data.model_data) that record the lag-1 statistics."""
    nan = Independence(float("nan"), float("nan"), 0, 0, 0.0)
    if stops is None or getattr(stops, "lag1_num", None) is None:
        return nan
    num, den, pairs = (np.asarray(a, float) for a in (stops.lag1_num, stops.lag1_den, stops.lag1_pairs))
    ok = np.isfinite(num) & np.isfinite(den)
    if not ok.any():
        return nan
    rho, se = rho_and_se(float(num[ok].sum()), float(den[ok].sum()), float(pairs[ok].sum()))
    repeated = np.asarray(stops.frames_repeated, float)[ok]
    frames = np.asarray(stops.frames, float)[ok]
    kept, constant = np.asarray(stops.kept, float)[ok], np.asarray(stops.constant, float)[ok]
    return Independence(rho if np.isfinite(rho) else 0.0, se if np.isfinite(se) else 1.0, int(repeated.sum()),
                        int(np.maximum(frames - 1, 0).sum()), float(constant.sum() / max(kept.sum(), 1.0)))


def error_inflation(d: Any) -> float:
    """sqrt(n / n_eff) for the data `d` (grouped data: the whole data's), 1 if its frames are independent or unchecked."""
    full = getattr(d, "full", d)
    return independence(getattr(full, "stops", None)).error_inflation
