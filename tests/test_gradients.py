"""The likelihood's analytic gradient (`rig.models.parts.tangents`) against central differences of the likelihood
itself, for every built-in effect and every empirical term, alone and composed.

The differences are fourth-order (f(x +- h), f(x +- 2h)), with h 1e-4 of each parameter's scale, on recordings
that reach every branch: a 0.05 mm depth unit with a stop at 3.1 m (the format ends at 3.28 m, so rows there
take the quadrature near the end), projector-off frames (ambient), a camera that drifts, mismatches and drops
samples; and a 1 mm unit where rounding to the depth unit matters. The point is off the optimum (parameters moved
from their start), where the gradient is large and a wrong term shows."""

from __future__ import annotations

import math

import numpy as np
import pytest
from simrig import record_perpendicular

from rig.models import parse_model
from rig.models.fitting.closed_form import power_law_mle
from rig.models.parts.component import EFFECTS
from rig.models.data.model_data import ModelData
from rig.models.effects.empirical import SHAPES
from rig.models.fitting.likelihood import model_loglik_gradient
from rig.models.parts.parameters import Param
from rig.models.parts.tangents import analytic

#: analytic derivatives against differences, two computations of each: run again on the other floating-point paths
pytestmark = pytest.mark.numeric

#: agreement asked of each parameter's derivative (times its scale), against the largest such derivative:
#: the fourth-order differences' own error is below 1e-8 here; rows whose rounded moments sit on a kink of the
#: rounding table (bilinear in ln s) are differenced over a smaller step per row than over the whole likelihood
RTOL = 1e-5


@pytest.fixture(scope="module")
def fine(tmp_path_factory) -> ModelData:
    path, _, _ = record_perpendicular(tmp_path_factory.mktemp("g") / "fine.h5", width=32, frames=20, seed=3,
                                      stops_m=[0.5, 1.25, 2.25, 3.1], ambient_frames=4,
                                      effects="noise_floor(sigma_px=0.03)+outliers(fraction=0.02)+drift+ambient")
    return ModelData.from_recording(path)


@pytest.fixture(scope="module")
def coarse(tmp_path_factory) -> ModelData:
    path, _, _ = record_perpendicular(tmp_path_factory.mktemp("g") / "coarse.h5", width=32, frames=20, seed=4,
                                      stops_m=[0.5, 0.75, 1.0, 1.5], depth_unit_mm=1.0)
    return ModelData.from_recording(path)


def _point(model, d: ModelData, seed: int) -> dict[str, float]:
    """Parameter values off the optimum: the model's start values moved by a few per cent (empirical shapes:
    by 0.1 in ln)."""
    rng = np.random.default_rng(seed)
    values = {n: p.value for n, p in model.parameters()}
    paper = power_law_mle(d.z_m, d.m2_m2, d.n, lam=model.base.lam)
    values["k"], values["lambda"] = paper.k, paper.lam
    partial = type(model)(model.base)
    for e in model.effects:
        for k, v in e.start(d, partial.predict(values, d)).items():
            values[f"{e.name}.{k}"] = v
        partial = partial + e
    for n, p in model.free():
        if n.startswith("empirical("):
            values[n] += 0.1 * rng.standard_normal()
        else:
            values[n] *= 1.0 + 0.03 * rng.standard_normal()
        values[n] = min(max(values[n], p.min), p.max)
    return values


def _check(spec: str, d: ModelData, seed: int = 0) -> None:
    model = parse_model(spec)
    assert analytic(model), f"{spec}: a built-in model must carry its own derivatives"
    values = _point(model, d, seed)
    names = [n for n, _ in model.free()]
    ll, grad = model_loglik_gradient(model, values, d, names)
    # one implementation: the same prediction (its derivatives are carried beside it, not mixed into it) summed by the
    # same compiled pass over the same chunks, so the same value to the last bit on any processor
    assert ll == model.loglik(values, d)
    numeric = []
    scales = []
    for n in names:
        # an empirical shape's step is absolute and small: its cubic has a kink where two knots' values cross
        s = 1e-2 if n.startswith("empirical(") else max(abs(values[n]), 1e-6)
        h = 1e-4 * s

        def f(x: float, n=n) -> float:
            return model.loglik(dict(values, **{n: values[n] + x}), d)

        numeric.append((8 * (f(h) - f(-h)) - (f(2 * h) - f(-2 * h))) / (12 * h))
        scales.append(s)
    a, b = np.array(grad) * scales, np.array(numeric) * scales
    worst = np.max(np.abs(a - b))
    assert worst <= RTOL * np.max(np.abs(b)), (
        f"{spec}: analytic gradient {dict(zip(names, grad))} against differences {dict(zip(names, numeric))}")


BUILT_INS = [e for e in EFFECTS if e not in ("quantization",)]


@pytest.mark.parametrize("effect", BUILT_INS)
def test_each_built_in_effect_has_the_likelihoods_gradient(fine, effect):
    _check(f"power_law+{effect}", fine)


@pytest.mark.parametrize("shape", SHAPES)
def test_each_empirical_term_has_the_likelihoods_gradient(fine, shape):
    _check(f"power_law+noise_floor+empirical({shape})", fine, seed=1)


def test_rounding_to_a_coarse_depth_unit_has_the_likelihoods_gradient(coarse):
    _check("power_law+noise_floor+quantization", coarse)


@pytest.mark.parametrize("spec", [
    "active+read_noise+slant_range+incidence+ambient+noise_floor",
    "power_law+noise_floor+censoring+outliers",
    "power_law+drift+censoring+empirical(tails)+empirical(fill)",
    "active+noise_floor+empirical(radius)+empirical(position)",
])
def test_composed_models_have_the_likelihoods_gradient(fine, spec):
    _check(spec, fine, seed=2)


def test_the_stop_near_the_formats_end_takes_the_quadrature(fine):
    """The fixture reaches the branch it is there for: rows within 6 standard deviations of the deepest range (the
    series `_series` where the model does not censor, the quadrature where it does)."""
    z_max = 65535 * fine.depth_unit_m
    sigma_d = np.sqrt(fine.s2_m2) * fine.fb_px_m / fine.z0_m**2
    a = (fine.fb_px_m / z_max - fine.fb_px_m / fine.z0_m) / sigma_d
    assert (a > -6.0).sum() > 10 and math.isclose(z_max, 3.27675)


#: a user's effect at each stage, as a term of the covariates (`rig.models.effects.user_effects.TermEffect`)
USER_STAGES = {
    "illumination": (lambda c, n: 1.0 / np.maximum(c.cos_off_axis, 0.1) ** n, Param("n", 1.5, 0.0, 10.0, "1", "power")),
    "image_noise": (lambda c, r: r * c.z_m**2, Param("r", 0.05, 0.0, 10.0, "1", "ratio at 1 m")),
    "disparity": (lambda c, s: s**2 * (1.0 + c.rho2), Param("s", 0.02, 0.0, 1.0, "px", "floor")),
    "range": (lambda c, v: v * c.z_m, Param("v", 1e-7, 0.0, 1e-3, "m", "added variance per m")),
    "variance": (lambda c, a: np.exp(a * c.rho2), Param("a", 0.3, -5.0, 5.0, "1", "growth with radius")),
}


@pytest.mark.parametrize("stage", USER_STAGES)
def test_a_users_effect_has_the_likelihoods_gradient_at_every_stage(fine, stage):
    """A user's effect has no formula rig knows: its own derivative is the function's central differences (the
    function alone), carried by the chain rule like any other's."""
    from rig.models.effects.user_effects import TermEffect

    fn, param = USER_STAGES[stage]
    users = type(f"Users_{stage}", (TermEffect,), {"name": f"users_{stage}", "stage": stage, "params": (param,),
                                                   "signature": "test", "term": lambda self, c, **kw: fn(c, *kw.values())})
    e = users()
    model = parse_model("power_law+noise_floor") + e
    assert analytic(model)
    values = _point(model, fine, 5)
    values[f"{e.name}.{param.name}"] = param.value * 1.1
    names = [n for n, _ in model.free()]
    ll, grad = model_loglik_gradient(model, values, fine, names)
    for n, g in zip(names, grad):
        h = 1e-4 * abs(values[n])

        def f(x: float, n=n) -> float:
            return model.loglik(dict(values, **{n: values[n] + x}), fine)

        numeric = (8 * (f(h) - f(-h)) - (f(2 * h) - f(-2 * h))) / (12 * h)
        assert g == pytest.approx(numeric, rel=1e-5, abs=1e-5 * np.max(np.abs(grad * [values[m] for m in names]))
                                  / abs(values[n])), (stage, n)


def test_the_outlier_rows_chain_rule_against_differences_on_every_branch():
    """`_outlier_row`'s derivatives in var0, fraction and width against fourth-order differences of its own value,
    on rows where the mismatches' lower end is -w, the format's end, and (wide mismatches far out) nearly w."""
    from rig.models.effects.builtin import outliers as effects

    # the Python of the row: compiled on its own it is a second copy of the kernel it is inlined into (1.3 s to build)
    _outlier_row = getattr(effects._outlier_row, "py_func", effects._outlier_row)
    rng = np.random.default_rng(11)
    fb, deepest = 380.0 * 0.05, 65535 * 5e-5  # f b in px m, the deepest range in m (0.05 mm unit)
    branches = set()
    for _ in range(300):
        z = rng.uniform(0.4, 3.25)
        v0 = (rng.uniform(1e-4, 3e-2) * z) ** 2
        k40, f, w = rng.uniform(0, 2) * v0 * v0, rng.uniform(0.001, 0.4), rng.uniform(0.05, 20.0)
        lo = fb / deepest - fb / z
        branches.add("end" if lo > -w else "-w")
        x = np.array([v0, f, w])
        for j, h in enumerate((1e-4 * v0, 1e-5, 1e-5 * w)):
            def numeric(h, j=j):
                def at(dx):
                    y = x.copy()
                    y[j] += dx * h
                    return np.array(_outlier_row(z, y[0], k40, y[1], y[2], fb, deepest, 0.0, 0.0, 0.0)[:3])
                return (8 * (at(1) - at(-1)) - (at(2) - at(-2))) / (12 * h)
            # the differences' own error: what halving the step changes, plus 1e-6 of each value, because the row
            # cancels up to ~10 digits (E[Z_o^2] - E[Z_o]^2 for narrow mismatches, m4 r^2 - 3 var^2) and a step of
            # 1e-4-1e-5 multiplies the rounding by 1e4-1e5; a wrong term in the chain rule is off by its own size
            n1, n2 = numeric(h), numeric(h / 2)
            tolerance = 3 * np.abs(n1 - n2) + 1e-6 * np.abs(n1)
            analytic_d = np.array(_outlier_row(z, v0, k40, f, w, fb, deepest, *np.eye(3)[j])[3:6])
            assert np.all(np.abs(analytic_d - n2) <= tolerance), (z, v0, f, w, j, analytic_d, n1, n2)
        # k4 is exactly linear in k40: a step as large as k4 itself shows the slope without rounding
        k4, slope = np.array(_outlier_row(z, v0, k40, f, w, fb, deepest, 0.0, 0.0, 0.0))[[1, 6]]
        step = max(abs(k4), v0 * v0)
        k4_up = _outlier_row(z, v0, k40 + step, f, w, fb, deepest, 0.0, 0.0, 0.0)[1]
        assert (k4_up - k4) / step == pytest.approx(slope, rel=1e-9)
    assert branches == {"end", "-w"}
