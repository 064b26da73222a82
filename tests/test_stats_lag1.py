"""The streaming lag-1 sums (frame independence) against numpy on the stacked frames."""

import numpy as np
import pytest

from moment_bounds import lag1_bounds
from protocols.stats import PixelMomentAccumulator


def numpy_lag1(frames: np.ndarray):
    """Per pixel, with the accumulator's shift (its first valid sample): pairs of consecutive valid frames, and
    over them sum x_t x_{t-1} and sum (x_t + x_{t-1}) of the shifted samples, in int64."""
    valid = frames > 0
    first = np.argmax(valid, axis=0)
    shift = np.where(valid.any(axis=0), np.take_along_axis(frames, first[None], axis=0)[0], 0).astype(np.int64)
    x = frames.astype(np.int64) - shift
    both = valid[1:] & valid[:-1]
    xy = np.where(both, x[1:] * x[:-1], 0).sum(axis=0)
    x_plus_y = np.where(both, x[1:] + x[:-1], 0).sum(axis=0)
    return both.sum(axis=0), xy, x_plus_y


@pytest.mark.numeric
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lag1_sums_are_exact_against_numpy_with_missing_data(seed):
    rng = np.random.default_rng(seed)
    n, h, w = 60, 7, 11
    true = rng.uniform(300, 40000, (h, w))
    frames = np.rint(rng.normal(true, rng.uniform(0.5, 50, (h, w)), (n, h, w))).astype(np.uint16)
    frames[rng.random((n, h, w)) < 0.25] = 0  # missing data breaks pairs
    frames[:5, 0, 0] = 0  # the shift comes from a later frame
    far = rng.random((n, h, w)) < 0.01
    frames[far] = rng.integers(1, 65535, far.sum())  # outliers across the whole range
    frames[1] = frames[0]  # one repeated frame
    acc = PixelMomentAccumulator((h, w), 0.001)
    for f in frames:
        acc.add(f)
    pairs, xy, x_plus_y = numpy_lag1(frames)
    np.testing.assert_array_equal(acc.pairs, pairs)
    np.testing.assert_array_equal(acc.lag_xy, xy)
    np.testing.assert_array_equal(acc.lag_x_plus_y, x_plus_y)
    assert acc.frames_repeated == 1
    # C1 = sum over pairs of (z_t - mean)(z_{t-1} - mean), against floating numpy: within the two implementations'
    # rounding, pixel by pixel (tests/moment_bounds.py)
    r = acc.result()
    z = np.where(frames > 0, frames * 0.001, np.nan)
    d = z - np.nanmean(z, axis=0)
    c1 = np.nansum(d[1:] * d[:-1], axis=0)
    bound = lag1_bounds(frames, 0.001)
    assert np.all(np.abs(r.lag1_m2 - c1) <= bound), np.max(np.abs(r.lag1_m2 - c1) / bound)
    np.testing.assert_array_equal(r.lag1_pairs, pairs)


def test_independent_frames_pool_to_zero_correlation_and_smoothed_ones_do_not():
    """The pooled lag-1 correlation (rig.models.data.independence) is about 0 for independent frames and about
    1 - alpha for exponential smoothing out_t = alpha in_t + (1 - alpha) out_{t-1}."""
    from rig.models.data.independence import pooled_lag1

    rng = np.random.default_rng(5)
    n, h, w, alpha = 40, 30, 40, 0.4
    noise = rng.normal(0, 20, (n, h, w))
    smooth = noise.copy()
    for t in range(1, n):
        smooth[t] = alpha * noise[t] + (1 - alpha) * smooth[t - 1]
    for series, want in ((noise, 0.0), (smooth, 1 - alpha)):
        acc = PixelMomentAccumulator((h, w), 0.001)
        for f in np.rint(10000 + series).astype(np.uint16):
            acc.add(f)
        r = acc.result()
        num, den, pairs = pooled_lag1(r)
        rho = num / den
        assert abs(rho - want) < 0.05, (rho, want)


def test_identical_frames_are_counted_as_repeated():
    acc = PixelMomentAccumulator((3, 4), 0.001)
    f = np.full((3, 4), 1000, np.uint16)
    g = f.copy()
    g[0, 0] = 0  # a pixel missing in one frame does not make it different
    for frame in (f, g, f, f + 1):
        acc.add(frame)
    assert acc.frames_repeated == 2
