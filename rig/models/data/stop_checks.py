"""Stops that contradict themselves or the rest of their recording, found before any fit.

A file can be readable and still wrong: a stop's variances zeroed (a writer bug, a bad repair), its
mean range a factor off its position (a wrong depth unit for one stop, a corrupted dataset), or its
per-pixel counts disagreeing with the per-frame valid fractions recorded as the frames came in. Fitted
as they are, one such stop moves lambda by hundreds of standard errors without a word. Each check
here names the stop, the field and what it should be; `rig.models.data.loading` leaves such a stop out of
the fit and the recording's notes say so.
"""

from __future__ import annotations

import json

import math
import re

import numpy as np

#: a stop's central mean range this many times its position (or its inverse) is not that stop's wall
RANGE_FACTOR = 1.5
#: a stop with at least this share of its pixels at zero variance, where the other stops' median share is at most
#: OTHERS_ZERO_SHARE, holds no noise the others have
ZERO_SHARE = 0.95
OTHERS_ZERO_SHARE = 0.5
#: counts and per-frame valid fractions may differ by float32 rounding: this share of the samples
COUNT_TOLERANCE = 1e-3
_LABEL_M = re.compile(r"^([0-9]+(?:\.[0-9]+)?)m$")


#: where a stop's distance came from (`stop_truth`), in the words the report uses
TRUTH_SOURCES = ("stage measured", "stage commanded", "plan")


def stage_info(recording) -> dict:
    """The stage an open `Recording` was made with, as its driver described it (`drivers.stage.Stage.describe`: name,
    limits_m, tolerance_m ...); {} where the file does not say or says it in a form not read."""
    try:
        stage = json.loads(str(recording.attrs.get("stage", "{}")))
    except ValueError:
        return {}
    return stage if isinstance(stage, dict) else {}


def stop_truth(stop, stage_measures: bool = True) -> tuple[float, str]:
    """Where the stop says the wall was, m, and how it knows (TRUTH_SOURCES): the stage's measured position, else the
    commanded one, else the plan's distance in its label ('2.500m'); (NaN, "") when nothing says. Without a stage
    that measures (`none:`, the camera placed by hand) the commanded position is the plan's distance, and says so."""
    if not stage_measures:
        z = stop.commanded_position_m
        if z is not None and math.isfinite(z) and z > 0:
            return float(z), TRUTH_SOURCES[2]
    for z, source in zip((stop.measured_position_m, stop.commanded_position_m), TRUTH_SOURCES):
        if z is not None and math.isfinite(z) and z > 0:
            return float(z), source
    m = _LABEL_M.match(stop.label)
    return (float(m.group(1)), TRUTH_SOURCES[2]) if m else (math.nan, "")


def stop_distance_m(stop) -> float:
    """Where the stop says it was (`stop_truth`), m."""
    return stop_truth(stop)[0]


def range_problem(stop, cx_px: float | None = None, cy_px: float | None = None) -> str | None:
    """The stop's mean range about the optical axis (a tenth of the image each way round the principal point `cx_px`,
    `cy_px`, else the image's centre; the image's nearest pixels when a recorded region leaves the axis out) against
    its position: more than RANGE_FACTOR apart is a one-line problem naming mean_m; None when they agree or nothing
    says where the stop was. On the axis a tilted wall is at the stop's distance too."""
    z = stop_distance_m(stop)
    mean = stop.stats.mean_m
    h, w = mean.shape
    rows = _about(cy_px if cy_px is not None else (h - 1) / 2, h)
    cols = _about(cx_px if cx_px is not None else (w - 1) / 2, w)
    centre = mean[rows, cols]
    ok = np.isfinite(centre) & (centre > 0)
    if not math.isfinite(z) or not ok.any():
        return None
    r = float(np.median(centre[ok]))
    if 1 / RANGE_FACTOR <= r / z <= RANGE_FACTOR:
        return None
    return (f"stop {stop.label!r}: mean_m is {r:.3g} m at the image centre, but the stop was at {z:.3f} m "
            f"({r / z:.2g} times); the stop's data are damaged or recorded with another depth unit")


def _about(centre_px: float, size: int) -> slice:
    """A tenth of `size` pixels round `centre_px` (at least one), moved inside 0..size-1."""
    half = max(size // 20, 0)
    c = min(max(int(round(centre_px)), 0), size - 1)
    return slice(max(c - half, 0), min(c + half, size - 1) + 1)


def count_problem(stop) -> str | None:
    """Each pixel's count against the frames' valid fractions: sum(count) must equal sum(valid_fraction) * pixels."""
    series = stop.series
    if series is None or not len(series.valid_fraction) or not np.all(np.isfinite(series.valid_fraction)):
        return None
    counted = float(np.sum(stop.stats.count, dtype=np.float64))
    seen = float(np.sum(series.valid_fraction, dtype=np.float64)) * stop.stats.count.size
    if abs(counted - seen) <= COUNT_TOLERANCE * max(seen, 1.0) + len(series.valid_fraction):
        return None
    return (f"stop {stop.label!r}: count sums to {counted:,.0f} samples, but its frames' valid_fraction says "
            f"{seen:,.0f}; the per-pixel statistics do not belong to these frames")


def zero_variance_problems(labels: list[str], zero_shares: list[float]) -> dict[int, str]:
    """Stops (by index) whose pixels all but never vary while the others' mostly do: {index: one line naming m2_m2}."""
    out: dict[int, str] = {}
    shares = np.asarray(zero_shares, float)
    for i, share in enumerate(shares):
        others = np.delete(shares, i)
        others = others[np.isfinite(others)]
        if share >= ZERO_SHARE and others.size and float(np.median(others)) <= OTHERS_ZERO_SHARE:
            out[i] = (f"stop {labels[i]!r}: m2_m2 is 0 at {100 * share:.0f} % of its pixels, where the other stops' "
                      f"median is {100 * float(np.median(others)):.0f} %; its variances are lost (the stop is damaged)")
    return out
