"""What models are fitted to: every pixel of every stop, with the covariates effects use, and its likelihood.

Each row is one pixel at one stop: its mean range z_m, the sum of squared deviations of its
samples from that mean (m2_m2, in m^2), and its sample count n. A pixel with n samples gives
nu = n - 1 degrees of freedom to a variance, because its mean was estimated from the same
samples; its sample variance is s2 = m2 / nu.

The likelihood (`rig.models.fitting.likelihood`) has three parts: each pixel's s2 is Gamma-distributed
about the model's variance, with the scatter the measured kurtosis gives it; the measured
kurtosis of each range window is normal about the model's; each stop's fill rate is normal
about the model's. The Gamma part needs s2 > 0: `positive_variance()` drops the pixels whose
samples were all equal, as `from_recording` does.

Covariates (brightness, incidence, ambient light, position, drift, fill) are computed when first
used, from the per-stop sources the recording gave (`rig.models.data.covariates.StopSource`), and
kept; data built by hand pass them in. Rows of one stop are contiguous, so the work that visits
every pixel can go a few stops at a time (`chunks`), with arrays the size of about one stop.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Iterator

import numpy as np
from numba import njit

from protocols.recording import CameraCalibration, Recording

from .covariates import StopSource, covariate_rows, rows_by_stop
from .loading import LAG1_FACTS, read_rows
from .order_statistics import median
from .rounding import grid_offset
from .shape_statistics import ShapeStatistics

#: range windows of the kurtosis term and of the diagnosis (m)
RANGE_BIN_M = 0.25
#: rows of the chunks work over every pixel goes in (whole stops; about a full-resolution stop)
CHUNK_ROWS = 400_000
#: rows of the pieces the chunks are worked in: arrays that stay in the processor's cache, the derivatives'
#: (parameters x rows) too: 8,192 rows (64 kB an array) made a likelihood's gradient 22-30 % quicker than 65,536
#: (on the demo's loop recording, 70,000 rows: 52-54 against 67-79 ms with outliers, 30-31 against 38-39 without)
PIECE_ROWS = 8_192
#: rows of the pieces of work that visits the data once (the diagnosis's residuals, the stop table): its per-piece
#: costs (a prediction's set-up, the bins' labels, the sums' merge) are paid 8x less often than in PIECE_ROWS, and a
#: piece's arrays (512 kB) stay below glibc's 1 MB mmap threshold, so they reuse the heap instead of faulting in new
#: pages: on a full sweep (4.48 M rows) the headline took 2.1-2.4 s against 3.0-3.2 s in 8,192 rows and 3.2 s in 400,000
PASS_ROWS = 65_536


@dataclass(frozen=True)
class StopTable:
    """One entry per stop, in the order of `ModelData.stop`.

    frames: frames captured; series_var_inv2: the variance over frames of the frame's mean of
    1/z - 1/z_first over valid pixels, (1/m)^2 (NaN if not recorded): independent pixel noise
    makes it mean(var / Z^4) / n_valid, a common wander (drift) or noise shared by neighbouring
    pixels makes it larger; n_valid: valid pixels in a frame, on average; time_s: the stop's
    middle, s after the first stop began (NaN if the camera gave no timestamps). lag1_num, lag1_den,
    lag1_pairs, frames_repeated, kept, constant: frame independence (`rig.models.data.independence`; NaN where
    the stop does not record it, None for data built by hand).
    """

    label: tuple[str, ...]
    frames: np.ndarray
    series_var_inv2: np.ndarray
    n_valid: np.ndarray
    time_s: np.ndarray
    lag1_num: np.ndarray | None = None
    lag1_den: np.ndarray | None = None
    lag1_pairs: np.ndarray | None = None
    frames_repeated: np.ndarray | None = None
    kept: np.ndarray | None = None
    constant: np.ndarray | None = None
    #: where each stop's wall was (m) and how that is known (`stop_checks.stop_truth`): the accuracy's ground truth
    truth_m: np.ndarray | None = None
    truth_source: tuple[str, ...] | None = None


#: covariates computed from the stop sources when first used (or given, for data built by hand)
LAZY = ("ir", "fill", "rho2", "cos_inc", "ambient_ratio", "drift_var_m2", "projector_on", "x_norm", "y_norm")
#: columns effects derive from the sources by a key of their own (`ModelData.column`) start with this
COLUMN_PREFIX = "column:"
#: per-pixel quantities derived from the data alone, cached, and handed to chunks and selections as slices
DERIVED = ("nu", "s2_m2", "neighbour_variance", "pixel_kurtosis", "z0_m", "ln_z0_m", "range_group", "kurtosis_usable",
           "excess_measured", "gamma_shape", "gamma_b", "kurtosis_weight", "grid_offset")


class ModelData(ShapeStatistics):
    """Pooled per-pixel statistics with the covariates models may need, and the camera's f*b and depth unit.

    z_m: pixel mean range, m; m2_m2: sum of (z_i - z_mean)^2 over the pixel's samples, m^2; m4_m4: sum of
    (z_i - z_mean)^4, m^4 (NaN where not recorded); n: valid samples; stop: index of the stop the row comes
    from; u_px, v_px: pixel column and row; ir: mean IR brightness, DN, smoothed over the matching window
    (NaN where not recorded or the IR saturated: covariates.clipped_nearby); fill: fraction of the stop's frames in which the pixel was valid; rho2: squared
    normalised radius ((u-cx)/fx)^2 + ((v-cy)/fy)^2; cos_inc: cosine of the incidence angle on a plane fitted
    to the stop's mean depth; ambient_ratio: ambient / pattern brightness from the projector-off frames (NaN
    if none, or saturated); drift_var_m2: variance of the stop's mean depth over its frames, beyond noise, scaled to this
    pixel's range; projector_on: the stop's projector state; x_norm, y_norm: (u - cx) / fx, (v - cy) / fy.
    """

    ARRAYS = ("z_m", "m2_m2", "m4_m4", "n", "stop", "u_px", "v_px", *LAZY)

    def __init__(self, *, z_m: np.ndarray, m2_m2: np.ndarray, m4_m4: np.ndarray, n: np.ndarray, stop: np.ndarray,
                 u_px: np.ndarray | None = None, v_px: np.ndarray | None = None, fb_px_m: float = float("nan"),
                 depth_unit_m: float = float("nan"), n_dropped_zero: int = 0, stops: StopTable | None = None,
                 sources: list[StopSource] | None = None, calibration: CameraCalibration | None = None,
                 **covariates: np.ndarray | None):
        unknown = {k for k in covariates if k not in LAZY and not k.startswith(COLUMN_PREFIX)}
        if unknown:
            raise TypeError(f"ModelData got unknown arrays {sorted(unknown)}")
        self.z_m, self.m2_m2, self.m4_m4, self.n, self.stop = z_m, m2_m2, m4_m4, n, stop
        if u_px is None:
            u_px = np.full(len(z_m), np.nan)
        if v_px is None:
            v_px = np.full(len(z_m), np.nan)
        self.u_px, self.v_px = u_px, v_px
        self._cols: dict[str, np.ndarray] = {k: v for k, v in covariates.items() if v is not None}
        self.fb_px_m = fb_px_m
        self.depth_unit_m = depth_unit_m
        self.n_dropped_zero = n_dropped_zero  # pixels left out because all their samples were equal (s2 = 0)
        self.stops = stops  # per-stop facts (frames, the frame-mean series, time), indexed by `stop`
        self.sources = sources
        self.calibration = calibration

    # -- covariates ------------------------------------------------------------------------------
    def covariate(self, name: str) -> np.ndarray | None:
        """A covariate's rows: given, computed before, or computed now from the stop sources (None if neither)."""
        col = self._cols.get(name)
        if col is None and self.sources is not None and self.calibration is not None:
            col = self._cols[name] = covariate_rows(name, self)
        return col

    def column(self, key: str, compute: Any) -> np.ndarray:
        """A per-row column an effect derives from the sources (`key` starts with COLUMN_PREFIX): computed by
        `compute()` when first asked for, then kept, and handed to selections as slices like the covariates."""
        if not key.startswith(COLUMN_PREFIX):
            raise KeyError(f"a derived column's key starts with {COLUMN_PREFIX!r}, not {key!r}")
        col = self._cols.get(key)
        if col is None:
            col = self._cols[key] = compute()
        return col

    def _known(self) -> dict[str, Any]:
        return dict(fb_px_m=self.fb_px_m, depth_unit_m=self.depth_unit_m, n_dropped_zero=self.n_dropped_zero,
                    stops=self.stops, sources=self.sources, calibration=self.calibration)

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def from_recording(cls, path: Any) -> "ModelData":
        """Every pixel with a positive sample variance, from every complete stop of the recording at `path`."""

        with Recording(path) as rec:
            return load_samples(rec, positive_variance=True)

    def _taken(self, rows: Any, derived: bool) -> "ModelData":
        """These rows (a mask, indices or a slice), with the covariates computed so far; with `derived`, also
        the derived quantities (valid only when `rows` are whole stops of the same data)."""
        out = ModelData(z_m=self.z_m[rows], m2_m2=self.m2_m2[rows], m4_m4=self.m4_m4[rows], n=self.n[rows],
                        stop=self.stop[rows], u_px=self.u_px[rows], v_px=self.v_px[rows],
                        **{k: v[rows] for k, v in self._cols.items()}, **self._known())
        if derived:
            for name in DERIVED:
                if name in self.__dict__:
                    v = self.__dict__[name]
                    out.__dict__[name] = tuple(a[rows] for a in v) if isinstance(v, tuple) else v[rows]
            if "kurtosis_by_range" in self.__dict__:
                out.__dict__["kurtosis_by_range"] = self.__dict__["kurtosis_by_range"]
            if "loglik_positions" in self.__dict__:  # the likelihood's row positions, with their key (rig.models.fitting.likelihood)
                key, *positions = self.__dict__["loglik_positions"]
                out.__dict__["loglik_positions"] = (key, *(a[rows] for a in positions))
        return out

    def select(self, mask: np.ndarray) -> "ModelData":
        """The rows where `mask` is true (or the rows `mask` indexes); their shape statistics are their own."""
        return self._taken(mask, derived=False)

    def in_range(self, z_min_m: float, z_max_m: float) -> "ModelData":
        return self.select((self.z_m >= z_min_m) & (self.z_m <= z_max_m))

    def positive_variance(self) -> "ModelData":
        """The pixels the likelihood can use (s2 > 0); the others are counted in n_dropped_zero."""
        keep = self.m2_m2 > 0
        if keep.all():
            return self
        out = self.select(keep)
        out.n_dropped_zero = self.n_dropped_zero + int(np.sum(~keep))
        return out

    def stop_slices(self) -> list[slice] | None:
        """The row range of each stop, in order, if the rows come stop by stop (as loaded); else None. Kept with the
        data while its `stop` array is the same one: every covariate of a piece asks (on a sweep, 1,900 times a
        diagnosis)."""
        kept = self.__dict__.get("_stop_slices")
        if kept is not None and kept[0] is self.stop:
            return kept[1]
        slices = self._stop_slices()
        self.__dict__["_stop_slices"] = (self.stop, slices)
        return slices

    def _stop_slices(self) -> list[slice] | None:
        s = self.stop
        if len(s) == 0:
            return []
        if np.any(s[1:] < s[:-1]):
            return None
        edges = np.flatnonzero(s[1:] != s[:-1]) + 1
        bounds = [0, *edges.tolist(), len(s)]
        return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]

    def chunks(self) -> Iterator["ModelData"]:
        """The data in runs of whole stops of about CHUNK_ROWS rows (views, with every quantity computed so far;
        what is computed in a chunk is the chunk's own). Small data, or data whose rows are not in stop order,
        come as one chunk, themselves."""
        slices = self.stop_slices()
        if slices is None or len(self) <= CHUNK_ROWS:
            yield self
            return
        start = 0
        for i, sl in enumerate(slices):
            if sl.stop - start >= CHUNK_ROWS or i == len(slices) - 1:
                yield self._taken(slice(start, sl.stop), derived=True)
                start = sl.stop

    def pieces(self, rows: int | None = None, *, neighbours: bool = True) -> Iterator["ModelData"]:
        """The data in pieces of at most `rows` rows (PIECE_ROWS), within `chunks`: what needs a whole stop (the
        neighbours' variance and the true range, unless `neighbours` is False) is made for the stop first, and
        the pieces share it, so the work over every pixel holds arrays of a piece, not of a stop."""
        rows = rows or PIECE_ROWS
        if rows < len(self) <= CHUNK_ROWS:  # one chunk: its pieces are kept, and with them what each computes
            yield from self._kept_pieces(rows, neighbours)
            return
        for c in self.chunks():
            if len(c) <= rows:
                yield c
                continue
            if neighbours:
                c.z0_m  # the stop's own, from its neighbours, made once for all its pieces
            for a in range(0, len(c), rows):
                yield c._taken(slice(a, a + rows), derived=True)

    def pass_pieces(self, *, neighbours: bool = True) -> Iterator["ModelData"]:
        """The pieces for work that visits the data once: PASS_ROWS rows in data of more than a chunk; in data of one
        chunk, the pieces a fit keeps (`_kept_pieces`), which already hold what they computed."""
        return self.pieces(PASS_ROWS if len(self) > CHUNK_ROWS else None, neighbours=neighbours)

    def _kept_pieces(self, rows: int, neighbours: bool) -> list["ModelData"]:
        """The pieces of data that are one chunk, made once and kept: a fit evaluates its likelihood on them hundreds of
        times, and each piece keeps what it computes (its rows' positions among the windows, covariates). Made
        again when this data has computed a derived quantity or covariate since, which the pieces then take as
        slices instead of computing their own."""
        if neighbours:
            self.z0_m
        known = (rows, neighbours, tuple(n for n in (*DERIVED, "kurtosis_by_range") if n in self.__dict__), tuple(self._cols))
        kept = self.__dict__.get("kept_pieces")
        if kept is None or kept[0] != known:
            pieces = [self._taken(slice(a, a + rows), derived=True) for a in range(0, len(self), rows)]
            kept = self.__dict__["kept_pieces"] = (known, pieces)
        return kept[1]

    # -- sizes -----------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.z_m)

    @property
    def n_samples(self) -> int:
        return int(self.n.sum())

    total_samples = n_samples

    @cached_property
    def nu(self) -> np.ndarray:
        """Degrees of freedom of each pixel's variance, n - 1."""
        return self.n - 1.0

    @property
    def dof(self) -> np.ndarray:
        return self.nu

    @cached_property
    def s2_m2(self) -> np.ndarray:
        """Sample variance M2 / (n - 1), m^2."""
        return self.m2_m2 / (self.n - 1.0)

    @cached_property
    def range_group(self) -> np.ndarray:
        """Each pixel's range window: 0.25 m windows centred on multiples of 0.25 m (`range_bin_index`)."""
        return range_bin_index(self.z_m)

    # -- physics the models share -------------------------------------------------------------------
    @cached_property
    def z0_m(self) -> np.ndarray:
        """Each pixel's true range, estimated from its measured mean: Z = f b / d is convex in the disparity,
        so the mean of the samples sits above the true range, E[Z] = Z0 (1 + v / Z0^2) (eq. dist_to_disp to
        second order). v is the variance the pixel's neighbours measure (`neighbour_variance`), not its own,
        so a model's prediction at Z0 does not depend on the very sample variance it is compared with;
        where it has no neighbours, its stop's pooled variance. Models predict at Z0; bins and the
        depth grid use the measured mean."""
        v, _ = self.neighbour_variance
        if len(self) == 0:
            return np.zeros(0)
        out = np.empty(len(self))
        _true_range(np.ascontiguousarray(self.z_m, dtype=np.float64), v, np.ascontiguousarray(self.stop),
                    np.ascontiguousarray(self.m2_m2, dtype=np.float64), np.ascontiguousarray(self.nu, dtype=np.float64), out)
        return out

    @cached_property
    def ln_z0_m(self) -> np.ndarray:
        """ln of each row's true range `z0_m` (m): every evaluation of a fit raises Z to a new power (`Base.shot`)."""
        return np.log(self.z0_m)

    @cached_property
    def grid_offset(self) -> np.ndarray:
        """Where each pixel's measured mean sits between two depth levels: its offset from the nearest, in units of
        the depth unit, in [-1/2, 1/2] (`rig.models.data.rounding`)."""
        return grid_offset(self.z_m / self.depth_unit_m)

    def disparity_to_range(self, var_px2: np.ndarray | float) -> np.ndarray:
        """Variance in px^2 of disparity -> m^2 of range: (Z^2 / (f b))^2 var_d (paper, eq. error_prop_unassisted)."""
        return (self.z0_m**2 / self.fb_px_m) ** 2 * var_px2

    # -- likelihood (rig.models.fitting.likelihood) --------------------------------------------------------------
    @cached_property
    def gamma_shape(self) -> np.ndarray:
        """Each pixel's Gamma shape: 1 / (2 / nu + excess / n), its s2's scatter from the measured kurtosis."""
        return np.maximum(1.0 / np.maximum(2.0 / self.nu + self.excess_measured / self.n, 1e-12), 0.5)

    @cached_property
    def gamma_b(self) -> np.ndarray:
        """Each pixel's a s2 (`gamma_shape` times the sample variance, m^2): the Gamma log-likelihood's other weight."""
        return self.gamma_shape * self.s2_m2

    @cached_property
    def kurtosis_weight(self) -> np.ndarray:
        """Each pixel's weight in its range window's kurtosis: n where its kurtosis is usable, else 0."""
        return np.where(self.kurtosis_usable, self.n, 0.0)

    @cached_property
    def median_range_by_stop(self) -> dict[int, float]:
        """Each stop's median measured range, m (stop index -> median of its pixels' `z_m`): where a per-stop
        statistic sits along the range (the frame-mean check, the plots); made once for the data."""
        return {s: median(self.z_m[r]) for s, r in rows_by_stop(self)}  # np.median's value (rig.models.data.order_statistics)

    @cached_property
    def fill_by_stop(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(stop of each pixel as 0..S-1, measured mean fill per stop, its binomial standard error): what the
        likelihood's fill term compares the models' fill with (`rig.models.fitting.likelihood`)."""
        present = np.bincount(self.stop) > 0  # stops are small non-negative integers: index them by a table, not a sort
        idx = (np.cumsum(present) - 1)[self.stop]
        stops = np.flatnonzero(present)
        fill = self.fill
        frames = self.n / np.maximum(fill, 1e-12)
        return (idx, *mean_fill(fill, frames, idx, len(stops)))


def mean_fill(fill: np.ndarray, frames: np.ndarray, idx: np.ndarray, groups: int) -> tuple[np.ndarray, np.ndarray]:
    """(mean fill of each group 0..groups-1 of pixels, its standard error): `fill` each pixel's share of its `frames`
    frames with a valid depth, `idx` its group. The error is binomial, each pixel's frames independent trials:
    sqrt(sum f (1 - f) / frames) / pixels, and at least one sample in the group's frames, 1 / sum frames."""
    count = np.bincount(idx, minlength=groups).astype(float)
    measured = np.bincount(idx, weights=fill, minlength=groups) / count
    binomial = np.sqrt(np.bincount(idx, weights=fill * (1 - fill) / frames, minlength=groups)) / count
    one_sample = 1.0 / np.bincount(idx, weights=frames, minlength=groups)
    return measured, np.maximum(binomial, one_sample)


def _lazy(name: str) -> property:
    def get(self: ModelData) -> np.ndarray | None:
        return self.covariate(name)

    def put(self: ModelData, value: np.ndarray | None) -> None:
        if value is None:
            self._cols.pop(name, None)
        else:
            self._cols[name] = value

    return property(get, put, doc=f"the {name} covariate (see `ModelData`)")


for _name in LAZY:
    setattr(ModelData, _name, _lazy(_name))


def stops_of(d: ModelData) -> np.ndarray:
    """The stops `d` holds, in order (stops are small non-negative integers: a table, not a sort)."""
    return np.flatnonzero(np.bincount(d.stop) > 0)


def range_bin_index(z_m: np.ndarray) -> np.ndarray:
    """0.25 m windows centred on multiples of 0.25 m, so a perpendicular stop falls in one window."""
    return np.round(np.asarray(z_m) / RANGE_BIN_M).astype(np.int64)


def load_samples(recording: Any, *, min_count: int = 2, positive_variance: bool = False) -> ModelData:
    """All pixels with at least `min_count` valid samples (with `positive_variance`, also a positive sample
    variance), from every complete stop of an open `Recording`, read once (`rig.models.data.loading`)."""
    r = read_rows(recording, min_count=min_count, positive_variance=positive_variance)
    f = r.facts
    t0 = np.nanmin(f["time_s"]) if np.isfinite(f["time_s"]).any() else 0.0
    stops = StopTable(tuple(f["label"]), np.array(f["frames"]), np.array(f["series_var_inv2"]), np.array(f["n_valid"]),
                      np.array(f["time_s"]) - t0, **{k: np.array(f[k], float) for k in LAG1_FACTS},
                      truth_m=np.array(f["truth_m"], float), truth_source=tuple(f["truth_source"]))
    cal = recording.calibration
    return ModelData(**r.arrays, fb_px_m=cal.fx * cal.baseline_m, depth_unit_m=cal.depth_scale_m, stops=stops,
                     sources=r.sources, calibration=cal, n_dropped_zero=r.dropped_zero)


@njit(cache=True, nogil=True)
def _true_range(z_m, v_m2, stop, m2_m2, nu, out):  # pragma: no cover - compiled
    """`ModelData.z0_m` into `out`: Z0 = Z / (1 + v / Z^2) (eq. dist_to_disp to second order), v the neighbours'
    variance `v_m2` (m^2) or, where it is NaN, the stop's pooled variance sum M2 / sum nu."""
    stops = 0
    for i in range(stop.size):  # a loop, not stop.max(): numba's reductions took a second to compile
        stops = max(stops, stop[i] + 1)
    sum_m2, sum_nu = np.zeros(stops), np.zeros(stops)
    for i in range(z_m.size):  # in row order, as numpy's bincount adds
        sum_m2[stop[i]] += m2_m2[i]
        sum_nu[stop[i]] += nu[i]
    for s in range(stops):
        sum_m2[s] /= max(sum_nu[s], 1e-300)
    for i in range(z_m.size):
        v = v_m2[i] if np.isfinite(v_m2[i]) else sum_m2[stop[i]]
        out[i] = z_m[i] / (1.0 + v / (z_m[i] * z_m[i]))
