"""The streaming per-pixel statistics against numpy on the same raw frames, and against exact rational arithmetic.

Counts are exact. The moments are two implementations' floating point (the accumulator's shifted power sums,
numpy's two passes): each within the bound its operations give (tests/moment_bounds.py), so the two within the sum
of their bounds, pixel by pixel."""

import numpy as np
import pytest

from moment_bounds import U, accumulator_bounds, numpy_bounds, numpy_moments
from protocols.stats import PixelMomentAccumulator

MOMENTS = ("mean_m", "m2_m2", "m3_m3", "m4_m4")


@pytest.mark.numeric
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
    want = numpy_moments(frames, scale)
    np.testing.assert_array_equal(got.count, want["count"])
    # the bounds: the mean within 1.2e-14, M2 within 2.7e-12 (a narrow pixel at 30 m: numpy's deviations each carry
    # the rounding of a sample 60,000 times their size), M3 and M4 within 5e-9 and 4e-10 where they nearly cancel
    ours, theirs = accumulator_bounds(frames, scale), numpy_bounds(frames, scale)
    for name in MOMENTS:
        diff = np.abs(getattr(got, name) - want[name])
        assert np.all(diff <= ours[name] + theirs[name]), (name, np.max(diff / (ours[name] + theirs[name])))


def test_pixel_without_samples_is_nan_and_count_zero():
    acc = PixelMomentAccumulator((2, 2), 0.001)
    f = np.array([[0, 1000], [1000, 1000]], np.uint16)
    acc.add(f)
    acc.add(f + np.array([[0, 2], [0, 0]], np.uint16))
    r = acc.result()
    assert r.count[0, 0] == 0 and np.isnan(r.mean_m[0, 0])
    assert r.count[0, 1] == 2
    # against decimal values: each side a few roundings of the same exact number (1001 units of fl(0.001); 2 units^2
    # of it squared), within 8 u of each other (np.isclose's default atol=1e-8 would allow 0.5 % of 2e-6)
    rtol = 4 * np.finfo(np.float64).eps
    assert np.isclose(r.mean_m[0, 1], 1.001, rtol=rtol, atol=0)
    assert np.isclose(r.m2_m2[0, 1], 2 * 0.001**2, rtol=rtol, atol=0)
    assert np.isclose(r.variance_m2[0, 1], 2e-6, rtol=rtol, atol=0)


@pytest.mark.numeric
def test_streaming_moments_are_exact_to_1e13_against_rational_arithmetic():
    """Every stored moment against the same moments computed exactly (Python fractions, no floating point): within
    the bound of the accumulator's own roundings (tests/moment_bounds.py), and that bound within 1e-13 of the mean
    and M2, and of sum |z - mean|^k for M3 and M4 (4.1e-14 at most here), outliers across the whole uint16 range
    included (where the float64 sums S3, S4 round)."""
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
    bound = accumulator_bounds(frames, 1.0)
    for i in range(h):
        for j in range(w):
            xs = [int(v) for v in frames[:, i, j] if v]
            assert got.count[i, j] == len(xs)
            mean = Fraction(sum(xs), len(xs))
            assert abs(Fraction(float(got.mean_m[i, j])) - mean) <= Fraction(float(bound["mean_m"][i, j]))
            assert bound["mean_m"][i, j] <= 1e-13 * mean
            for k, moment in ((2, got.m2_m2), (3, got.m3_m3), (4, got.m4_m4)):
                exact = sum((x - mean) ** k for x in xs)
                scale = sum(abs(x - mean) ** k for x in xs)
                b = bound[f"m{k}_m{k}"][i, j]
                assert abs(Fraction(float(moment[i, j])) - exact) <= Fraction(float(b)), (i, j, k)
                assert b <= 1e-13 * scale, (i, j, k, b / scale)


@pytest.mark.numeric
def test_the_frame_signal_and_valid_count_match_numpy():
    """What `add` returns (the frame's mean of 1/z - 1/z_ref over valid pixels, in 1/m) and the valid count.

    The accumulator forms each term -(d - ref) / (d ref) from exact integers (one rounding), adds the n terms (n - 1
    roundings) and divides twice; numpy forms 1/(d s) and 1/(ref s) (two roundings each, on values near 1/z, which
    the difference cancels) and takes their mean (n - 1 additions, a quotient). Together: within
    u (4 mean(1/z) + (2 n + 4) mean |term|), in 1/m."""
    rng = np.random.default_rng(5)
    frames = np.rint(rng.normal(2000, 30, (6, 7, 9))).astype(np.uint16)
    frames[rng.random(frames.shape) < 0.3] = 0
    acc = PixelMomentAccumulator((7, 9), 0.001)
    ref = np.zeros((7, 9))
    for f in frames:
        got = acc.add(f)
        ref = np.where((ref == 0) & (f > 0), f, ref)
        valid = f > 0
        terms = 1 / (f[valid] * 0.001) - 1 / (ref[valid] * 0.001)
        expect = np.mean(terms)
        assert acc.last_valid == valid.sum()
        n = valid.sum()
        bound = U * (4 * np.mean(1 / (f[valid] * 0.001)) + (2 * n + 4) * np.mean(np.abs(terms)))
        assert abs(got - expect) <= bound, (got, expect, bound)
