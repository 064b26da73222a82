"""A tilted wall's plane, fitted from one stop: where the wall is, at what angle, and the depth against it.

A plane n . X = p seen through a pinhole has, along the ray X = Z (x, y, 1) (x = (u - cx) / fx, y = (v - cy) / fy),

    1 / Z = (n_z + n_x x + n_y y) / p = a + b x + c y        (the plan's wall: Z = D / (1 + tan(t) x), fakes/physics)

so the inverse depth is linear in x and y. The plane is fitted as that linear model by weighted least squares, each
pixel weighted by the variance of its mean 1/Z: its noise, var_Z / (n Z^4), plus the wall's relief estimated from the
pixels' scatter (rig.accuracy.pixel_weights), the maximum-likelihood estimate for normal errors, with its Cramer-Rao
covariance; chi^2 at the noise alone says how far the relief scatters the pixels beyond it.
The wall's distance on the optical axis is D = 1 / a, m; its tilt about the vertical axis atan(b / a), about the
horizontal atan(c / a), degrees.

The same linearity is why one tilted stop does not measure the camera's calibration: a depth scale (1 + s) and a
disparity offset delta (rig.accuracy.bias) turn 1/Z into (a + b x + c y + delta / fb) / (1 + s), linear again, a
plane at another distance and angle. A tilted stop measures the plane, the depth against the plan's plane, and the
depth's departure from any plane (spatial RMS: distortion, rectification); the scale and disparity offset are
measured on a perpendicular sweep.

The plan gives the tilt's size (`tilt_deg`, the wall's angle to the image plane) and not its direction, so the plan's
plane takes its sign from the fitted one; its distance is the stop's truth (`stop_checks.stop_truth`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..models.parts.result import chi2_sf
from .pixel_weights import relief_weighted_fit


@dataclass(frozen=True)
class WallPlane:
    """The fitted plane of a tilted wall (module docstring), with the plan's for comparison."""

    distance_m: float  # on the optical axis, 1 / a
    distance_se_m: float
    tilt_deg: float  # about the vertical axis (the plan's tilt): atan(b / a)
    tilt_se_deg: float
    tilt_x_deg: float  # about the horizontal axis: atan(c / a)
    tilt_x_se_deg: float
    chi2: float  # of the pixels' mean 1/Z about the plane, at their noise alone
    dof: int
    planned_distance_m: float
    planned_tilt_deg: float  # the plan's size of the tilt, with the fitted one's sign

    @property
    def relief_ratio(self) -> float:
        """sqrt(chi^2 / dof): how far the pixels scatter about the plane beyond their noise (1 within it)."""
        return math.sqrt(self.chi2 / self.dof) if self.dof > 0 else math.nan

    @property
    def p_value(self) -> float:
        return chi2_sf(self.chi2, self.dof) if self.dof > 0 else math.nan


def fit_plane(z_m: np.ndarray, var_mean_m2: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                             float, int]:
    """1/Z = a + b x + c y, each pixel weighted by its noise and the wall's relief (rig.accuracy.pixel_weights; the
    variance of 1/Z is var(Z) / Z^4 to first order): (a, b, c) in 1/m, their Cramer-Rao covariance, chi^2 at the
    noise alone, dof. `var_mean_m2`: the variance of each pixel's mean depth, m^2."""
    xc, yc = float(np.mean(x)), float(np.mean(y))  # centred: a well-conditioned solve
    a = np.column_stack([np.ones_like(x), x - xc, y - yc])
    fit = relief_weighted_fit(1.0 / z_m, var_mean_m2 / z_m**4, a)
    shift = np.array([[1.0, -xc, -yc], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])  # back to a + b x + c y
    return shift @ fit.coef, shift @ fit.covariance @ shift.T, fit.chi2_noise, fit.dof


def plane_z_m(coef: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The plane's depth Z = 1 / (a + b x + c y) at normalised image coordinates (x, y), m."""
    return 1.0 / (coef[0] + coef[1] * x + coef[2] * y)


def wall_plane(coef: np.ndarray, cov: np.ndarray, chi2: float, dof: int, planned_distance_m: float,
               planned_tilt_deg: float) -> WallPlane:
    """The plane's distance and tilts with their errors (the delta method on (a, b, c))."""
    a, b, c = (float(v) for v in coef)

    def angle(k: int) -> tuple[float, float]:  # atan(coef[k] / a) in degrees, and its error
        q = coef[k] / a
        grad = np.zeros(3)
        grad[0], grad[k] = -q / a, 1.0 / a
        se = math.sqrt(max(float(grad @ cov @ grad), 0.0)) / (1.0 + q * q)
        return math.degrees(math.atan(q)), math.degrees(se)

    tilt, tilt_se = angle(1)
    tilt_x, tilt_x_se = angle(2)
    planned = math.copysign(abs(planned_tilt_deg), tilt) if math.isfinite(planned_tilt_deg) else math.nan
    return WallPlane(1.0 / a, math.sqrt(max(float(cov[0, 0]), 0.0)) / a**2, tilt, tilt_se, tilt_x, tilt_x_se,
                     chi2, dof, planned_distance_m, planned)


def planned_z_m(wall: WallPlane, x: np.ndarray) -> np.ndarray:
    """The plan's wall along each pixel's ray: Z = D / (1 + tan(t) x), D its distance, t its tilt (with the fitted
    sign), m."""
    return wall.planned_distance_m / (1.0 + math.tan(math.radians(wall.planned_tilt_deg)) * x)
