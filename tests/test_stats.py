"""The streaming per-pixel statistics against numpy on the same raw frames."""

import numpy as np

from protocols.stats import PixelMomentAccumulator


def numpy_moments(frames: np.ndarray, scale: float):
    z = np.where(frames > 0, frames.astype(np.float64) * scale, np.nan)
    count = np.sum(frames > 0, axis=0)
    mean = np.nanmean(z, axis=0)
    d = z - mean
    return count, mean, *(np.nansum(d**k, axis=0) for k in (2, 3, 4))


def test_streaming_moments_match_numpy_with_gaps_and_outliers():
    rng = np.random.default_rng(3)
    n, h, w = 120, 9, 13
    true = rng.uniform(400, 30000, (h, w))
    frames = np.rint(rng.normal(true, rng.uniform(0.5, 40, (h, w)), (n, h, w))).astype(np.uint16)
    frames[rng.random((n, h, w)) < 0.2] = 0  # missing data
    frames[0, 0, 0] = 0  # first frame missing: the shift comes from a later one
    far = rng.random((n, h, w)) < 0.01
    frames[far] = rng.integers(1, 65535, far.sum())  # wild outliers across the whole range
    scale = 0.001
    acc = PixelMomentAccumulator((h, w), scale)
    for f in frames:
        acc.add(f)
    got = acc.result()
    count, mean, m2, m3, m4 = numpy_moments(frames, scale)
    np.testing.assert_array_equal(got.count, count)
    np.testing.assert_allclose(got.mean_m, mean, rtol=1e-13)
    np.testing.assert_allclose(got.m2_m2, m2, rtol=1e-11)
    np.testing.assert_allclose(got.m3_m3, m3, rtol=1e-8, atol=1e-12 * np.abs(m3).max())
    np.testing.assert_allclose(got.m4_m4, m4, rtol=1e-8)


def test_pixel_without_samples_is_nan_and_count_zero():
    acc = PixelMomentAccumulator((2, 2), 0.001)
    f = np.array([[0, 1000], [1000, 1000]], np.uint16)
    acc.add(f)
    acc.add(f + np.array([[0, 2], [0, 0]], np.uint16))
    r = acc.result()
    assert r.count[0, 0] == 0 and np.isnan(r.mean_m[0, 0])
    assert r.count[0, 1] == 2
    assert np.isclose(r.mean_m[0, 1], 1.001)
    assert np.isclose(r.m2_m2[0, 1], 2 * 0.001**2)
    assert np.isclose(r.variance_m2[0, 1], 2e-6)
