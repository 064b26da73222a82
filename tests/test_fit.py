"""The maximum-likelihood fit of sigma_Z = k Z^lambda on exact model data.

Data are drawn from the fit's own model, z ~ N(Z, (k Z^lambda)^2), so any bias or
miscalibrated standard error is the estimator's.
"""

import numpy as np
import pytest

from rig.diagnosis import pooled_sigma
from rig.models import ModelData as PixelSamples
from rig.models import fit_power_law

STOPS = np.arange(0.5, 3.001, 0.25)


def model_samples(k, lam, seed, pixels_per_stop=150, frames=40):
    rng = np.random.default_rng(seed)
    z = np.repeat(STOPS, pixels_per_stop)
    x = rng.normal(z[:, None], (k * z**lam)[:, None], (z.size, frames))
    mean = x.mean(axis=1)
    d = x - mean[:, None]
    n = np.full(z.size, float(frames))
    nan = np.full(z.size, np.nan)
    return PixelSamples(z_m=mean, m2_m2=(d**2).sum(1), m4_m4=(d**4).sum(1), n=n,
                        stop=np.repeat(np.arange(STOPS.size), pixels_per_stop), u_px=nan, v_px=nan, ir=nan,
                        fill=np.ones(z.size), rho2=np.zeros(z.size), cos_inc=np.ones(z.size), ambient_ratio=nan,
                        drift_var_m2=np.zeros(z.size), projector_on=np.ones(z.size, bool))


@pytest.mark.parametrize("k,lam", [(0.002, 3.0), (0.005, 2.0)])
def test_recovers_parameters_and_standard_errors_match_spread(k, lam):
    fits = [fit_power_law(model_samples(k, lam, seed)) for seed in range(40)]
    lams = np.array([f.lam for f in fits])
    ks = np.array([f.k for f in fits])
    for f in fits[:8]:  # several seeds, each within 3 standard errors
        assert abs(f.lam - lam) < 3 * f.se_lam
        assert abs(f.k - k) < 3 * f.se_k
    # no bias: the mean over 40 seeds is within 3 standard errors of the mean
    assert abs(lams.mean() - lam) < 3 * np.mean([f.se_lam for f in fits]) / np.sqrt(len(fits))
    assert abs(ks.mean() - k) < 3 * np.mean([f.se_k for f in fits]) / np.sqrt(len(fits))
    # the Cramer-Rao standard errors describe the scatter across seeds (40 seeds: the
    # spread itself is known to about 11 %, so 30 % is a ~3 sigma band)
    se_lam = np.mean([f.se_lam for f in fits])
    se_k = np.mean([f.se_k for f in fits])
    assert abs(lams.std(ddof=1) / se_lam - 1) < 0.3
    assert abs(ks.std(ddof=1) / se_k - 1) < 0.3


@pytest.mark.numeric
def test_loglik_is_the_gaussian_likelihood_with_pixel_degrees_of_freedom():
    s = model_samples(0.002, 3.0, seed=5)
    f = fit_power_law(s)
    sig2 = (f.k * s.z_m**f.lam) ** 2
    terms = -0.5 * (s.n - 1) * np.log(2 * np.pi * sig2) - s.m2_m2 / (2 * sig2)
    brute = np.sum(terms)
    # two implementations: the brute force adds N terms (N - 1 roundings, each term within 20 u of its value: sigma^2
    # by pow and products, the log within 1 ulp), the closed form takes the log of a sum of N positive terms (N + 3
    # u); together (2 N + 30) u of the terms' size, 3.7e-13 here
    u = np.finfo(np.float64).eps / 2
    assert f.loglik == pytest.approx(brute, rel=(2 * len(s) + 30) * u * np.abs(terms).sum() / abs(brute), abs=0)
    # and it is the maximum: moving lambda by a little lowers it
    for dl in (-0.01, 0.01):
        lam = f.lam + dl
        k2 = np.sum(s.m2_m2 / s.z_m ** (2 * lam)) / np.sum(s.n - 1)
        sig2 = k2 * s.z_m ** (2 * lam)
        assert np.sum(-0.5 * (s.n - 1) * np.log(2 * np.pi * sig2) - s.m2_m2 / (2 * sig2)) < f.loglik


def test_fixed_lambda_fits_k_only():
    s = model_samples(0.002, 3.0, seed=2)
    f = fit_power_law(s, lam=3.0)
    assert f.lam_fixed and f.lam == 3.0
    assert abs(f.k - 0.002) < 3 * f.se_k


def test_single_range_cannot_estimate_lambda():
    s = model_samples(0.002, 3.0, seed=1)
    one = s.select(s.stop == 0)
    one.z_m[:] = 0.5
    with pytest.raises(ValueError, match="same range"):
        fit_power_law(one)


def test_pooled_sigma_per_stop():
    s = model_samples(0.002, 3.0, seed=4)
    b = pooled_sigma(s, s.stop)
    expected = 0.002 * b.z_m**3
    assert np.all(np.abs(b.sigma_m - expected) < 4 * b.se_sigma_m)


@pytest.mark.numeric
def test_on_many_pixels_newton_starts_from_a_subsample_and_ends_at_the_paper_s_maximum():
    """Above 4 x 64 x 1024 pixels lambda is first solved on every 64th (rig.models.fitting.closed_form.STRIDE); the maximum is
    still the paper's, as scipy's bounded scalar minimiser of the profile likelihood finds it (no Newton, no
    shared code), and the one Newton from the fixed start finds."""
    from scipy.optimize import minimize_scalar

    from rig.models.fitting import closed_form

    rng = np.random.default_rng(3)
    rows = 300_000
    z = rng.uniform(0.5, 3.0, rows)
    n = rng.integers(1, 60, rows).astype(float)  # some pixels with one sample: no degrees of freedom
    m2 = np.where(n > 1, (0.002 * z**2.6) ** 2 * rng.chisquare(np.maximum(n - 1, 1)), 0.0)
    est = closed_form.power_law_mle(z, m2, n)
    w = np.maximum(n - 1, 0.0)
    lz = np.where(n > 1, np.log(z), 0.0)
    W = w.sum()

    def profile(lam):  # -loglik with k profiled out (paper, eq. k_mle), up to a constant
        return 0.5 * W * np.log(np.sum(m2 * np.exp(-2 * lam * lz)) / W) + lam * np.sum(w * lz)

    scipy_lam = minimize_scalar(profile, bounds=(-2, 8), method="bounded", options={"xatol": 1e-12}).x
    # Brent's method on a function this flat at its minimum finds it to about sqrt(machine epsilon): a thousandth of
    # the standard error is far above that and far below anything a fit reports
    assert abs(est.lam - scipy_lam) < 1e-3 * np.sqrt(est.covariance[1, 1])
    lz_ref = np.where(n > 1, np.log(z) - np.sum(w * np.log(z)) / W, 0.0)
    fixed_start = closed_form._solve_lambda(lz_ref, m2, W, 0.0)
    # Two runs of Newton on the same root, one from the subsample's solution: each stops within 1e-13 lambda of where
    # its iteration settles, and where it settles is the root of B = sum m2 e^(-2 lambda ln z) ln z as rounded: that
    # sum of N terms is within (N + 20) u sum |terms| of exact (N - 1 additions; each term within 20 u: the exp's ulp,
    # its argument's two roundings times |2 lambda ln z| < 6, the products, and the two runs' ln z, numba's log and
    # numpy's), which moves the root by that over B's slope 2 C: each run within that, two within twice (5.8e-11
    # here; 3.5e-13 seen)
    u = np.finfo(np.float64).eps / 2
    t = m2 * np.exp(-2 * est.lam * lz_ref)
    settles = ((w > 0).sum() + 20) * u * np.sum(np.abs(t * lz_ref)) / (2 * np.sum(t * lz_ref**2))
    assert abs(est.lam - fixed_start) < 2 * (settles + 1e-13 * max(1.0, est.lam))
