"""What models are fitted to: every pixel of every stop, with the covariates effects use, and its likelihood.

Each row is one pixel at one stop: its mean range z_m, the sum of squared deviations of its
samples from that mean (m2_m2, in m^2), and its sample count n. A pixel with n samples gives
nu = n - 1 degrees of freedom to a variance, because its mean was estimated from the same
samples; its sample variance is s2 = m2 / nu.

The likelihood (`ModelData.loglik`): each pixel's s2 is Gamma-distributed with mean sigma^2
and var(s2) = sigma^4 (2 / nu + excess / n), excess = k4 / sigma^4 (k4: the fourth cumulant a
model predicts). With excess = 0 this is exactly the paper's Gaussian likelihood of the
samples about the pixel means (paper, "Experimental parameter estimation"); heavy tails or
truncation change the scatter of s2 across pixels, which is how outliers and censoring are told
apart from effects that only change the variance. It needs s2 > 0: `positive_variance()` drops
the pixels whose samples were all equal, as `from_recording` does.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np
from scipy.special import gammaln

from protocols.recording import Recording

#: the matching window over which brightness is averaged (px)
BRIGHTNESS_WINDOW_PX = 7


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
    fb_px_m: float = float("nan")  # focal length (px) times baseline (m)
    depth_unit_m: float = float("nan")
    n_dropped_zero: int = 0  # pixels left out because all their samples were equal (s2 = 0)

    #: the per-pixel arrays, in field order
    ARRAYS = ("z_m", "m2_m2", "m4_m4", "n", "stop", "u_px", "v_px", "ir", "fill", "rho2", "cos_inc", "ambient_ratio",
              "drift_var_m2", "projector_on")

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def from_recording(cls, path: Any) -> "ModelData":
        """Every pixel with a positive sample variance, from every complete stop of the recording at `path`."""
        with Recording(path) as rec:
            return load_samples(rec).positive_variance()

    def select(self, mask: np.ndarray) -> "ModelData":
        return replace(self, **{k: getattr(self, k)[mask] for k in self.ARRAYS})

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

    # -- physics the models share -------------------------------------------------------------------
    def disparity_to_range(self, var_px2: np.ndarray | float) -> np.ndarray:
        """Variance in px^2 of disparity -> m^2 of range: (Z^2 / (f b))^2 var_d (paper, eq. error_prop_unassisted)."""
        return (self.z_m**2 / self.fb_px_m) ** 2 * var_px2

    # -- likelihood ---------------------------------------------------------------------------------
    @cached_property
    def _log_s2(self) -> np.ndarray:
        return np.log(self.s2_m2)

    @cached_property
    def _gamma_const(self) -> float:
        """The data-only terms of the Gamma log-likelihood with excess 0 (shape a = nu / 2)."""
        a = self.nu / 2.0
        return float(np.sum(a * np.log(a) - gammaln(a) + (a - 1) * self._log_s2))

    def loglik_terms(self, var: np.ndarray, k4: np.ndarray | None) -> np.ndarray:
        """Per-pixel log-likelihood of the sample variances under the Gamma law of the module docstring
        (without the data-only terms when k4 is None; `loglik` adds them)."""
        if k4 is None:
            a = self.nu / 2.0
            return -a * np.log(var) - a * self.s2_m2 / var
        excess = k4 / var**2
        a = 1.0 / np.maximum(2.0 / self.nu + excess / self.n, 1e-12)
        a = np.maximum(a, 0.5)
        return a * np.log(a) - gammaln(a) + (a - 1) * self._log_s2 - a * np.log(var) - a * self.s2_m2 / var

    def loglik(self, var: np.ndarray, k4: np.ndarray | None) -> float:
        t = self.loglik_terms(var, k4)
        if k4 is None:
            return float(np.sum(t)) + self._gamma_const
        return float(np.sum(t))


def load_samples(recording: Recording, *, min_count: int = 2) -> ModelData:
    """All pixels with at least `min_count` valid samples, from every complete stop, with covariates."""
    from .covariates import ambient_ratio, drift_inverse_variance, drift_variance_m2, incidence_cosine, smoothed

    cal = recording.calibration
    parts: dict[str, list[np.ndarray]] = {name: [] for name in ModelData.ARRAYS}
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
    if not parts["z_m"] or sum(len(a) for a in parts["z_m"]) == 0:
        raise ValueError(f"{recording.path}: no pixel has 2 or more valid samples; nothing to fit (check the stops and the camera's fill rate)")
    return ModelData(**{k: np.concatenate(v) for k, v in parts.items()},
                     fb_px_m=cal.fx * cal.baseline_m, depth_unit_m=cal.depth_scale_m)

