"""Per-pixel covariates derived from a stop's recorded images and series.

These are what the model effects need besides range: incidence angle on the wall, the
ambient-to-pattern brightness ratio, and the drift of the mean depth during the stop.

A `StopSource` keeps, per stop, the little that covariates are computed from (the smoothed IR
and ambient-ratio images, the wall plane's normal, the drift, the projector state), so a
covariate of any set of pixel rows is a gather or a formula, computed when it is first needed.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np
from numba import njit

from drivers.image_regions import center_box
from protocols.recording import CameraCalibration, StopData

from .smoothing import smoothed


@dataclass(eq=False)
class StopSource:
    """What one stop's covariates are computed from (see the module docstring).

    ir_dn: the IR image smoothed over the matching window (DN, float32; None without IR); ambient:
    ambient / pattern light per pixel (float32; None without projector-off frames); normal: the
    unit normal (nx, ny, nz) of the plane fitted to the stop's mean depth, in camera axes;
    drift_inverse: the common wander's variance in (1/m)^2 (None: not recorded, see drift_m2);
    drift_m2, drift_center_m: the central region's wander (m^2) and range (m), for old recordings;
    n_frames; projector_on.
    """

    ir_dn: np.ndarray | None
    ambient: np.ndarray | None
    normal: np.ndarray
    drift_inverse: float | None
    drift_m2: float
    drift_center_m: float
    n_frames: int
    projector_on: bool
    #: where the IR clipped (None: none, or not checked), and there the smoothed ambient light (DN) and mean depth (m):
    #: for the pattern's light at those pixels from another stop (`fill_clipped_ambient`)
    clipped: np.ndarray | None = None
    ambient_dn: np.ndarray | None = None
    mean_m: np.ndarray | None = None
    #: the smoothed pattern light I - A (DN), NaN where clipped (None without projector-off frames)
    pattern_dn: np.ndarray | None = None
    #: the pattern light at each pixel, unsmoothed (DN, float32; NaN where unknown; None with the projector off or
    #: without IR): `rig.models.data.pattern_light`, which smooths it over a window chosen from the data
    light_raw: np.ndarray | None = None
    #: light_raw smoothed, by window (px): computed when first asked for (`pattern_light.light_image`)
    light_smoothed: dict = field(default_factory=dict, repr=False)
    #: pixels whose IR clipped, and of them those whose light came from another stop (`fill_clipped_light`)
    light_clipped: int = 0
    light_filled: int = 0

    @classmethod
    def of(cls, stop: StopData, keep: np.ndarray, cal: CameraCalibration, window_px: int) -> "StopSource":
        ir = smoothed(stop.ir_mean, window_px).astype(np.float32) if stop.ir_mean is not None else None
        amb = ambient_ratio(stop.ir_mean, stop.ambient_ir_mean, window_px)
        a = smoothed(stop.ambient_ir_mean, window_px) if amb is not None else None
        pattern = smoothed(stop.ir_mean, window_px) - a if a is not None else None
        clipped = clipped_nearby(stop.ir_saturated, window_px)
        if clipped is not None and clipped.any():  # saturated brightness is not a brightness: no covariate value there
            ir = np.where(clipped, np.float32(np.nan), ir) if ir is not None else None
            amb = np.where(clipped, np.nan, amb) if amb is not None else None
            pattern = np.where(clipped, np.nan, pattern) if pattern is not None else None
        else:
            clipped = None
        d_var, z_c = drift_variance_m2(stop)
        return cls(ir, amb.astype(np.float32) if amb is not None else None, plane_normal(stop.stats.mean_m, keep, cal),
                   drift_inverse_variance(stop), d_var, z_c, max(stop.n_frames, 1), stop.projector_on, clipped,
                   a.astype(np.float32) if a is not None and clipped is not None else None,
                   stop.stats.mean_m.astype(np.float32), pattern.astype(np.float32) if pattern is not None else None,
                   raw_pattern_light(stop))


    def drift_var_m2(self, z_m: np.ndarray) -> np.ndarray:
        """The drift variance at range z_m (m^2): D Z^4 from the whole-frame series (d(1/z) = -dz / z^2), or,
        for recordings without it, the central region's wander scaled to the pixel's range."""
        z2 = z_m * z_m  # Z^4 as (Z^2)^2: numpy's pow costs 30 products a value
        if self.drift_inverse is not None:
            return self.drift_inverse * (z2 * z2)
        if np.isfinite(self.drift_center_m):
            r2 = z2 / self.drift_center_m**2
            return self.drift_m2 * (r2 * r2)
        return np.zeros_like(z_m)


def fill_clipped_ambient(sources: list[StopSource]) -> None:
    """Ambient / pattern light where a stop's IR clipped: the pattern light P there is unknown (the clipped mean is a
    lower bound), so it is taken from the same pixel at the nearest stop (in range) where it did not clip, scaled by
    the inverse square of the pixel's mean depth, P = P' (Z' / Z)^2 (the projected light on the wall falls as 1/Z^2
    along the ray; a matte wall's image brightness does not change with distance); the ambient light A is measured
    (projector-off frames do not clip). Sets each such stop's `ambient` there, in place."""
    for s in sources:
        if s.clipped is None or s.ambient is None or s.ambient_dn is None or s.mean_m is None:
            continue
        todo = s.clipped & (s.mean_m > 0)
        p_est = np.full(s.clipped.shape, np.nan)
        others = [o for o in sources if o is not s and o.pattern_dn is not None and o.mean_m is not None]
        with np.errstate(divide="ignore", invalid="ignore"):
            # nearest in range first: the inverse square is exact on the wall, the nearest stop the least extrapolated
            for o in sorted(others, key=lambda o: abs(np.log(np.nanmedian(o.mean_m[o.mean_m > 0]) /
                                                            np.nanmedian(s.mean_m[s.mean_m > 0])))):
                ok = todo & np.isnan(p_est) & np.isfinite(o.pattern_dn) & (o.pattern_dn > 0) & (o.mean_m > 0)
                p_est[ok] = o.pattern_dn[ok] * (o.mean_m[ok] / s.mean_m[ok]) ** 2
            filled = todo & np.isfinite(p_est)
            s.ambient = np.where(filled, np.clip(s.ambient_dn, 0, None) / p_est, s.ambient).astype(np.float32)
    for s in sources:  # needed only here: not kept with the data (nor sent to the workers of a parallel fit)
        s.clipped = s.ambient_dn = s.mean_m = s.pattern_dn = None


def raw_pattern_light(stop: StopData) -> np.ndarray | None:
    """The projected pattern's light at each pixel, unsmoothed: the IR mean less the projector-off mean where the stop
    has one (DN, float32); NaN where any IR sample clipped (the mean is only a lower bound there: filled later from
    another stop, `pattern_light.fill_clipped_light`). None with the projector off or without an IR image."""
    if stop.ir_mean is None or not stop.projector_on:
        return None
    p = stop.ir_mean.astype(np.float64)
    if stop.ambient_ir_mean is not None:
        p = p - stop.ambient_ir_mean
    if stop.ir_saturated is not None:
        p = np.where(stop.ir_saturated > 0, np.nan, p)
    return p.astype(np.float32)


def plane_normal(mean_m: np.ndarray, valid: np.ndarray, cal: CameraCalibration) -> np.ndarray:
    """Unit normal of the plane fitted to the stop's mean depth (see `incidence_cosine`); (0, 0, 1) with fewer
    than three valid pixels. The least-squares fit of 1/Z = p xn + q yn + r, by its normal equations."""
    ata, atb, count = _plane_sums(np.ascontiguousarray(mean_m, dtype=np.float64), np.ascontiguousarray(valid),
                                  cal.cx, cal.cy, cal.fx, cal.fy)
    if count < 3:
        return np.array([0.0, 0.0, 1.0])
    try:
        coef = np.linalg.solve(ata, atb)
    except np.linalg.LinAlgError:
        coef = np.linalg.lstsq(ata, atb, rcond=None)[0]
    return coef / np.linalg.norm(coef)  # plane: p X + q Y + r Z = 1


@njit(cache=True, nogil=True)
def _plane_sums(mean_m, valid, cx, cy, fx, fy):  # pragma: no cover - compiled
    """A^T A and A^T b of the fit 1/Z = p xn + q yn + r over the valid pixels, in one pass over the image: with a
    row (xn, yn, 1), the sums of xn^2, xn yn, xn, yn^2, yn, 1, xn / Z, yn / Z and 1 / Z, kept in scalars."""
    sxx = sxy = sx = syy = sy = s1 = bx = by = b1 = 0.0
    count = 0
    h, w = mean_m.shape
    for v in range(h):
        yn = (v - cy) / fy
        for u in range(w):
            if not valid[v, u]:
                continue
            xn = (u - cx) / fx
            inv = 1.0 / mean_m[v, u]
            sxx += xn * xn
            sxy += xn * yn
            sx += xn
            syy += yn * yn
            sy += yn
            s1 += 1.0
            bx += xn * inv
            by += yn * inv
            b1 += inv
            count += 1
    ata = np.array([[sxx, sxy, sx], [sxy, syy, sy], [sx, sy, s1]])
    return ata, np.array([bx, by, b1]), count


def incidence_from_normal(normal: np.ndarray, xn: np.ndarray, yn: np.ndarray) -> np.ndarray:
    """cos of the angle between the ray (xn, yn, 1) and the plane's normal (`_cos_to_plane`), for arrays of any shape."""
    xn, yn = np.broadcast_arrays(np.asarray(xn, dtype=np.float64), np.asarray(yn, dtype=np.float64))
    out = np.empty(xn.shape)
    _incidence_rows(np.asarray(normal, dtype=np.float64), np.ascontiguousarray(xn).ravel(),
                    np.ascontiguousarray(yn).ravel(), out.reshape(-1))
    return out


@njit(cache=True, nogil=True, inline="always")
def _normalised(u, v, cx, cy, fx, fy):  # pragma: no cover - compiled
    """A pixel's ray direction (xn, yn, 1) from its position (u, v) in px: xn = (u - cx) / fx, yn = (v - cy) / fy."""
    return (np.float64(u) - cx) / fx, (np.float64(v) - cy) / fy


@njit(cache=True, nogil=True, inline="always")
def _cos_to_plane(normal, xn, yn):  # pragma: no cover - compiled
    """cos of the angle between the ray (xn, yn, 1) and the plane's unit normal: |n . r| / |r|."""
    return abs(normal[0] * xn + normal[1] * yn + normal[2]) / np.sqrt(xn * xn + yn * yn + 1.0)


@njit(cache=True, nogil=True)
def _incidence_rows(normal, xn, yn, out):  # pragma: no cover - compiled
    """`_cos_to_plane` of each ray (xn[i], yn[i], 1) into `out`."""
    for i in range(out.size):
        out[i] = _cos_to_plane(normal, xn[i], yn[i])


#: what `_position_rows` makes of each row's position
X_NORM, Y_NORM, RHO2, COS_INC = 0, 1, 2, 3


@njit(cache=True, nogil=True)
def _position_rows(u, v, cx, cy, fx, fy, normal, what, out):  # pragma: no cover - compiled
    """For rows at (u, v) px, one covariate of the position (`what`): xn, yn, rho^2 = xn^2 + yn^2, or the incidence
    cosine on the plane of unit `normal` (`_cos_to_plane`)."""
    for i in range(out.size):
        xn, yn = _normalised(u[i], v[i], cx, cy, fx, fy)
        if what == X_NORM:
            out[i] = xn
        elif what == Y_NORM:
            out[i] = yn
        elif what == RHO2:
            out[i] = xn * xn + yn * yn
        else:
            out[i] = _cos_to_plane(normal, xn, yn)


@njit(cache=True, nogil=True)
def _nearest_pixel_rows(image, u, v, out):  # pragma: no cover - compiled
    """`image` at each row's nearest pixel (positions rounded half to even, clipped to the image; NaN: none)."""
    h, w = image.shape
    for i in range(out.size):
        if not (np.isfinite(u[i]) and np.isfinite(v[i])):
            out[i] = np.nan
            continue
        row = np.int64(min(max(np.rint(v[i]), 0), h - 1))
        col = np.int64(min(max(np.rint(u[i]), 0), w - 1))
        out[i] = image[row, col]


#: the share of a pixel's smoothed brightness that may come from saturated pixels before it is no brightness: a
#: clipped pixel's light is unknown above full scale, so the smoothed value is low by up to this share times what
#: the clipped pixels lack (kept: low by under 1 % of a full scale while they lack less than one). A lone
#: clipped pixel weighs 1 / (2 pi window_px^2) = 0.3 % at its own place (window 7 px): away from the border, none left out
CLIPPED_SHARE = 0.01


def clipped_nearby(ir_saturated: np.ndarray | None, window_px: int) -> np.ndarray | None:
    """Pixels whose smoothed brightness (`smoothed`) draws more than CLIPPED_SHARE of its weight from saturated
    pixels: those with any IR sample at full scale (their mean is only a lower bound). None: not checked."""
    if ir_saturated is None:
        return None
    sat = ir_saturated > 0
    if not sat.any():
        return sat
    return smoothed(sat, window_px) > CLIPPED_SHARE


def brightness_left_out(d) -> int:
    """Rows (pixel-stops) of `d` whose stop has an IR image but whose brightness was left out (NaN) because
    saturated pixels make it only a lower bound (`clipped_nearby`)."""
    ir = d.ir if d.sources is not None else None
    if ir is None:
        return 0
    has_ir = np.array([src.ir_dn is not None for src in d.sources], bool)
    return int(np.count_nonzero(np.isnan(ir) & has_ir[d.stop])) if has_ir.any() else 0


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
    if valid.sum() < 3:
        return np.ones_like(mean_m)
    v, u = np.mgrid[0:h, 0:w]
    return incidence_from_normal(plane_normal(mean_m, valid, cal), (u - cal.cx) / cal.fx, (v - cal.cy) / cal.fy)


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
    st = stop.stats
    pixels, noise_sum = _noise_of_inverse_range(*(np.ascontiguousarray(a).ravel() for a in (st.count, st.m2_m2, st.mean_m)))
    n = float(np.mean(series.valid_fraction)) * st.count.size if np.isfinite(series.valid_fraction).all() else pixels
    if pixels < 2 or n < 2:
        return None
    noise = noise_sum / pixels / n
    return max((float(np.var(o, ddof=1)) - noise) / (1.0 - 1.0 / n), 0.0)


@njit(cache=True, nogil=True)
def _noise_of_inverse_range(count, m2, mean_m):  # pragma: no cover - compiled
    """Over the pixels with a finite variance s2 = M2 / (n - 1) (n > 1) and mean range Z: how many, and the sum of
    s2 / Z^4, the variance of each one's 1/z (d(1/z) = -dz / z^2); one pass, no temporary images."""
    pixels, total = 0, 0.0
    for i in range(count.size):
        n = np.float64(count[i])
        if not n > 1:
            continue
        s2, z = m2[i] / (n - 1.0), mean_m[i]
        if np.isfinite(s2) and np.isfinite(z):
            z2 = z * z
            total += s2 / (z2 * z2)
            pixels += 1
    return pixels, total


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
    var_c = stop.stats.variance_m2_in((cy, cx))
    ok = np.isfinite(var_c)
    n = ok.sum()
    if n < 2:
        return 0.0, float("nan")
    v_series = float(np.var(series.center_mean_m, ddof=1))
    d = (v_series - float(var_c[ok].mean()) / n) / (1.0 - 1.0 / n)
    return max(d, 0.0), float(np.nanmean(series.center_mean_m))


def covariate_rows(name: str, d) -> np.ndarray:
    """One covariate (a `ModelData.LAZY` name) for the rows of `d`, from its stop sources and calibration."""
    cal, sources = d.calibration, d.sources
    if name in ("x_norm", "y_norm", "rho2", "cos_inc"):  # compiled passes over the positions, stop by stop for the plane
        what = {"x_norm": X_NORM, "y_norm": Y_NORM, "rho2": RHO2, "cos_inc": COS_INC}[name]
        out = np.empty(len(d))
        for s, rows in rows_by_stop(d) if what == COS_INC else [(0, slice(None))]:
            normal = np.asarray(sources[s].normal, dtype=np.float64) if what == COS_INC else np.zeros(3)
            with _into(out, rows) as part:
                _position_rows(np.ascontiguousarray(d.u_px[rows]), np.ascontiguousarray(d.v_px[rows]),
                               float(cal.cx), float(cal.cy), float(cal.fx), float(cal.fy), normal, what, part)
        return out
    if name in ("ir", "ambient_ratio"):
        out = np.full(len(d), np.nan)
        for s, rows in rows_by_stop(d):
            image = sources[s].ir_dn if name == "ir" else sources[s].ambient
            if image is not None:  # the nearest pixel (grouped data's nodes sit between pixels)
                with _into(out, rows) as part:
                    _nearest_pixel_rows(image, np.ascontiguousarray(d.u_px[rows]), np.ascontiguousarray(d.v_px[rows]), part)
        return out
    per_stop = {"fill": lambda src, rows: d.n[rows] / src.n_frames,
                "drift_var_m2": lambda src, rows: src.drift_var_m2(d.z_m[rows]),
                "projector_on": lambda src, rows: np.full(_size(rows, len(d)), src.projector_on)}
    if name not in per_stop:
        raise KeyError(f"no covariate named {name!r}")
    parts = [(rows, per_stop[name](sources[s], rows)) for s, rows in rows_by_stop(d)]
    out = np.empty(len(d), dtype=bool if name == "projector_on" else np.float64)
    for rows, values in parts:
        out[rows] = values
    return out


@contextmanager
def _into(out: np.ndarray, rows) -> Iterator[np.ndarray]:
    """Where a compiled pass writes `out[rows]`: the rows themselves for a slice, else a buffer copied in after."""
    if isinstance(rows, slice):
        yield out[rows]
        return
    part = np.empty(len(rows), out.dtype)
    yield part
    out[rows] = part


def _size(rows, total: int) -> int:
    return len(range(*rows.indices(total))) if isinstance(rows, slice) else len(rows)


def rows_by_stop(d):
    """(stop index, its rows) for every stop in `d`: slices when the rows come stop by stop."""
    slices = d.stop_slices()
    if slices is not None:
        return [(int(d.stop[sl.start]), sl) for sl in slices]
    return [(int(s), np.flatnonzero(d.stop == s)) for s in np.unique(d.stop)]
