"""The streaming per-pixel statistics against numpy on the same raw frames."""

import numpy as np
import pytest

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


def test_streaming_moments_are_exact_to_1e13_against_rational_arithmetic():
    """Every stored moment against the same moments computed exactly (Python fractions, no floating point):
    mean and M2 to 1e-13 of their value, M3 and M4 to 1e-13 of sum |z - mean|^k, outliers across the whole
    uint16 range included (where the float64 sums S3, S4 round)."""
    from fractions import Fraction

    rng = np.random.default_rng(11)
    n, h, w = 150, 5, 6
    true = rng.uniform(400, 30000, (h, w))
    frames = np.rint(rng.normal(true, rng.uniform(0.5, 40, (h, w)), (n, h, w))).astype(np.uint16)
    frames[rng.random((n, h, w)) < 0.2] = 0
    far = rng.random((n, h, w)) < 0.02
    frames[far] = rng.integers(1, 65535, far.sum())
    acc = PixelMomentAccumulator((h, w), 1.0)
    for f in frames:
        acc.add(f)
    got = acc.result()
    for i in range(h):
        for j in range(w):
            xs = [int(v) for v in frames[:, i, j] if v]
            assert got.count[i, j] == len(xs)
            mean = Fraction(sum(xs), len(xs))
            assert abs(Fraction(float(got.mean_m[i, j])) - mean) <= mean * Fraction(1, 10**13)
            for k, moment in ((2, got.m2_m2), (3, got.m3_m3), (4, got.m4_m4)):
                exact = sum((x - mean) ** k for x in xs)
                scale = sum(abs(x - mean) ** k for x in xs)
                assert abs(Fraction(float(moment[i, j])) - exact) <= scale * Fraction(1, 10**13), (i, j, k)


def test_the_frame_signal_and_valid_count_match_numpy():
    """What `add` returns (the frame's mean of 1/z - 1/z_ref over valid pixels, in 1/m) and the valid count."""
    rng = np.random.default_rng(5)
    frames = np.rint(rng.normal(2000, 30, (6, 7, 9))).astype(np.uint16)
    frames[rng.random(frames.shape) < 0.3] = 0
    acc = PixelMomentAccumulator((7, 9), 0.001)
    ref = np.zeros((7, 9))
    for f in frames:
        got = acc.add(f)
        ref = np.where((ref == 0) & (f > 0), f, ref)
        valid = f > 0
        expect = np.mean(1 / (f[valid] * 0.001) - 1 / (ref[valid] * 0.001))
        assert acc.last_valid == valid.sum()
        assert got == pytest.approx(expect, rel=1e-12, abs=1e-15)
