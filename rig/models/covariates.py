"""Per-pixel covariates derived from a stop's recorded images and series.

These are what the model effects need besides range: incidence angle on the wall, the
ambient-to-pattern brightness ratio, and the drift of the mean depth during the stop.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from drivers.image_regions import center_box
from protocols.recording import CameraCalibration, StopData


def smoothed(image: np.ndarray, window_px: int) -> np.ndarray:
    """Brightness as the matcher sees it, without the projected dots: a Gaussian of sigma = window_px.

    Averaging over several matching windows removes the dot pattern (whose period is about a
    window); illumination changes slowly across the image, so it survives. Borders reflect.
    """
    return gaussian_filter(image.astype(np.float64), sigma=window_px, mode="reflect")


def ambient_ratio(ir_mean: np.ndarray | None, ambient_ir_mean: np.ndarray | None, window_px: int) -> np.ndarray | None:
    """Ambient / pattern light per pixel: A / (I_on - A) from the projector-on and -off IR means."""
    if ir_mean is None or ambient_ir_mean is None:
        return None
    a = smoothed(ambient_ir_mean, window_px)
    p = smoothed(ir_mean, window_px) - a
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(p > 0, np.clip(a, 0, None) / p, np.nan)


def incidence_cosine(mean_m: np.ndarray, valid: np.ndarray, cal: CameraCalibration) -> np.ndarray:
    """cos of the angle between each pixel's ray and the normal of a plane fitted to the mean depth.

    Points X = z (xn, yn, 1); plane n . X = 1/c fitted by least squares on the valid pixels
    (a Z = a x + b y + c form: Z = c / (1 - a xn - b yn) is linear in 1/Z: 1/Z = (1 - a xn - b yn) / c).
    """
    h, w = mean_m.shape
    v, u = np.mgrid[0:h, 0:w]
    xn, yn = (u - cal.cx) / cal.fx, (v - cal.cy) / cal.fy
    if valid.sum() < 3:
        return np.ones_like(mean_m)
    A = np.column_stack([xn[valid], yn[valid], np.ones(valid.sum())])
    coef, *_ = np.linalg.lstsq(A, 1.0 / mean_m[valid], rcond=None)  # 1/Z = p xn + q yn + r
    normal = np.array([coef[0], coef[1], coef[2]])  # plane: p X + q Y + r Z = 1
    normal /= np.linalg.norm(normal)
    ray_norm = np.sqrt(xn**2 + yn**2 + 1.0)
    return np.abs(normal[0] * xn + normal[1] * yn + normal[2]) / ray_norm


def drift_inverse_variance(stop: StopData) -> float | None:
    """Variance over frames of a common disparity-like offset, in (1/m)^2, beyond pixel noise; None if not recorded.

    The per-frame series holds o_t = mean over valid pixels of 1/z - 1/z_ref. Pixel noise
    contributes mean_p(s2_p / Z_p^4) / N to var_t(o) (since d(1/z) = -dz / z^2), and per-pixel
    variances include the drift, so D = (var_t(o) - mean(s2 / Z^4) / N) / (1 - 1/N).
    A pixel at range Z then sees a drift variance D Z^4 (m^2).
    """
    series = stop.series
    if series is None:
        return None
    o = series.inverse_range_offset_per_m
    if len(o) < 3 or not np.isfinite(o).all():
        return None
    var_p = stop.stats.variance_m2
    ok = np.isfinite(var_p) & np.isfinite(stop.stats.mean_m)
    n = float(np.mean(series.valid_fraction)) * var_p.size if np.isfinite(series.valid_fraction).all() else ok.sum()
    if ok.sum() < 2 or n < 2:
        return None
    noise = float(np.mean(var_p[ok] / stop.stats.mean_m[ok] ** 4)) / n
    return max((float(np.var(o, ddof=1)) - noise) / (1.0 - 1.0 / n), 0.0)


def drift_variance_m2(stop: StopData) -> tuple[float, float]:
    """Variance over frames of the stop's mean depth beyond what pixel noise explains, and its range.

    The central region's per-frame mean c_t has variance D + s2 / N over frames (D: drift, s2:
    per-pixel noise variance, N: pixels averaged). Per-pixel variances include the drift, s2 + D,
    so D = (var_t(c) - mean(s2 + D) / N) / (1 - 1 / N). Returns (D in m^2, central range in m).
    """
    series = stop.series
    if series is None or len(series.center_mean_m) < 3 or not np.isfinite(series.center_mean_m).all():
        return 0.0, float("nan")
    cy, cx = center_box(stop.stats.count.shape)
    var_c = stop.stats.variance_m2[cy, cx]
    ok = np.isfinite(var_c)
    n = ok.sum()
    if n < 2:
        return 0.0, float("nan")
    v_series = float(np.var(series.center_mean_m, ddof=1))
    d = (v_series - float(var_c[ok].mean()) / n) / (1.0 - 1.0 / n)
    return max(d, 0.0), float(np.nanmean(series.center_mean_m))
