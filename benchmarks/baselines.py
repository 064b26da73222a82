"""What rig is measured against: the least work a per-frame pass can do, a textbook streaming variance, the
paper's likelihood in a short script on the same file, and the paper's per-sample MLE without subsampling."""

from __future__ import annotations

import numpy as np

#: the 60-line script the issue measured `rig fit` against: the paper's likelihood from the recording's
#: per-pixel statistics, read with h5py alone, k in closed form and lambda by scipy's bounded search
PAPER_SCRIPT = r'''
import sys, h5py, numpy as np
from scipy.optimize import minimize_scalar
z, m2, w = [], [], []
with h5py.File(sys.argv[1], "r") as f:
    for label in f["stops"]:
        g = f["stops"][label]
        count = g["count"][()]
        keep = count >= 2
        z.append(g["mean_m"][()][keep]); m2.append(g["m2_m2"][()][keep]); w.append(count[keep] - 1.0)
z, m2, w = np.concatenate(z), np.concatenate(m2), np.concatenate(w)
W = w.sum(); lz = np.log(z); lz = lz - np.sum(w * lz) / W
def profile(lam):
    return 0.5 * W * np.log(np.sum(m2 * np.exp(-2 * lam * lz)) / W)
lam = minimize_scalar(profile, bounds=(-2, 8), method="bounded", options={"xatol": 1e-10}).x
k_ref = np.sqrt(np.sum(m2 * np.exp(-2 * lam * lz)) / W)
k = k_ref * np.exp(-lam * np.sum(w * np.log(z)) / W)
print(repr(float(k)), repr(float(lam)))
'''


class Welford:
    """A textbook streaming mean and variance per pixel (float64, two moments): the baseline of the statistics."""

    def __init__(self, shape: tuple[int, int]):
        self.n = np.zeros(shape)
        self.mean = np.zeros(shape)
        self.m2 = np.zeros(shape)

    def add(self, frame: np.ndarray) -> None:
        x = frame.astype(np.float64)
        self.n += 1
        delta = x - self.mean
        self.mean += delta / self.n
        self.m2 += delta * (x - self.mean)


def per_sample_mle(raw: list[np.ndarray], scale_m: float) -> tuple[float, float, int]:
    """The paper's MLE over every raw sample (no per-pixel statistics): z_i ~ N(mean_p, (k mean_p^lambda)^2), the
    pixel means estimated from the same samples (so each pixel's n samples carry n - 1 degrees of freedom, as
    rig's likelihood has them), maximised over (ln k, lambda) by scipy's L-BFGS-B with the gradient, from
    lambda = 2.5. `raw`: one array
    (frames, height, width) of depth units per stop. Returns (k, lambda, samples)."""
    from scipy.optimize import minimize

    z_all, mean_all, dof_all = [], [], []
    for frames in raw:
        valid = frames > 0
        count = valid.sum(axis=0)
        z = np.where(valid, frames * scale_m, np.nan)
        mean = np.nanmean(np.where(count >= 2, z, np.nan), axis=0)
        keep = valid & (count >= 2)
        z_all.append(z[keep])
        mean_all.append(np.broadcast_to(mean, frames.shape)[keep])
        dof_all.append(np.broadcast_to((count - 1.0) / np.maximum(count, 1), frames.shape)[keep])
    z, mean, dof = np.concatenate(z_all), np.concatenate(mean_all), np.concatenate(dof_all)
    log_mean = np.log(mean)
    sq = (z - mean) ** 2

    def negative_loglik(p: np.ndarray) -> tuple[float, np.ndarray]:
        log_k, lam = p
        log_sigma = log_k + lam * log_mean  # every sample's own sigma, every evaluation
        r = sq * np.exp(-2 * log_sigma)
        value = float(np.sum(dof * log_sigma + 0.5 * r))
        return value, np.array([np.sum(dof - r), np.sum((dof - r) * log_mean)])

    res = minimize(negative_loglik, np.array([np.log(0.002), 2.5]), jac=True, method="L-BFGS-B",
                   options={"ftol": 1e-15, "gtol": 1e-9, "maxiter": 1000})
    return float(np.exp(res.x[0])), float(res.x[1]), int(z.size)
