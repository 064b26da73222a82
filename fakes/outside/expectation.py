"""What the scene's physics predicts for the statistics rig records, without drawing noise: each pixel's mean and
variance of the depth over a stop, and the (k, lambda) that a maximum-likelihood fit of sigma_Z = k Z^lambda converges
to on those moments (Huber et al. sec. III-C, with n - 1 degrees of freedom a pixel).

Moments of Z = f b / d for d ~ N(d0 + delta_d(t), sigma_d^2) by Gauss-Hermite quadrature (exact for the smooth 1/d
while sigma_d << d0; the delta method sigma_Z = Z^2 sigma_d / (f b) is its first order); a miscalibrated camera
(calibration.py) reports (1 + e) f b / d with its constant offset delta in d. A frame-varying offset
delta_d(t) adds the variance of the frame means (law of total variance). Rounding to a depth unit u adds u^2 / 12
(Sheppard's correction; accurate when sigma_Z > u).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .sweep import Sweep, StopMaps


@dataclass(frozen=True)
class StopMoments:
    z_m: float
    mean_m: np.ndarray        # (H, W), NaN where no depth
    var_m2: np.ndarray
    max_relative_sigma_d: float


def stop_moments(sweep: Sweep, index: int, maps: StopMaps, n_nodes: int = 24) -> StopMoments:
    nodes, weights = np.polynomial.hermite_e.hermegauss(n_nodes)
    weights = weights / weights.sum()
    offsets = (sweep.drift.offset_px(sweep.clock.frame_times_s(index, sweep.frames_per_stop))
               + sweep.miscalibration.disparity_offset_px)
    d = (maps.disparity_px + offsets[:, None, None, None]
         + maps.sigma_d_px[None, :, :, None] * nodes[None, None, None, :])
    z = sweep.reported_fb_px_m / d
    frame_mean = (z * weights).sum(axis=-1)
    frame_var = (z**2 * weights).sum(axis=-1) - frame_mean**2
    mean = frame_mean.mean(axis=0)
    var = frame_var.mean(axis=0) + frame_mean.var(axis=0) + sweep.depth_unit_m**2 / 12
    mean = np.where(maps.valid, mean, np.nan)
    var = np.where(maps.valid, var, np.nan)
    return StopMoments(maps.z_m, mean, var, float(np.max(maps.sigma_d_px / maps.disparity_px)))


def population_fit(moments: list[StopMoments], dof_per_pixel: int) -> tuple[float, float]:
    """(k, lambda) minimising the expected negative log-likelihood sum_i nu_i [log s_i^2 + v_i / s_i^2],
    s_i = k mu_i^lambda: k^2 = mean(v_i mu_i^(-2 lambda)) in closed form, lambda by a bounded scalar search."""
    from scipy.optimize import minimize_scalar  # 410 ms to import (tests/test_layers.py LAZY): the answer only

    mu = np.concatenate([m.mean_m[np.isfinite(m.mean_m)] for m in moments])
    v = np.concatenate([m.var_m2[np.isfinite(m.var_m2)] for m in moments])
    log_mu = np.log(mu)

    def profile(lam: float) -> float:
        k2 = np.mean(v * np.exp(-2 * lam * log_mu))
        return dof_per_pixel * (mu.size * np.log(k2) + 2 * lam * log_mu.sum())

    lam = minimize_scalar(profile, bounds=(0.0, 6.0), method="bounded", options={"xatol": 1e-7}).x
    k = float(np.sqrt(np.mean(v * np.exp(-2 * lam * log_mu))))
    return k, float(lam)
