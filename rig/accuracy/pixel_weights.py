"""Each pixel's weight in the accuracy's fits: its noise's variance plus the wall's relief, estimated from the data.

A pixel's mean depth over a stop's n frames scatters about the truth by two things: its temporal noise, variance
v = var_Z / n (var_Z the noise model's where given), and the wall's own relief (a real wall is not flat to the
depth unit, and the matcher's window spreads it), variance r^2, the same at every pixel. The maximum-likelihood
weight is 1 / (v + r^2). r^2 is the method-of-moments (DerSimonian-Laird, generalised to a linear model) estimate:
with W = diag(1 / v) and P = W - W A (A^T W A)^-1 A^T W,

    r^2 = max(0, (Q - (N - p)) / tr(P)),   Q = y^T P y    (DerSimonian & Laird 1986, in meta-regression's form)

one pass, no iteration. The fit is then weighted least squares at 1 / (v + r^2), with the Cramer-Rao covariance
(A^T W* A)^-1; Q, the chi^2 at the noise alone, says how far the pixels scatter beyond it.

Without the noise model's variance, v is not each pixel's own sample variance: that is noisy, and a pixel whose
variance came out low by chance would weigh more while its curvature correction (Z - s^2 / Z) came out high,
biasing the mean. The stop's own power law is used instead: ln s^2 fitted as a line in ln Z over the stop's pixels
(the base noise law, eq. sigma_Z = k Z^lambda, fitted to one stop) where the stop spans a range (a tilted wall),
the stop's median variance where it does not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


#: the least span of ln Z (1st to 99th percentile) over which a stop's power law of variance is fitted: 10 %
MIN_LN_SPAN = 0.1


@dataclass(frozen=True)
class WeightedFit:
    """A linear model y = A coef fitted at weights 1 / (v + relief_var) (module docstring)."""

    coef: np.ndarray
    covariance: np.ndarray
    chi2_noise: float  # Q: the residuals against the noise alone, at the noise's weights
    dof: int
    relief_var: float  # r^2, in y's units squared


def noise_of_mean(z_m: np.ndarray, s2_m2: np.ndarray, n: np.ndarray, var_m2: np.ndarray | None) -> np.ndarray:
    """The variance of each pixel's mean depth, m^2: the noise model's `var_m2` / n where given, else the stop's own
    power law of its pixels' sample variance in Z (module docstring) / n. `z_m`, `s2_m2`, `n`: one stop's pixels."""
    n = np.asarray(n, dtype=float)
    if var_m2 is not None:
        return np.asarray(var_m2, dtype=float) / n
    ok = (s2_m2 > 0) & np.isfinite(s2_m2) & (z_m > 0) & np.isfinite(z_m)
    ln_z, ln_s2 = np.log(z_m[ok]), np.log(s2_m2[ok])
    if len(ln_z) < 3 or np.subtract(*np.percentile(ln_z, [99, 1])) < MIN_LN_SPAN:
        # one range (a perpendicular stop): the stop's median variance at every pixel. A line through the noise of Z
        # alone would be steep and wrong: a pixel's mean is high by its own variance (Z - s^2 / Z), so ln s^2 rises
        # with ln Z there, and weights from it would pull the mean down
        level = float(np.median(s2_m2[ok])) if ok.any() else np.nan
        return np.full(len(z_m), level) / n
    slope, intercept = np.polyfit(ln_z, ln_s2, 1)
    return np.exp(intercept + slope * np.log(z_m)) / n


def relief_weighted_fit(y: np.ndarray, v: np.ndarray, a: np.ndarray) -> WeightedFit:
    """y = A coef at weights 1 / (v + r^2), r^2 by the generalised DerSimonian-Laird estimate (module docstring)."""
    w = 1.0 / v
    aw = a * w[:, None]
    normal = a.T @ aw
    coef0 = np.linalg.solve(normal, aw.T @ y)
    resid = y - a @ coef0
    q = float(np.sum(w * resid * resid))
    n_obs, p = a.shape
    trace_p = float(np.sum(w) - np.trace(np.linalg.solve(normal, (a * (w * w)[:, None]).T @ a)))
    relief = max(0.0, (q - (n_obs - p)) / trace_p) if trace_p > 0 else 0.0
    ws = 1.0 / (v + relief)
    aws = a * ws[:, None]
    normal_s = a.T @ aws
    coef = np.linalg.solve(normal_s, aws.T @ y)
    return WeightedFit(coef, np.linalg.inv(normal_s), q, n_obs - p, relief)
