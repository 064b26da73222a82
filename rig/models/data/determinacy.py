"""Is lambda determined by the data? The one rule, for every fit, comparison, diagnosis and screen.

lambda is the slope of log sigma against log range; a slope needs points at several ranges, far
enough apart. With the fitted pixels at fewer than `MIN_RANGES` distinct ranges, or with the
farthest of them less than `MIN_SPAN` times the nearest, the fit still returns a number (one stop
gave lambda = 4.99 +/- 2.19), but the number rests on the spread of range inside a stop and on the
model's other assumptions, not on a measured range dependence. Such a lambda is reported as not
determined, with the reason and the fix, and never as a fit "within noise".

The distinct ranges of the fitted pixels: each stop of a wall facing the camera is one range (the
median of its pixels' mean range); a stop whose pixels spread over more than `FLAT_SPREAD` in range
(a tilted wall) counts each `RANGE_STEP` of range it covers with at least `MIN_SHARE` of its pixels.
Ranges closer than `RANGE_STEP` to one another count once.

    status = lambda_status(data)          # data: the ModelData the fit used
    if not status.determined:
        print(status.reason, status.fix)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model_data import ModelData
from .order_statistics import median

#: fewest distinct ranges from which lambda is determined
MIN_RANGES = 3
#: least ratio of the farthest to the nearest of those ranges
MIN_SPAN = 1.5
#: ranges closer than this ratio count as one
RANGE_STEP = 1.05
#: a stop whose pixels' 10th-90th percentile range ratio is under this is at one range
FLAT_SPREAD = 1.1
#: share of a tilted stop's pixels a range step needs to count
MIN_SHARE = 0.02

FIX = ("record more stops over a wider range (at least three, the farthest at least 1.5 x the nearest), or fit "
       "with lambda fixed: --model active (projector on) or --model passive (projector off)")


@dataclass(frozen=True)
class LambdaStatus:
    """Whether the data determine lambda, and why not. `free`: the model fits lambda (it is not fixed)."""

    free: bool
    ranges_m: tuple[float, ...]  # the distinct ranges of the fitted pixels, m, nearest first

    @property
    def n_ranges(self) -> int:
        return len(self.ranges_m)

    @property
    def span(self) -> float:
        """Farthest over nearest range (1 for a single range; NaN without data)."""
        return self.ranges_m[-1] / self.ranges_m[0] if self.ranges_m else float("nan")

    @property
    def data_determine_lambda(self) -> bool:
        return self.n_ranges >= MIN_RANGES and self.span >= MIN_SPAN

    @property
    def determined(self) -> bool:
        """True unless lambda is free and the data do not determine it (a fixed lambda is never in question)."""
        return not self.free or self.data_determine_lambda

    @property
    def reason(self) -> str | None:
        """Why lambda is not determined, in a sentence; None when it is (or is fixed)."""
        if self.determined:
            return None
        if not self.ranges_m:
            return "lambda is not determined: no fitted pixel"
        if self.n_ranges == 1:
            where = f"one range ({self.ranges_m[0]:.3f} m)"
        else:
            where = (f"{self.n_ranges} ranges from {self.ranges_m[0]:.3f} to {self.ranges_m[-1]:.3f} m "
                     f"(a span of {self.span:.2f} x)")
        return (f"lambda is not determined: the fitted pixels lie at {where}; a range dependence needs at least "
                f"{MIN_RANGES} ranges, the farthest at least {MIN_SPAN:g} x the nearest")

    @property
    def fix(self) -> str | None:
        return None if self.determined else FIX

    def as_dict(self) -> dict:
        """For JSON: {"free", "determined", "reason", "fix", "n_ranges", "ranges_m", "span"}."""
        return {"free": self.free, "determined": self.determined, "reason": self.reason, "fix": self.fix,
                "n_ranges": self.n_ranges, "ranges_m": list(self.ranges_m),
                "span": None if not self.ranges_m else self.span}


def distinct_ranges_m(z_m: np.ndarray, stop: np.ndarray, slices: list[slice] | None = None,
                      medians: dict[int, float] | None = None) -> tuple[float, ...]:
    """The distinct ranges, m, that pixels at mean range `z_m` from stops `stop` lie at (see the module). `slices`:
    each stop's rows when they come stop by stop (`ModelData.stop_slices`), which spares a search per stop.
    `medians`: each stop's median of `z_m` (`ModelData.median_range_by_stop`), made already, for stops whose
    ranges are all positive numbers."""
    z_m, stop = np.asarray(z_m, dtype=float), np.asarray(stop)
    rows = ([(int(stop[sl.start]), sl) for sl in slices if sl.stop > sl.start] if slices is not None
            else [(int(s), stop == s) for s in np.unique(stop)])
    levels: list[float] = []
    step = np.log(RANGE_STEP)
    for s, r in rows:
        z = z_m[r]
        ok = np.isfinite(z) & (z > 0)
        whole = bool(ok.all())
        z = z if whole else z[ok]
        if len(z) == 0:
            continue
        known = medians.get(s) if medians is not None and whole else None
        if z.max() / z.min() < FLAT_SPREAD:  # then the 10-90 % spread is too: the median alone
            levels.append(known if known is not None else median(z))
            continue
        lo, hi = np.percentile(z, [10, 90])
        if hi / lo < FLAT_SPREAD:
            levels.append(known if known is not None else median(z))
            continue
        bins = np.floor(np.log(z) / step).astype(np.int64)
        keys, counts = np.unique(bins, return_counts=True)
        levels += [float(np.exp((k + 0.5) * step)) for k in keys[counts >= MIN_SHARE * len(z)]]
    merged: list[float] = []
    for z in sorted(levels):
        if not merged or z / merged[-1] >= RANGE_STEP - 1e-9:
            merged.append(z)
    return tuple(merged)


def lambda_status(d: ModelData, *, free: bool = True) -> LambdaStatus:
    """Whether the pixels of `d` (the data a fit used) determine lambda; `free=False` for a model that fixes it.
    The ranges are kept with `d`: every headline of a diagnosis asks of the same data (0.3-0.5 s a time on a sweep)."""
    ranges = d.__dict__.get("distinct_ranges_m")
    if ranges is None:
        ranges = d.__dict__["distinct_ranges_m"] = distinct_ranges_m(d.z_m, d.stop, d.stop_slices(),
                                                                     d.median_range_by_stop)
    return LambdaStatus(free, ranges)
