"""Exact rounding (rig.models.data.rounding) against simulated rounded normals, which share no formula with it:
numpy draws normals, rounds them, drops the pixels whose samples are all equal (as `ModelData` does), and
the per-pixel sample variance is compared with the prediction made from the same measured mean offset the
model sees. Tolerances are the simulation's own standard error."""

import numpy as np
import pytest

from rig.models.data.rounding import expected_sample_variance, grid_offset, rounded_moments
from rig.models.data.rounding_table import F_GRID, MAX_CANCELLATION, N_GRID, S_GRID, TABLE_FILE, build, resample, table

PIXELS = 20_000


def simulate(s: float, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(measured mean offset, sample variance) of PIXELS pixels with n rounded samples of N(mu, s^2) each,
    mu uniform between two levels (units of q)."""
    rng = np.random.default_rng(seed)
    mu = rng.uniform(0.0, 1.0, PIXELS)[:, None]
    r = np.round(mu + s * rng.standard_normal((PIXELS, n)))
    s2 = r.var(axis=1, ddof=1)
    kept = s2 > 0  # all samples equal: not in the data
    return grid_offset(r.mean(axis=1))[kept], s2[kept]


@pytest.mark.parametrize("s", [0.05, 0.12, 0.2, 0.3, 0.45, 0.6, 1.5])
@pytest.mark.parametrize("n", [37, 100, 150])  # 37 and 150 lie between the table's counts
def test_expected_sample_variance_matches_simulated_rounded_normals(s, n):
    f, s2 = simulate(s, n, seed=int(1000 * s) + n)
    pixels = len(s2)
    predicted, _ = expected_sample_variance(np.full(pixels, s), f, np.full(pixels, n))
    diff = s2 - predicted
    # over pixels whose true means sit anywhere between two levels (what sigma by range compares):
    # 4 standard errors of the simulation, plus 0.1 % of the variance for the table's interpolation
    se = diff.std(ddof=1) / np.sqrt(pixels)
    assert abs(diff.mean()) < 4 * se + 1e-3 * s2.mean(), (s, n, diff.mean(), se)
    # pixel by pixel, in bands of the measured offset (0 on a level, q^2/4 half-way), the same: the prediction
    # is conditioned exactly on the measured mean (5 bands: 4.9 standard errors keeps the false alarms at 1e-5)
    band = np.digitize(np.abs(f), [0.1, 0.2, 0.3, 0.4])
    for b in range(5):
        m = band == b
        if m.sum() < 200:
            continue
        se = diff[m].std(ddof=1) / np.sqrt(m.sum())
        assert abs(diff[m].mean()) < 4.9 * se + 1e-3 * predicted[m].mean(), (s, n, b, diff[m].mean(), se)


@pytest.mark.slow
@pytest.mark.numeric
def test_shipped_table_is_what_the_sums_give():
    """The table in the package is the generating-function computation's, at a few grid points (regenerate it
    with `python -m rig.models.data.rounding_table` when the grids change)."""
    assert TABLE_FILE.exists()
    on_k, on_f = table()
    assert on_f.shape == (len(S_GRID), len(N_GRID), len(F_GRID))
    # The table was computed on another machine, whose libm, FFT and SIMD loops round differently: each entry is
    # within eps x log2(FFT size, at most 2^16) x MAX_CANCELLATION (what K = 0's subtraction may amplify) of the
    # true value, relatively, 3.6e-9; two computations within twice that. Entries near 0 (what a third level adds,
    # where it adds nothing) differ in absolute terms: 1e-12 q^2, far below any variance the model predicts.
    rtol = 2 * np.finfo(float).eps * 16 * MAX_CANCELLATION
    for i, n in ((3, 7), (20, 100), (40, 300)):
        j = int(np.searchsorted(N_GRID, n))
        fresh_k, fresh_f = resample(build(float(S_GRID[i]), n), n)
        np.testing.assert_allclose(on_k[i, j], fresh_k, rtol=rtol, atol=1e-12)
        np.testing.assert_allclose(on_f[i, j], fresh_f, rtol=rtol, atol=1e-12)


def test_a_kept_pixel_on_a_level_has_at_least_the_least_variance():
    """At K = 0 a kept pixel has a sample a level up and one a level down at least: s2 >= 2 / (n - 1), so the
    table's D = s2 (n - 1) / n >= 2 / n everywhere, also where the probability of it is at the rounding floor."""
    on_k, _ = table()
    least = 2.0 / N_GRID
    assert (on_k[:, :, 0] >= least * (1 - 1e-9)).all()


def test_two_levels_are_exact():
    """With s far below q only two levels occur, so s2 = n / (n - 1) f (1 - f) whatever the mean."""
    f = np.array([0.01, 0.1, 0.25, 0.4, 0.5])
    n = np.full(5, 100.0)
    predicted, _ = expected_sample_variance(np.full(5, 0.03), f, n)
    np.testing.assert_allclose(predicted, n / (n - 1) * f * (1 - f), rtol=1e-3)


def test_sheppards_correction_is_the_wide_limit():
    s = np.array([2.0, 2.9])
    var, mu4 = rounded_moments(s, np.array([0.1, 0.4]))
    np.testing.assert_allclose(var, s**2 + 1 / 12, rtol=2e-3)
    np.testing.assert_allclose(mu4, 3 * (s**2 + 1 / 12) ** 2 - 1 / 120, rtol=5e-3)


def test_narrow_noise_depends_on_where_the_mean_sits():
    var, _ = rounded_moments(np.array([0.05, 0.05]), np.array([0.0, 0.5]))
    assert var[0] < 1e-6 and abs(var[1] - 0.25) < 1e-3  # one level: nothing; half-way: two levels equally often
