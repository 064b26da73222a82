"""The depth's bias against the stage's truth, modelled: a wall offset, a depth scale and a disparity offset.

A stereo camera reports Z = f b' / d'. With its f b off by a factor (1 + s) (a baseline or focal-length error) and
its disparity off by delta px (a rectification or subpixel bias), a wall at distance t from the stage's zero, c in
front of the camera's origin, reads

    Z(t) = (1 + s) f b / (f b / (t + c) + delta)            (eq. dist_to_disp with both errors)

so its bias Z - t is about c + s t - delta t^2 / (f b): a constant, a part growing as Z and one as Z^2, which
stops from 0.5 to 3 m tell apart. Each stop gives the mean over its pixels of Z - t (`stop_figures`; the curvature
of Z = f b / d taken out), with the standard error of that mean; (c, s, delta) are fitted by weighted least squares,
the maximum-likelihood estimate for normal errors, by Gauss-Newton from zero, with Cramer-Rao standard errors from
the inverse of J^T W J.

The stops can scatter about any smooth bias by more than their pixels' noise says: the stage's repeatability (its
measured position jitters), a wall not quite flat or not quite where the last stop left it. When chi^2 at the pixels'
errors alone exceeds its degrees of freedom, a between-stop variance tau^2 is added to every stop's error until
chi^2 equals them (the Paule-Mandel estimate), and the fit and its errors are taken there; tau is reported, and the
chi^2 at tau = 0 says whether the model alone is within the pixels' noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..models.parts.result import chi2_sf
from .stop_figures import StopAccuracy

#: the bias model's parameters, in the order they are fitted (fewer stops fit fewer: the first n - 1)
PARAMS = ("offset_m", "scale", "disparity_offset_px")
UNITS = {"offset_m": "m", "scale": "1", "disparity_offset_px": "px"}
MEANING = {"offset_m": "the wall's offset c from the stage's zero to the camera's origin",
           "scale": "the depth scale error s: f b is (1 + s) the true one (baseline or focal length)",
           "disparity_offset_px": "the disparity offset delta added to every disparity (px of the recorded image)"}


@dataclass(frozen=True)
class BiasFit:
    """The fitted bias model (see the module docstring) and the stops it was fitted to."""

    names: tuple[str, ...]
    values: dict[str, float]
    errors: dict[str, float]
    covariance: np.ndarray
    chi2: float  # at tau = 0: the stops against their pixels' errors alone
    dof: int
    p_value: float
    tau_m: float  # the between-stop scatter beyond the pixels' noise, m (0 when chi^2 <= dof)
    fb_px_m: float
    stops: tuple[StopAccuracy, ...]

    def bias_m(self, truth_m: np.ndarray | float, values: dict[str, float] | None = None) -> np.ndarray:
        """The modelled bias Z - t at stage distance `truth_m` (m)."""
        return model_bias(np.asarray(truth_m, dtype=float), values or self.values, self.fb_px_m)

    def corrected_m(self, z_m: np.ndarray | float) -> np.ndarray:
        """A measured depth with the bias taken out: the distance t + c from the camera's origin whose reading is z_m
        (the inverse of Z(t) above), m."""
        p = {**dict.fromkeys(PARAMS, 0.0), **self.values}
        fb = self.fb_px_m
        return 1.0 / ((1.0 + p["scale"]) / np.asarray(z_m, dtype=float) - p["disparity_offset_px"] / fb)

    @property
    def within_noise(self) -> bool:
        """The stops agree with the model within their pixels' noise (p >= 0.001 at tau = 0)."""
        return self.dof <= 0 or self.p_value >= 1e-3


def model_bias(t: np.ndarray, p: dict[str, float], fb: float) -> np.ndarray:
    """Z(t) - t, m (the module docstring's equation); parameters not in `p` are 0."""
    c, s, delta = (p.get(n, 0.0) for n in PARAMS)
    return (1.0 + s) * fb / (fb / (t + c) + delta) - t


def _jacobian(t: np.ndarray, p: dict[str, float], fb: float, names: tuple[str, ...]) -> np.ndarray:
    c, s, delta = (p.get(n, 0.0) for n in PARAMS)
    den = fb / (t + c) + delta
    cols = {"offset_m": (1.0 + s) * fb / den**2 * fb / (t + c) ** 2, "scale": fb / den,
            "disparity_offset_px": -(1.0 + s) * fb / den**2}
    return np.column_stack([cols[n] for n in names])


def _solve(t, y, var, fb, names) -> tuple[dict[str, float], np.ndarray, float]:
    """Gauss-Newton on the weighted squares: the values, the inverse of J^T W J and chi^2."""
    p = dict.fromkeys(names, 0.0)
    w = 1.0 / var
    for _ in range(100):
        r = y - model_bias(t, p, fb)
        j = _jacobian(t, p, fb, names)
        a = j.T @ (j * w[:, None])
        step = np.linalg.solve(a, j.T @ (w * r))
        p = {n: p[n] + float(x) for n, x in zip(names, step)}
        if np.all(np.abs(step) <= 1e-12 * (1.0 + np.abs(list(p.values())))):
            break
    r = y - model_bias(t, p, fb)
    j = _jacobian(t, p, fb, names)
    return p, np.linalg.inv(j.T @ (j * w[:, None])), float(np.sum(r * r * w))


def fit_bias(stops: list[StopAccuracy], fb_px_m: float) -> BiasFit | None:
    """The bias model fitted to the stops' mean bias (None with fewer than two stops: a constant and a scale need
    two). With three stops the disparity offset is not fitted (two parameters, one degree of freedom)."""
    use = [s for s in stops if math.isfinite(s.mean_bias_m) and s.mean_bias_se_m > 0]
    if len(use) < 2 or not (math.isfinite(fb_px_m) and fb_px_m > 0):
        return None
    names = PARAMS[: min(len(PARAMS), len(use) - 1)]
    t = np.array([s.truth_m for s in use])
    y = np.array([s.mean_bias_m for s in use])
    se2 = np.array([s.mean_bias_se_m for s in use]) ** 2
    dof = len(use) - len(names)
    p, cov, chi2 = _solve(t, y, se2, fb_px_m, names)
    chi2_0, tau2 = chi2, 0.0
    if dof > 0 and chi2 > dof:  # Paule-Mandel: the tau^2 at which chi^2 equals its degrees of freedom
        lo, hi = 0.0, float(np.var(y)) + float(np.max(se2))
        while _solve(t, y, se2 + hi, fb_px_m, names)[2] > dof:
            hi *= 4.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            if _solve(t, y, se2 + mid, fb_px_m, names)[2] > dof:
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-12 * hi:
                break
        tau2 = hi
        p, cov, _ = _solve(t, y, se2 + tau2, fb_px_m, names)
    errors = {n: float(math.sqrt(cov[i, i])) for i, n in enumerate(names)}
    return BiasFit(names, p, errors, cov, chi2_0, dof, chi2_sf(chi2_0, dof) if dof > 0 else math.nan,
                   math.sqrt(tau2), fb_px_m, tuple(use))
