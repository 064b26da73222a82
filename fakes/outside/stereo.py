"""Disparity noise from the IR signal, and depth from disparity.

Disparity variance of a maximum-likelihood window match (Matthies 1989, as Huber et al. eq. 7 state it):
sigma_d^2 = sigma_n^2 / sum_W I'^2. With the projected dots as the only texture, the intensity gradient scales with
the signal, I' = c S per native pixel (c: the dots' RMS gradient relative to the mean signal), so
sum_W I'^2 = n_W c^2 S^2; the image noise of the two imagers adds, sigma_n^2 = sigma_l^2 + sigma_r^2 =
(S_l + r^2) + (S_r + r^2) (Poisson shot noise plus read noise r). With S = (S_l + S_r) / 2:

    sigma_d^2 = 2 (S + r^2) / (n_W c^2 S^2)        [native px^2]

Pure shot noise (r = 0): sigma_d ∝ S^(-1/2); with S ∝ Z^-2 (the projector's light, Huber et al. eq. 15),
sigma_d ∝ Z and sigma_Z = Z^2 sigma_d / (f b) ∝ Z^3 (their eq. 21). Read noise adds sigma_d ∝ r / S ∝ Z^2 where
the signal is weak. Depth Z = f b / d (Huber et al. eq. 8; Intel white paper), reported in integer counts of the
depth unit, 0 where there is no match.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Matcher:
    window_px: int = 7                 # n_W = 7 x 7 native pixels (assumed; D4xx correlation windows are a few px)
    dot_gradient_rms: float = 0.15     # c: RMS gradient of the imaged dots per px, relative to the mean signal

    def disparity_sigma_px(self, signal_e: np.ndarray, read_noise_e: float) -> np.ndarray:
        """sigma_d = sqrt(2 (S + r^2) / (n_W c^2 S^2)), native px."""
        s = np.asarray(signal_e, dtype=float)
        n_w = self.window_px**2
        return np.sqrt(2.0 * (s + read_noise_e**2) / (n_w * self.dot_gradient_rms**2 * s**2))


def depth_counts(disparity_px: np.ndarray, fb_px_m: float, depth_unit_m: float, valid: np.ndarray) -> np.ndarray:
    """Z = f b / d in integer counts of depth_unit_m (rounded to the nearest), 0 where invalid, d <= 0, or beyond
    the 16-bit range."""
    with np.errstate(divide="ignore", invalid="ignore"):
        counts = np.rint(fb_px_m / disparity_px / depth_unit_m)
    ok = valid & (disparity_px > 0) & (counts >= 1) & (counts <= 65535)
    return np.where(ok, counts, 0).astype(np.uint16)
