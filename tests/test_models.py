"""Composable models: composition, the base equals the paper's fit, effect parameters are recovered."""

import numpy as np
import pytest

from protocols.recording import Recording
from rig.models import (EFFECTS, Model, ModelData, active, censoring, noise_floor, parse_model, passive, power_law,
                        slant_range, fit_power_law, load_samples)
from simrig import record_perpendicular


@pytest.fixture(scope="module")
def floor_data(tmp_path_factory):
    """Active perpendicular run with a known noise floor (0.04 native px = 0.005 px at 106 px wide)."""
    path, truth, _ = record_perpendicular(tmp_path_factory.mktemp("m") / "f.h5", width=106, frames=60, seed=11,
                                          effects="noise_floor(sigma_px=0.04)")
    return ModelData.from_recording(path), truth, path


def test_composition_reads_like_lmfit_and_is_order_free():
    a = active + slant_range + noise_floor
    b = active + noise_floor + slant_range
    assert a == b and a.name == "active+slant_range+noise_floor"
    assert parse_model("active+noise_floor+slant_range") == a
    assert [n for n, _ in a.free()] == ["k", "noise_floor.sigma_px"]
    assert [n for n, _ in (power_law + censoring).free()] == ["k", "lambda", "censoring.threshold_px"]
    assert (a + noise_floor) == a  # adding an effect twice changes nothing


@pytest.mark.parametrize("text,message", [
    ("slant_range+active", "must start with a base model"),
    ("active+sunlight", "unknown effect 'sunlight'"),
])
def test_bad_model_strings(text, message):
    with pytest.raises(ValueError, match=message):
        parse_model(text)


def test_every_effect_documents_its_physics_and_parameters():
    for name, e in EFFECTS.items():
        assert e.name == name and e.signature and e.explanation and type(e).__doc__
        for p in e.params:
            assert p.unit and p.doc and p.min <= p.value <= p.max


def test_base_model_is_the_papers_fit(tmp_path):
    # up to 1.5 m the curvature of Z = f b / d (which the models include and the paper's fit
    # does not) is below 0.02 % of the variance, so the two fits must agree; they differ by design
    # in two small ways (docs/models.md, the likelihood): the models predict at the true range, not
    # the samples' mean, and weigh each pixel's variance by the measured kurtosis, not 3. Together
    # these move lambda by 0.2 standard errors here, so the bound is half a standard error.
    path, _, _ = record_perpendicular(tmp_path / "s.h5", width=106, frames=60, seed=12,
                                      stops_m=[0.5, 0.75, 1.0, 1.25, 1.5], effects="noise_floor(sigma_px=0.04)")
    d = ModelData.from_recording(path)
    with Recording(path) as rec:
        paper = fit_power_law(load_samples(rec))
    mine = Model(power_law).fit(d)
    assert mine.values["lambda"] == pytest.approx(paper.lam, abs=0.5 * paper.se_lam)
    assert mine.values["k"] == pytest.approx(paper.k, abs=0.5 * paper.se_k)
    assert mine.errors["lambda"] == pytest.approx(paper.se_lam, rel=0.01)
    assert mine.errors["k"] == pytest.approx(paper.se_k, rel=0.01)


@pytest.mark.slow
def test_noise_floor_recovered_and_lambda_back_to_three(floor_data):
    d, (k, lam), _ = floor_data
    f = (active + noise_floor).fit(d)
    sigma_true = 0.04 * 106 / 848
    assert abs(f.values["noise_floor.sigma_px"] - sigma_true) < 3 * f.errors["noise_floor.sigma_px"] + 0.002 * sigma_true
    assert abs(f.values["k"] - k) < 3 * f.errors["k"] + 0.002 * k
    free = (power_law + noise_floor).fit(d)
    assert abs(free.values["lambda"] - 3.0) < 3 * free.errors["lambda"] + 0.003
    # the paper's power law, without the floor, is pulled far below 3
    assert Model(power_law).fit(d).values["lambda"] < 2.8


def test_effects_that_need_the_projector_refuse_passive_data(tmp_path):
    path, _, _ = record_perpendicular(tmp_path / "p.h5", width=32, frames=10, projector_on=False)
    d = ModelData.from_recording(path)
    with pytest.raises(ValueError, match="slant_range needs the projector on"):
        (passive + slant_range).fit(d)


@pytest.mark.numeric
def test_the_empirical_shape_is_scipys_pchip():
    """The empirical terms' curve (evaluated directly, for speed) against scipy's PchipInterpolator, on random
    knots and values, flat runs and sign changes included.

    The slopes are the same expressions both ways, and so are their branches (a flat run gives exact zeros); the
    curve is evaluated two ways: rig's Hermite basis in t = (x - x_i) / h (each basis function within 48 u of its
    exact value, its powers of t carrying t's 3 u), scipy's polynomial coefficients in x - x_i by Horner's rule
    (compiled code, which GCC may fuse into multiply-adds; its coefficients cancel up to |d_i| + |d_i+1| + 2 |m|,
    within about 30 u of S). With S = |y_i| + |y_i+1| + h (|d_i| + |d_i+1|), the size of the cubic's terms on the
    interval, the two agree within 85 u S (8 u S seen here)."""
    from scipy.interpolate import PchipInterpolator

    from rig.models.effects.empirical import _smooth
    from rig.models.effects.pchip import pchip_slopes

    u = np.finfo(np.float64).eps / 2
    rng = np.random.default_rng(1)
    for _ in range(500):
        knots = np.cumsum(rng.uniform(0.05, 1.0, rng.integers(3, 9)))
        values = np.round(rng.normal(0, 1, len(knots)), int(rng.integers(0, 3)))
        x = rng.uniform(knots[0] - 1, knots[-1] + 1, 100)
        want = PchipInterpolator(knots, values, extrapolate=False)(np.clip(x, knots[0], knots[-1]))
        i = np.clip(np.searchsorted(knots, np.clip(x, knots[0], knots[-1]), side="right") - 1, 0, len(knots) - 2)
        d, h = np.abs(pchip_slopes(knots, values)), np.diff(knots)[i]
        size = np.abs(values[i]) + np.abs(values[i + 1]) + h * (d[i] + d[i + 1])
        assert np.all(np.abs(_smooth(knots, values, x) - want) <= 85 * u * size), (knots, values)
