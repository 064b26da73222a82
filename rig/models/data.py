"""What models are fitted to: every pixel of every stop, with the covariates effects use, and its likelihood.

Each row is one pixel at one stop: its mean range z_m, the sum of squared deviations of its
samples from that mean (m2_m2, in m^2), and its sample count n. A pixel with n samples gives
nu = n - 1 degrees of freedom to a variance, because its mean was estimated from the same
samples; its sample variance is s2 = m2 / nu.

The likelihood (`ModelData.loglik`) has two parts. Each pixel's s2 is Gamma-distributed with
mean sigma^2 (the model's variance) and var(s2) = sigma^4 (2 / nu + excess / n), the excess
kurtosis measured (model-free) in the pixel's range window; with excess = 0 this is exactly
the paper's Gaussian likelihood of the samples about the pixel means (paper, "Experimental
parameter estimation"). And the measured kurtosis of each range window is normal about the
kurtosis the model predicts (3 plus its fourth cumulant over sigma^4), with its own standard
error: heavy tails (outliers) or truncation (censoring) show there, and a model cannot buy
tolerance for a wrong variance by claiming a scatter the data do not have. And each stop's
fill rate (the share of its pixel-frames with a sample) is normal about the model's, with its
binomial standard error: samples a model says are dropped (censoring) must be missing. The Gamma part
needs s2 > 0: `positive_variance()` drops the pixels whose samples were all equal, as
`from_recording` does.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
from scipy.special import gammaln

from protocols.recording import Recording, StopData

#: the matching window over which brightness is averaged (px)
BRIGHTNESS_WINDOW_PX = 7
#: side of the square of neighbouring pixels, centred on a pixel, whose pooled variance standardises its fourth moment
KURTOSIS_WINDOW_PX = 7
#: range windows of the kurtosis term and of the diagnosis (m)
RANGE_BIN_M = 0.25
#: rounding to the depth unit adding more than this share of the variance makes a pixel's kurtosis meaningless
ROUNDING_SHARE = 0.02
#: usable pixels a range window needs for its kurtosis to count
MIN_KURTOSIS_PIXELS = 20


@dataclass(frozen=True)
class StopTable:
    """One entry per stop, in the order of `ModelData.stop`.

    frames: frames captured; series_var_inv2: the variance over frames of the frame's mean of
    1/z - 1/z_first over valid pixels, (1/m)^2 (NaN if not recorded): independent pixel noise
    makes it mean(var / Z^4) / n_valid, a common wander (drift) or noise shared by neighbouring
    pixels makes it larger; n_valid: valid pixels in a frame, on average; time_s: the stop's
    middle, s after the first stop began (NaN if the camera gave no timestamps).
    """

    label: tuple[str, ...]
    frames: np.ndarray
    series_var_inv2: np.ndarray
    n_valid: np.ndarray
    time_s: np.ndarray


@dataclass(eq=False)
class ModelData:
    """Pooled per-pixel statistics with the covariates models may need, and the camera's f*b and depth unit."""

    z_m: np.ndarray  # pixel mean range, m
    m2_m2: np.ndarray  # sum of (z_i - z_mean)^2 over the pixel's samples, m^2
    m4_m4: np.ndarray  # sum of (z_i - z_mean)^4, m^4 (NaN where not recorded)
    n: np.ndarray  # valid samples at this pixel
    stop: np.ndarray  # index of the stop the row comes from
    u_px: np.ndarray  # pixel column
    v_px: np.ndarray  # pixel row
    ir: np.ndarray  # mean IR brightness, DN, smoothed over the matching window (NaN where not recorded)
    fill: np.ndarray  # fraction of the stop's frames in which the pixel was valid
    rho2: np.ndarray  # squared normalised radius from the principal point: ((u-cx)/fx)^2 + ((v-cy)/fy)^2
    cos_inc: np.ndarray  # cosine of the incidence angle on a plane fitted to the stop's mean depth
    ambient_ratio: np.ndarray  # ambient / pattern brightness from the projector-off frames (NaN if none)
    drift_var_m2: np.ndarray  # variance of the stop's mean depth over its frames, beyond noise, scaled to this pixel's range
    projector_on: np.ndarray  # the stop's projector state
    x_norm: np.ndarray | None = None  # normalised image coordinates (u - cx) / fx and (v - cy) / fy
    y_norm: np.ndarray | None = None
    fb_px_m: float = float("nan")  # focal length (px) times baseline (m)
    depth_unit_m: float = float("nan")
    n_dropped_zero: int = 0  # pixels left out because all their samples were equal (s2 = 0)
    stops: StopTable | None = None  # per-stop facts (frames, the frame-mean series, time), indexed by `stop`

    #: the per-pixel arrays (x_norm and y_norm may be None in data built by hand)
    ARRAYS = ("z_m", "m2_m2", "m4_m4", "n", "stop", "u_px", "v_px", "ir", "fill", "rho2", "cos_inc", "ambient_ratio",
              "drift_var_m2", "projector_on", "x_norm", "y_norm")

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def from_recording(cls, path: Any) -> "ModelData":
        """Every pixel with a positive sample variance, from every complete stop of the recording at `path`."""
        with Recording(path) as rec:
            return load_samples(rec).positive_variance()

    def select(self, mask: np.ndarray) -> "ModelData":
        return replace(self, **{k: getattr(self, k)[mask] for k in self.ARRAYS if getattr(self, k) is not None})

    def in_range(self, z_min_m: float, z_max_m: float) -> "ModelData":
        return self.select((self.z_m >= z_min_m) & (self.z_m <= z_max_m))

    def positive_variance(self) -> "ModelData":
        """The pixels the likelihood can use (s2 > 0); the others are counted in n_dropped_zero."""
        keep = self.m2_m2 > 0
        return replace(self.select(keep), n_dropped_zero=self.n_dropped_zero + int(np.sum(~keep)))

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

    # -- the distribution's shape, measured ------------------------------------------------------------
    @cached_property
    def neighbour_variance(self) -> tuple[np.ndarray, np.ndarray]:
        """For each pixel, the variance pooled over the other pixels of the KURTOSIS_WINDOW_PX square centred
        on it at the same stop, and its degrees of freedom (NaN where too few, or positions unknown). Centred,
        so a variance changing linearly across the image is the pixel's own on average."""
        if len(self) == 0 or not (np.isfinite(self.u_px).all() and np.isfinite(self.v_px).all()):
            nan = np.full(len(self), np.nan)
            return nan, nan
        from scipy.ndimage import uniform_filter

        u, v = self.u_px.astype(np.int64), self.v_px.astype(np.int64)
        shape = (int(v.max()) + 1, int(u.max()) + 1)
        m2_out, nu_out = np.empty(len(self)), np.empty(len(self))
        size = KURTOSIS_WINDOW_PX * KURTOSIS_WINDOW_PX
        for s in np.unique(self.stop):
            m = self.stop == s
            m2_img, nu_img = np.zeros(shape), np.zeros(shape)
            m2_img[v[m], u[m]] = self.m2_m2[m]
            nu_img[v[m], u[m]] = self.nu[m]
            m2_sum = uniform_filter(m2_img, KURTOSIS_WINDOW_PX, mode="constant") * size
            nu_sum = uniform_filter(nu_img, KURTOSIS_WINDOW_PX, mode="constant") * size
            m2_out[m] = m2_sum[v[m], u[m]] - self.m2_m2[m]
            nu_out[m] = np.round(nu_sum[v[m], u[m]] - self.nu[m])
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(nu_out > 4, m2_out / nu_out, np.nan), np.where(nu_out > 4, nu_out, np.nan)

    @cached_property
    def pixel_kurtosis(self) -> np.ndarray:
        """Each pixel's unbiased estimate of its samples' kurtosis (3 for a normal distribution).

        M4 is standardised by the variance v its neighbours measure (`neighbour_variance`), not by
        a model's variance, which is what is in doubt. For samples about their own mean,
        E[M4] / sigma^4 = (n - 1) / n^2 ((n^2 - 3n + 3) beta + 3 (2n - 3)); v's own noise is removed
        by E[1 / v^2] = nu^2 / ((nu - 2)(nu - 4)) / sigma^4 (v ~ sigma^2 chi2_nu / nu). NaN where it
        cannot be formed."""
        v, nu_v = self.neighbour_variance
        n = self.n
        with np.errstate(invalid="ignore", divide="ignore"):
            m4_over_sigma4 = self.m4_m4 / v**2 * (nu_v - 2) * (nu_v - 4) / nu_v**2
            return (m4_over_sigma4 * n**2 / (n - 1) - 3 * (2 * n - 3)) / (n**2 - 3 * n + 3)

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
        stop_pooled = np.bincount(self.stop, weights=self.m2_m2) / np.maximum(np.bincount(self.stop, weights=self.nu), 1e-300)
        v = np.where(np.isfinite(v), v, stop_pooled[self.stop])
        return self.z_m / (1.0 + v / self.z_m**2)

    def disparity_to_range(self, var_px2: np.ndarray | float) -> np.ndarray:
        """Variance in px^2 of disparity -> m^2 of range: (Z^2 / (f b))^2 var_d (paper, eq. error_prop_unassisted)."""
        return (self.z0_m**2 / self.fb_px_m) ** 2 * var_px2

    # -- likelihood ---------------------------------------------------------------------------------
    @cached_property
    def range_group(self) -> np.ndarray:
        """Each pixel's range window: 0.25 m windows centred on multiples of 0.25 m (`range_bin_index`)."""
        return range_bin_index(self.z_m)

    @cached_property
    def kurtosis_usable(self) -> np.ndarray:
        """Pixels whose kurtosis estimate means something: formed, and not dominated by rounding to the
        depth unit (q^2 / 12 below ROUNDING_SHARE of the neighbours' variance), where the samples are
        a few discrete levels whose spread depends on each pixel's own position between them."""
        v, _ = self.neighbour_variance
        q2 = self.depth_unit_m**2 if np.isfinite(self.depth_unit_m) else 0.0
        with np.errstate(invalid="ignore"):
            return np.isfinite(self.pixel_kurtosis) & (q2 / 12 < ROUNDING_SHARE * v)

    @cached_property
    def kurtosis_by_range(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(range windows, measured kurtosis, its standard error) for windows with MIN_KURTOSIS_PIXELS usable pixels."""
        windows, measured, se = [], [], []
        use = self.kurtosis_usable
        for g in np.unique(self.range_group):
            m = (self.range_group == g) & use
            if m.sum() < MIN_KURTOSIS_PIXELS:
                continue
            k, e = pooled_kurtosis(self.pixel_kurtosis[m], self.n[m])
            if np.isfinite(k) and e > 0:
                windows.append(g)
                measured.append(k)
                se.append(e)
        return np.array(windows, dtype=np.int64), np.array(measured), np.array(se)

    @cached_property
    def _excess_measured(self) -> np.ndarray:
        """Each pixel's excess kurtosis as its range window measures it (0 where not measured), for the
        Gamma law's shape: the scatter of s2 across pixels comes from the data, not from a model."""
        windows, measured, _ = self.kurtosis_by_range
        excess = np.zeros(len(self))
        for g, k in zip(windows, measured):
            excess[self.range_group == g] = k - 3.0
        return np.maximum(excess, -1.5)

    @cached_property
    def _gamma_shape(self) -> np.ndarray:
        return np.maximum(1.0 / np.maximum(2.0 / self.nu + self._excess_measured / self.n, 1e-12), 0.5)

    @cached_property
    def _gamma_const(self) -> float:
        """The data-only terms of the Gamma log-likelihood."""
        a = self._gamma_shape
        return float(np.sum(a * np.log(a) - gammaln(a) + (a - 1) * np.log(self.s2_m2)))

    def loglik_terms(self, var: np.ndarray) -> np.ndarray:
        """Per-pixel Gamma log-likelihood of the sample variances given the predicted variance (m^2),
        without the data-only terms (`loglik` adds them)."""
        a = self._gamma_shape
        return -a * np.log(var) - a * self.s2_m2 / var

    def kurtosis_loglik(self, var: np.ndarray, k4: np.ndarray | None) -> float:
        """The measured kurtosis by range window against the model's, each window normal with its own
        standard error: -1/2 sum ((K_measured - K_predicted) / se)^2."""
        windows, measured, se = self.kurtosis_by_range
        if not len(windows):
            return 0.0
        use = self.kurtosis_usable
        w = np.where(use, self.n, 0.0)
        excess = np.zeros(len(self)) if k4 is None else np.where(use, k4 / var**2, 0.0)
        size = int(self.range_group.max()) + 1 if len(self) else 0
        offset = int(self.range_group.min()) if len(self) else 0
        idx = self.range_group - offset
        predicted = 3.0 + np.bincount(idx, weights=w * excess, minlength=size) / np.maximum(
            np.bincount(idx, weights=w, minlength=size), 1e-300)
        z = (measured - predicted[windows - offset]) / se
        return float(-0.5 * np.sum(z * z))

    @cached_property
    def fill_by_stop(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(stop of each pixel as 0..S-1, measured mean fill per stop, its binomial standard error)."""
        stops, idx = np.unique(self.stop, return_inverse=True)
        frames = self.n / np.maximum(self.fill, 1e-12)
        count = np.bincount(idx, minlength=len(stops)).astype(float)
        measured = np.bincount(idx, weights=self.fill, minlength=len(stops)) / count
        binomial = np.sqrt(np.bincount(idx, weights=self.fill * (1 - self.fill) / frames, minlength=len(stops))) / count
        one_sample = 1.0 / np.bincount(idx, weights=frames, minlength=len(stops))
        return idx, measured, np.maximum(binomial, one_sample)

    def fill_loglik(self, fill: np.ndarray | None) -> float:
        """The measured fill rate of each stop against the model's, normal with its binomial standard error."""
        if len(self) == 0:
            return 0.0
        idx, measured, se = self.fill_by_stop
        if fill is None:
            predicted = np.ones(len(measured))
        else:
            f = np.broadcast_to(np.asarray(fill, dtype=float), self.z_m.shape)
            predicted = np.bincount(idx, weights=f, minlength=len(measured)) / np.bincount(idx, minlength=len(measured))
        z = (measured - predicted) / se
        return float(-0.5 * np.sum(z * z))

    def loglik(self, var: np.ndarray, k4: np.ndarray | None, fill: np.ndarray | None = None) -> float:
        """The composite log-likelihood: every pixel's variance (Gamma, its scatter from the measured
        kurtosis), the measured kurtosis by range window and the fill rate by stop against the model's."""
        return (float(np.sum(self.loglik_terms(var))) + self._gamma_const + self.kurtosis_loglik(var, k4)
                + self.fill_loglik(fill))


def range_bin_index(z_m: np.ndarray) -> np.ndarray:
    """0.25 m windows centred on multiples of 0.25 m, so a perpendicular stop falls in one window."""
    return np.round(np.asarray(z_m) / RANGE_BIN_M).astype(np.int64)


def pooled_kurtosis(beta: np.ndarray, n: np.ndarray) -> tuple[float, float]:
    """Samples-weighted mean of pixel kurtosis estimates, and its standard error from their scatter."""
    ok = np.isfinite(beta)
    if ok.sum() < 3:
        return float("nan"), float("nan")
    b, w = beta[ok], n[ok]
    mean = float(np.sum(w * b) / np.sum(w))
    se = float(np.sqrt(np.sum(w**2 * (b - mean) ** 2) / (ok.sum() - 1) * ok.sum()) / np.sum(w))
    return mean, se


def load_samples(recording: Recording, *, min_count: int = 2) -> ModelData:
    """All pixels with at least `min_count` valid samples, from every complete stop, with covariates."""
    from .covariates import ambient_ratio, drift_inverse_variance, drift_variance_m2, incidence_cosine, smoothed

    cal = recording.calibration
    parts: dict[str, list[np.ndarray]] = {name: [] for name in ModelData.ARRAYS}
    table: dict[str, list] = {"label": [], "frames": [], "series_var_inv2": [], "n_valid": [], "time_s": []}
    for i, stop in enumerate(recording.stops()):
        s = stop.stats
        keep = (s.count >= max(2, min_count)) & np.isfinite(s.mean_m) & (s.mean_m > 0)
        v, u = np.nonzero(keep)
        n = len(u)
        n_frames = max(stop.n_frames, 1)
        z = s.mean_m[keep]
        parts["z_m"].append(z)
        parts["m2_m2"].append(s.m2_m2[keep])
        parts["m4_m4"].append(s.m4_m4[keep])
        parts["n"].append(s.count[keep].astype(np.float64))
        parts["stop"].append(np.full(n, i, np.int32))
        parts["u_px"].append(u.astype(np.float32))
        parts["v_px"].append(v.astype(np.float32))
        ir = smoothed(stop.ir_mean, BRIGHTNESS_WINDOW_PX)[keep] if stop.ir_mean is not None else np.full(n, np.nan)
        parts["ir"].append(ir)
        parts["fill"].append(s.count[keep] / n_frames)
        xn, yn = (u - cal.cx) / cal.fx, (v - cal.cy) / cal.fy
        parts["x_norm"].append(xn)
        parts["y_norm"].append(yn)
        parts["rho2"].append(xn**2 + yn**2)
        parts["cos_inc"].append(incidence_cosine(s.mean_m, keep, cal)[keep])
        amb = ambient_ratio(stop.ir_mean, stop.ambient_ir_mean, BRIGHTNESS_WINDOW_PX)
        parts["ambient_ratio"].append(amb[keep] if amb is not None else np.full(n, np.nan))
        d_inv = drift_inverse_variance(stop)
        if d_inv is not None:
            parts["drift_var_m2"].append(d_inv * z**4)
        else:  # recordings without the whole-frame series: the central region's mean depth
            d_var, z_c = drift_variance_m2(stop)
            parts["drift_var_m2"].append(d_var * (z / z_c) ** 4 if np.isfinite(z_c) else np.zeros(n))
        parts["projector_on"].append(np.full(n, stop.projector_on))
        _add_stop_facts(table, stop)
    if not parts["z_m"] or sum(len(a) for a in parts["z_m"]) == 0:
        raise ValueError(f"{recording.path}: no pixel has 2 or more valid samples; nothing to fit (check the stops and the camera's fill rate)")
    if not any(np.any(a > 0) for a in parts["m2_m2"]):
        raise ValueError(f"{recording.path}: every pixel's samples are identical (zero variance), so there is no noise to "
                         "fit; the frames are copies of one image: record or import frames captured one after another")
    t0 = np.nanmin(table["time_s"]) if np.isfinite(table["time_s"]).any() else 0.0
    stops = StopTable(tuple(table["label"]), np.array(table["frames"]), np.array(table["series_var_inv2"]),
                      np.array(table["n_valid"]), np.array(table["time_s"]) - t0)
    return ModelData(**{k: np.concatenate(v) for k, v in parts.items()},
                     fb_px_m=cal.fx * cal.baseline_m, depth_unit_m=cal.depth_scale_m, stops=stops)


def _add_stop_facts(table: dict[str, list], stop: StopData) -> None:
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

