"""Brightness as the matcher sees it: an image smoothed with a Gaussian, compiled (`smoothed`)."""

from __future__ import annotations

import numpy as np
from numba import njit


def smoothed(image: np.ndarray, window_px: float) -> np.ndarray:
    """Brightness as the matcher sees it, without the projected dots: a Gaussian of sigma = window_px.

    Averaging over several matching windows removes the dot pattern (whose period is about a
    window); illumination changes slowly across the image, so it survives. Borders reflect.

    scipy.ndimage.gaussian_filter(image, window_px, mode="reflect") within 2 (r + 2) eps of the value, r the
    radius (tests/test_covariates.py; equal here, but scipy's C code may fuse multiply-adds on other processors): its
    weights (truncated at 4 sigma), made as scipy makes them, applied down the columns and then along the rows in
    its order of terms (`_gaussian_columns`, `_gaussian_rows`: compiled, neighbouring pixels summed side by side);
    scipy's filter took twice as long (17.8 against 8.6 ms a 848x480 image), and its import 0.07 s more.
    """
    radius = int(4.0 * window_px + 0.5)
    x = np.arange(-radius, radius + 1)
    phi = np.exp(-0.5 / (window_px * window_px) * x**2)
    weights = phi / phi.sum()
    image = np.ascontiguousarray(image, dtype=np.float64)
    if image.ndim != 2 or image.size == 0:
        raise ValueError(f"smoothed: a 2-D image is needed, not shape {image.shape}")
    down, out = np.empty_like(image), np.empty_like(image)
    _gaussian_columns(image, weights, down)
    _gaussian_rows(down, weights, out)
    return out


@njit(cache=True, nogil=True)
def _reflected(i, n):  # pragma: no cover - compiled
    """Index `i` of a line of `n` values extended by reflection (d c b a | a b c d | d c b a), as scipy's mode="reflect"."""
    i = i % (2 * n)
    return i if i < n else 2 * n - 1 - i


@njit(cache=True, nogil=True)
def _gaussian_columns(image, weights, out):  # pragma: no cover - compiled
    """`out[y, x]` = the symmetric `weights` (2 r + 1 of them) down column x of `image` about row y, borders reflected,
    summed as scipy's correlate1d sums a symmetric kernel: the centre's term, then each pair from the outermost in.
    A row of sums at a time, so the terms of neighbouring columns are added side by side."""
    h, w = image.shape
    r = weights.size // 2
    for y in range(h):
        acc, row = out[y], image[y]
        for x in range(w):
            acc[x] = row[x] * weights[r]
        for j in range(r, 0, -1):
            before, after, wj = image[_reflected(y - j, h)], image[_reflected(y + j, h)], weights[r - j]
            for x in range(w):
                acc[x] += (before[x] + after[x]) * wj


@njit(cache=True, nogil=True)
def _gaussian_rows(image, weights, out):  # pragma: no cover - compiled
    """`_gaussian_columns` along each row instead: the row extended by reflection, then each pair of terms added to
    every pixel of the row at once (slices indexed from 0, which vectorise)."""
    h, w = image.shape
    r = weights.size // 2
    line = np.empty(w + 2 * r)
    for y in range(h):
        row, acc = image[y], out[y]
        for k in range(w + 2 * r):
            line[k] = row[_reflected(k - r, w)]
        for x in range(w):
            acc[x] = row[x] * weights[r]
        for j in range(r, 0, -1):
            before, after, wj = line[r - j:r - j + w], line[r + j:r + j + w], weights[r - j]
            for x in range(w):
                acc[x] += (before[x] + after[x]) * wj
