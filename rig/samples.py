"""Pixel samples: every valid pixel of every stop, pooled, as the fits and diagnostics use them.

Each row is one pixel at one stop: its mean range z_m, the sum of squared deviations of its
samples from that mean (m2_m2, in m^2), and its sample count n. A pixel with n samples gives
n - 1 degrees of freedom to a variance, because its mean was estimated from the same samples.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .recording import Recording


@dataclass
class PixelSamples:
    """Pooled per-pixel statistics with the covariates models may need."""

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

    @property
    def dof(self) -> np.ndarray:
        return self.n - 1.0

    def __len__(self) -> int:
        return len(self.z_m)

    def select(self, mask: np.ndarray) -> "PixelSamples":
        return PixelSamples(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})

    def in_range(self, z_min_m: float, z_max_m: float) -> "PixelSamples":
        return self.select((self.z_m >= z_min_m) & (self.z_m <= z_max_m))

    @property
    def total_samples(self) -> int:
        return int(self.n.sum())


#: the matching window over which brightness is averaged (px)
BRIGHTNESS_WINDOW_PX = 7


def load_samples(recording: Recording, *, min_count: int = 2) -> PixelSamples:
    """All pixels with at least `min_count` valid samples, from every complete stop, with covariates."""
    from .covariates import ambient_ratio, drift_inverse_variance, drift_variance_m2, incidence_cosine, smoothed

    cal = recording.calibration
    parts: dict[str, list[np.ndarray]] = {f.name: [] for f in fields(PixelSamples)}
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
    return PixelSamples(**{k: np.concatenate(v) for k, v in parts.items()})
