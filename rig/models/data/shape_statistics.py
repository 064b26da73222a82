"""The distribution's shape, measured model-free: each pixel's kurtosis, standardised by its neighbours'
variance, and the kurtosis of each range window pooled from them.

Per pixel the work is done within a stop (neighbours are pixels of the same stop), so it can go stop by
stop; the range windows' pooled kurtosis is made of sums over all stops (`pooled_from_sums`).

`ShapeStatistics` is the part of `rig.models.data.model_data.ModelData` that measures them: its properties,
computed once and kept (cached), are the data's own (`d.pixel_kurtosis`); it reads the rows' moments
and positions, which `ModelData` holds.
"""

from __future__ import annotations

from functools import cached_property
from typing import Any, Iterator

import numpy as np
from numba import njit

from .group_sums import group_sums

#: side of the square of neighbouring pixels, centred on a pixel, whose pooled variance standardises its fourth moment
KURTOSIS_WINDOW_PX = 7
#: rounding to the depth unit adding more than this share of the variance makes a pixel's kurtosis meaningless
ROUNDING_SHARE = 0.02
#: usable pixels a range window needs for its kurtosis to count
MIN_KURTOSIS_PIXELS = 20
#: a stop whose pixels' ln Z spans more than this (1st to 99th percentile: a tilted wall) has its kurtosis standardised
#: by its neighbours' variances scaled to each pixel's range (`kurtosis_variance`)
RANGE_SPAN_TO_SCALE = 0.05


def pooled_from_sums(count: float, sw: float, swb: float, sw2: float, sw2b: float, sw2b2: float) -> tuple[float, float]:
    """The samples-weighted mean of pixel kurtosis estimates b (weights w = n), and its standard error from their
    scatter, sqrt(k / (k - 1) sum w^2 (b - mean)^2) / sum w, from the sums count k, w, w b, w^2, w^2 b, w^2 b^2."""
    if count < 3:
        return float("nan"), float("nan")
    mean = swb / sw
    scatter = max(sw2b2 - 2 * mean * sw2b + mean * mean * sw2, 0.0)
    return float(mean), float(np.sqrt(scatter / (count - 1) * count) / sw)


class ShapeStatistics:
    """The measured shape of each pixel's samples and of each range window's (see the module docstring); a base
    of `ModelData`, which holds what these read."""

    z_m: np.ndarray
    m2_m2: np.ndarray
    m4_m4: np.ndarray
    n: np.ndarray
    stop: np.ndarray
    u_px: np.ndarray
    v_px: np.ndarray
    depth_unit_m: float
    nu: np.ndarray
    range_group: np.ndarray

    def __len__(self) -> int:
        raise NotImplementedError

    def stop_slices(self) -> list[slice] | None:
        raise NotImplementedError

    def _taken(self, rows: Any, derived: bool) -> Any:
        raise NotImplementedError

    @cached_property
    def neighbour_variance(self) -> tuple[np.ndarray, np.ndarray]:
        """For each pixel, the variance pooled over the other pixels of the KURTOSIS_WINDOW_PX square centred
        on it at the same stop, and its degrees of freedom (NaN where too few, or positions unknown). Centred,
        so a variance changing linearly across the image is the pixel's own on average."""
        if len(self) == 0 or not (np.isfinite(self.u_px).all() and np.isfinite(self.v_px).all()):
            nan = np.full(len(self), np.nan)
            return nan, nan
        shape = (int(self.v_px.max()) + 1, int(self.u_px.max()) + 1)
        var_out, nu_out = np.empty(len(self)), np.empty(len(self))
        slices = self.stop_slices()
        groups = slices if slices is not None else [np.flatnonzero(self.stop == s) for s in np.unique(self.stop)]
        nu = self.nu
        for m in groups:
            # the whole image, row by row (a stop as loaded): the rows are the image, no scattering and gathering
            whole = _whole_image(self.u_px[m], self.v_px[m], shape[0], shape[1])
            if whole:
                m2_img = np.ascontiguousarray(self.m2_m2[m], dtype=np.float64).reshape(shape)
                nu_img = np.ascontiguousarray(nu[m], dtype=np.float64).reshape(shape)
                if isinstance(m, slice):  # written straight into the rows
                    _others_in_window(m2_img, nu_img, KURTOSIS_WINDOW_PX // 2, var_out[m].reshape(shape),
                                      nu_out[m].reshape(shape))
                    continue
            else:
                vm, um = self.v_px[m].astype(np.int64), self.u_px[m].astype(np.int64)
                m2_img, nu_img = np.zeros(shape), np.zeros(shape)
                m2_img[vm, um] = self.m2_m2[m]
                nu_img[vm, um] = nu[m]
            var_img, nu_v_img = np.empty(shape), np.empty(shape)
            _others_in_window(m2_img, nu_img, KURTOSIS_WINDOW_PX // 2, var_img, nu_v_img)
            # the images back to rows
            var_out[m] = var_img.ravel() if whole else var_img[vm, um]
            nu_out[m] = nu_v_img.ravel() if whole else nu_v_img[vm, um]
        return var_out, nu_out

    @cached_property
    def kurtosis_variance(self) -> tuple[np.ndarray, np.ndarray]:
        """The neighbours' variance that standardises each pixel's fourth moment, and its degrees of freedom:
        `neighbour_variance`, except on a stop spanning a range of distances (ln Z over RANGE_SPAN_TO_SCALE: a tilted
        wall). There the variance grows as Z^(2 lambda) across the image (Z^6 for active stereo), and the square's
        neighbours, cut on one side at the image's edge (or curved), would bias v by it: each neighbour's M2 is
        scaled to the pixel's range first, by (Z_i / Z_j)^(2 lambda0), lambda0 = 3 with the projector on (or not
        known) and 2 off (eq. sigma_Z = k Z^lambda). A perpendicular stop's are used as measured."""
        v, nu_v = self.neighbour_variance
        if len(self) == 0 or not (np.isfinite(self.u_px).all() and np.isfinite(self.v_px).all()):
            return v, nu_v
        slices = self.stop_slices()
        groups = slices if slices is not None else [np.flatnonzero(self.stop == s) for s in np.unique(self.stop)]
        projector = getattr(self, "projector_on", None)
        shape = (int(self.v_px.max()) + 1, int(self.u_px.max()) + 1)
        out = None
        for m in groups:
            z = np.asarray(self.z_m[m], dtype=np.float64)
            ok = np.isfinite(z) & (z > 0)
            if ok.sum() < 3 or np.subtract(*np.percentile(np.log(z[ok]), [99, 1])) < RANGE_SPAN_TO_SCALE:
                continue
            if out is None:
                out = (np.array(v, dtype=np.float64), np.array(nu_v, dtype=np.float64))
            on = True if projector is None else bool(np.asarray(projector)[m][0])
            vm, um = self.v_px[m].astype(np.int64), self.u_px[m].astype(np.int64)
            m2_img, nu_img, z_img = np.zeros(shape), np.zeros(shape), np.zeros(shape)
            m2_img[vm, um], nu_img[vm, um], z_img[vm, um] = self.m2_m2[m], self.nu[m], np.where(ok, z, 0.0)
            var_img, nu_v_img = np.empty(shape), np.empty(shape)
            _others_scaled_to_range(m2_img, nu_img, z_img, 6.0 if on else 4.0, KURTOSIS_WINDOW_PX // 2, var_img,
                                    nu_v_img)
            out[0][m], out[1][m] = var_img[vm, um], nu_v_img[vm, um]
        return out if out is not None else (v, nu_v)

    @cached_property
    def pixel_kurtosis(self) -> np.ndarray:
        """Each pixel's unbiased estimate of its samples' kurtosis (3 for a normal distribution).

        M4 is standardised by the variance v its neighbours measure (`kurtosis_variance`), not by
        a model's variance, which is what is in doubt. For samples about their own mean,
        E[M4] / sigma^4 = (n - 1) / n^2 ((n^2 - 3n + 3) beta + 3 (2n - 3)); v's own noise is removed
        by E[1 / v^2] = nu^2 / ((nu - 2)(nu - 4)) / sigma^4 (v ~ sigma^2 chi2_nu / nu). NaN where it
        cannot be formed."""
        v, nu_v = self.kurtosis_variance
        out = np.empty(len(self))
        _pixel_kurtosis(*(np.ascontiguousarray(a, dtype=np.float64) for a in (self.m4_m4, v, nu_v, self.n)), out)
        return out

    @cached_property
    def kurtosis_usable(self) -> np.ndarray:
        """Pixels whose kurtosis estimate means something: formed, and not dominated by rounding to the
        depth unit (q^2 / 12 below ROUNDING_SHARE of the neighbours' variance), where the samples are
        a few discrete levels whose spread depends on each pixel's own position between them."""
        v, _ = self.kurtosis_variance
        q2 = self.depth_unit_m**2 if np.isfinite(self.depth_unit_m) else 0.0
        with np.errstate(invalid="ignore"):
            return np.isfinite(self.pixel_kurtosis) & (q2 / 12 < ROUNDING_SHARE * v)

    @cached_property
    def kurtosis_by_range(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(range windows, measured kurtosis, its standard error) for windows with MIN_KURTOSIS_PIXELS usable pixels.
        Stop by stop: a stop's per-pixel estimates are made and dropped, only the windows' sums are kept."""
        totals: dict[int, np.ndarray] = {}
        for c in self._stop_views():
            use = c.kurtosis_usable
            w, b = c.n[use], c.pixel_kurtosis[use]
            keys, sums = group_sums(c.range_group[use], [1.0, w, w * b, w * w, w * w * b, w * w * b * b])
            for key, row in zip(keys.tolist(), sums):
                totals[key] = totals[key] + row if key in totals else row
        windows, measured, se = [], [], []
        for g in sorted(totals):
            if totals[g][0] < MIN_KURTOSIS_PIXELS:
                continue
            k, e = pooled_from_sums(*totals[g])
            if np.isfinite(k) and e > 0:
                windows.append(g)
                measured.append(k)
                se.append(e)
        return np.array(windows, dtype=np.int64), np.array(measured), np.array(se)

    @cached_property
    def excess_measured(self) -> np.ndarray:
        """Each pixel's excess kurtosis as its range window measures it (0 where not measured), for the
        Gamma law's shape: the scatter of s2 across pixels comes from the data, not from a model."""
        windows, measured, _ = self.kurtosis_by_range
        excess = np.zeros(len(self))
        if len(windows):
            lo = int(min(windows.min(), self.range_group.min())) if len(self) else 0
            table = np.zeros(int(max(windows.max(), self.range_group.max() if len(self) else 0)) - lo + 1)
            table[windows - lo] = measured - 3.0
            excess = table[self.range_group - lo]
        return np.maximum(excess, -1.5)

    def _stop_views(self) -> Iterator[Any]:
        """The stops as views that compute their own per-pixel statistics (the parent's, where it has them)."""
        if all(name in self.__dict__ for name in ("pixel_kurtosis", "kurtosis_usable", "range_group")):
            yield self
            return
        slices = self.stop_slices()
        if slices is None or len(slices) <= 1:
            yield self
            return
        for sl in slices:
            yield self._taken(sl, derived=True)


@njit(cache=True, nogil=True)
def _others_in_window(m2, nu, half, var_out, nu_out):  # pragma: no cover - compiled
    """For each pixel of the images `m2` (M2, m^2) and `nu` (degrees of freedom; 0 where no pixel), the pooled
    variance sum M2 / sum nu over the other pixels of the (2 half + 1)^2 square centred on it (none beyond the
    image), and that sum nu; NaN both where it is 4 or less. Row by row: the square's columns are summed down,
    then along the row (each an exact sum of its 2 half + 1 terms, not a running one)."""
    h, w = m2.shape
    col_m2, col_nu, sq_m2, sq_nu = np.empty(w), np.empty(w), np.empty(w), np.empty(w)
    for y in range(h):
        col_m2[:] = 0.0
        col_nu[:] = 0.0
        for k in range(max(0, y - half), min(h, y + half + 1)):
            for x in range(w):
                col_m2[x] += m2[k, x]
                col_nu[x] += nu[k, x]
        sq_m2[:] = 0.0
        sq_nu[:] = 0.0
        for off in range(-half, half + 1):  # as slices, indexed from 0: no index can be negative, so it vectorises
            lo, hi = max(0, -off), min(w, w - off)
            to_m2, to_nu, from_m2, from_nu = sq_m2[lo:hi], sq_nu[lo:hi], col_m2[lo + off:hi + off], col_nu[lo + off:hi + off]
            for i in range(hi - lo):
                to_m2[i] += from_m2[i]
                to_nu[i] += from_nu[i]
        for x in range(w):
            s_m2, s_nu = sq_m2[x], sq_nu[x]
            n_other = np.rint(s_nu - nu[y, x])
            if n_other > 4:
                var_out[y, x] = (s_m2 - m2[y, x]) / n_other
                nu_out[y, x] = n_other
            else:
                var_out[y, x] = np.nan
                nu_out[y, x] = np.nan


@njit(cache=True, nogil=True)
def _others_scaled_to_range(m2, nu, z, power, half, var_out, nu_out):  # pragma: no cover - compiled
    """As `_others_in_window`, each other pixel's M2 first scaled to the pixel's range Z: by (Z / Z_j)^power
    (`ShapeStatistics.kurtosis_variance`); pixels with no range (z <= 0) or no samples are left out."""
    h, w = m2.shape
    for y in range(h):
        for x in range(w):
            zi = z[y, x]
            s_m2, s_nu = 0.0, 0.0
            if zi > 0:
                for k in range(max(0, y - half), min(h, y + half + 1)):
                    for j in range(max(0, x - half), min(w, x + half + 1)):
                        if (k == y and j == x) or nu[k, j] <= 0 or z[k, j] <= 0:
                            continue
                        s_m2 += m2[k, j] * (zi / z[k, j]) ** power
                        s_nu += nu[k, j]
            n_other = np.rint(s_nu)
            if n_other > 4:
                var_out[y, x] = s_m2 / n_other
                nu_out[y, x] = n_other
            else:
                var_out[y, x] = np.nan
                nu_out[y, x] = np.nan


@njit(cache=True, nogil=True)
def _whole_image(u, v, h, w):  # pragma: no cover - compiled
    """Whether the rows at positions `u`, `v` (px) are every pixel of an h x w image, row by row."""
    if u.size != h * w:
        return False
    i = 0
    for y in range(h):
        for x in range(w):
            if u[i] != x or v[i] != y:
                return False
            i += 1
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def _pixel_kurtosis(m4, v, nu_v, n, out):  # pragma: no cover - compiled
    """`ShapeStatistics.pixel_kurtosis` row by row, each term in numpy's order (within a few ulps, tests/test_neighbour_variance.py):
    M4 / v^2 (nu - 2) (nu - 4) / nu^2, then (that n^2 / (n - 1) - 3 (2 n - 3)) / (n^2 - 3 n + 3); NaN or inf where
    numpy's arrays would give them."""
    for i in range(out.size):
        m4_over_sigma4 = m4[i] / (v[i] * v[i]) * (nu_v[i] - 2.0) * (nu_v[i] - 4.0) / (nu_v[i] * nu_v[i])
        ni = n[i]
        out[i] = (m4_over_sigma4 * (ni * ni) / (ni - 1.0) - 3.0 * (2.0 * ni - 3.0)) / (ni * ni - 3.0 * ni + 3.0)
