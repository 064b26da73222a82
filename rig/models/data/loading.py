"""A recording's stops as model data: every pixel with two or more samples, read once, stop by stop.

Each stop is read, checked (`protocols.recording.check_stop`) and reduced to its kept pixels' rows
(range, M2, M4, count, position) and to what its covariates are later computed from (a
`StopSource`: the smoothed IR and ambient images, the wall plane, the drift), then dropped. The rows
go straight into arrays sized for every pixel of every stop, trimmed once at the end, so no stop's
images and no second copy of the rows are held while the next stop is read.
"""

from __future__ import annotations


from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from protocols.recording import Recording, StopData
from protocols.recording_errors import RecordingError

from .covariates import StopSource, fill_clipped_ambient
from .pattern_light import fill_clipped_light
from .independence import independence, pooled_lag1
from .stop_checks import count_problem, range_problem, stage_info, stop_truth, zero_variance_problems

#: per-stop facts of frame independence (rig.models.data.independence): the pooled lag-1 sums, frames repeating their
#: predecessor, pixels kept (two samples or more) and those of them that never changed; NaN: not recorded
LAG1_FACTS = ("lag1_num", "lag1_den", "lag1_pairs", "frames_repeated", "kept", "constant")
#: the matching window over which brightness is averaged (px)
BRIGHTNESS_WINDOW_PX = 7


@dataclass
class RecordingRows:
    """What `read_rows` returns: the kept pixels' core arrays, one `StopSource` per stop, the per-stop facts
    (label, frames, frame-mean series variance, valid pixels per frame, middle time in s) and the pixels left
    out for zero variance."""

    arrays: dict[str, np.ndarray]
    sources: list[StopSource]
    facts: dict[str, list]
    dropped_zero: int


def read_rows(recording: Recording, *, min_count: int = 2, positive_variance: bool = False,
              _excluded: dict[str, str] | None = None) -> RecordingRows:
    """All pixels with at least `min_count` valid samples (with `positive_variance`, also M2 > 0), from every
    complete stop, with the stop sources their covariates come from. A stop that contradicts itself or the rest
    (rig.models.data.stop_checks) is left out, and the recording notes it (Recording.exclude)."""
    cal = recording.calibration
    measured = _stage_measures(recording)
    excluded = dict(_excluded or {})
    labels = [label for label in recording.stop_labels() if label not in excluded]
    rows = _Rows(len(labels) * cal.width * cal.height)
    sources: list[StopSource] = []
    facts: dict[str, list] = {k: [] for k in ("label", "frames", "series_var_inv2", "n_valid", "time_s", "truth_m",
                                              "truth_source", *LAG1_FACTS)}
    dropped_zero = 0
    zero_shares: list[float] = []
    for label in labels:
        try:
            stop = recording.stop(label, third_moment=False)
        except RecordingError as e:  # a checksum that fails, a field out of its range: this stop only
            excluded[label] = str(e).removeprefix(f"{recording.path}: ")
            continue
        problem = range_problem(stop, cal.cx, cal.cy) or count_problem(stop)
        if problem:
            excluded[label] = problem
            continue
        i = len(sources)  # the stop's index among those kept
        s = stop.stats
        with np.errstate(invalid="ignore"):
            keep = (s.count >= max(2, min_count)) & np.isfinite(s.mean_m) & (s.mean_m > 0)
        zero = keep & ~(s.m2_m2 > 0)  # kept pixels whose samples never changed
        n_keep, n_zero = int(keep.sum()), int(zero.sum())
        zero_shares.append(float(n_zero) / max(n_keep, 1))
        _add_lag1_facts(facts, s, n_keep, n_zero)
        if positive_variance:
            dropped_zero += n_zero
            keep &= ~zero
        rows.add(i, s, keep)
        sources.append(StopSource.of(stop, keep, cal, BRIGHTNESS_WINDOW_PX))
        _add_stop_facts(facts, stop, measured)
    zero = zero_variance_problems(facts["label"], zero_shares)
    if zero:  # found only once every stop is read: read again without them (a damaged file only)
        return read_rows(recording, min_count=min_count, positive_variance=positive_variance,
                         _excluded={**excluded, **{facts["label"][i]: why for i, why in zero.items()}})
    for label, why in excluded.items():
        recording.exclude(label, why)
    if rows.size == 0 and excluded:
        raise ValueError(f"{recording.path}: no stop can be fitted; {next(iter(excluded.values()))}; re-record the "
                         "stops (rig run ... --resume after removing them) or check the depth unit")
    if rows.size == 0:
        raise ValueError(f"{recording.path}: no pixel has 2 or more valid samples; nothing to fit (check the stops and the camera's fill rate)")
    if not np.any(rows.m2[: rows.size] > 0):
        raise ValueError(f"{recording.path}: every pixel's samples are identical (zero variance), so there is no noise to "
                         "fit; the frames are copies of one image: record or import frames captured one after another")
    problem = independence(SimpleNamespace(**facts)).identical_problem()
    if problem:
        raise ValueError(f"{recording.path}: {problem}")
    fill_clipped_light(sources)  # before the ambient's: both read the stops' mean depth, which that one drops
    fill_clipped_ambient(sources)
    return RecordingRows(rows.arrays(), sources, facts, dropped_zero)


class _Rows:
    """The core per-pixel arrays, filled stop by stop, trimmed at the end."""

    def __init__(self, capacity: int):
        self.size = 0
        self.z = np.empty(capacity)
        self.m2 = np.empty(capacity)
        self.m4 = np.empty(capacity)
        self.n = np.empty(capacity)
        self.stop = np.empty(capacity, np.int32)
        self.u = np.empty(capacity, np.float32)
        self.v = np.empty(capacity, np.float32)

    def add(self, index: int, s, keep: np.ndarray) -> None:
        a = self.size
        if keep.all():  # every pixel (the usual case): whole images, no gathering
            h, w = keep.shape
            b = a + h * w
            self.z[a:b], self.m2[a:b], self.m4[a:b], self.n[a:b] = (x.ravel() for x in (s.mean_m, s.m2_m2, s.m4_m4, s.count))
            self.u[a:b].reshape(h, w)[:] = np.arange(w, dtype=np.float32)  # broadcast: no image-sized temporaries
            self.v[a:b].reshape(h, w)[:] = np.arange(h, dtype=np.float32)[:, None]
            self.stop[a:b] = index
            self.size = b
            return
        v, u = np.nonzero(keep)  # row-major, the order boolean indexing takes them in
        b = a + len(u)
        self.z[a:b] = s.mean_m[keep]
        self.m2[a:b] = s.m2_m2[keep]
        self.m4[a:b] = s.m4_m4[keep]
        self.n[a:b] = s.count[keep]
        self.stop[a:b] = index
        self.u[a:b] = u
        self.v[a:b] = v
        self.size = b

    def arrays(self) -> dict[str, np.ndarray]:
        k = self.size
        # a copy only when much was left out: otherwise the views keep a little unused memory
        trim = (lambda x: x[:k].copy()) if k < 0.8 * len(self.z) else (lambda x: x[:k])
        return {"z_m": trim(self.z), "m2_m2": trim(self.m2), "m4_m4": trim(self.m4), "n": trim(self.n),
                "stop": trim(self.stop), "u_px": trim(self.u), "v_px": trim(self.v)}


def _stage_measures(recording: Recording) -> bool:
    """Whether the recording's stage measured its positions: not `none:` (drivers.stage.NoStage), whose "measured"
    position is the one the plan asked the operator to set."""
    return stage_info(recording).get("name") != "none"


def _add_stop_facts(table: dict[str, list], stop: StopData, stage_measures: bool = True) -> None:
    series = stop.series
    size = stop.stats.count.size
    table["label"].append(stop.label)
    table["frames"].append(stop.n_frames)
    o = series.inverse_range_offset_per_m if series is not None else np.array([])
    table["series_var_inv2"].append(float(np.var(o, ddof=1)) if len(o) >= 3 and np.isfinite(o).all() else np.nan)
    frac = series.valid_fraction if series is not None else np.array([])
    table["n_valid"].append(float(np.mean(frac)) * size if len(frac) and np.isfinite(frac).all() else np.nan)
    ts = series.timestamp_ms if series is not None else np.array([])
    table["time_s"].append(float(np.mean(ts)) / 1000.0 if len(ts) and np.isfinite(ts).all() else np.nan)
    truth_m, source = stop_truth(stop, stage_measures)
    table["truth_m"].append(truth_m)
    table["truth_source"].append(source)


def _add_lag1_facts(table: dict[str, list], s, kept: int, constant: int) -> None:
    """The stop's frame-independence facts (LAG1_FACTS), with its `kept` pixels and the `constant` ones among them."""
    num, den, pairs = pooled_lag1(s)
    table["lag1_num"].append(num)
    table["lag1_den"].append(den)
    table["lag1_pairs"].append(pairs)
    table["frames_repeated"].append(float(s.frames_repeated) if s.frames_repeated is not None else np.nan)
    table["kept"].append(float(kept))
    table["constant"].append(float(constant))
