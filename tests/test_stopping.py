"""The Newton-decrement stop (rig.models.fitting.stopping) against a likelihood with a closed-form optimum: a normal
sample's mean and log standard deviation, which no part of rig computes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize

from rig.models.fitting.stopping import STOP_NATS, NewtonStop, inverse_hessian

N = 1_000_000


def _draws() -> np.ndarray:
    """N draws of N(0.3, 1.7^2), seed 5."""
    return np.random.default_rng(5).normal(0.3, 1.7, N)


def _normal_sample() -> tuple[float, float]:
    """(mean, variance with divisor N) of `_draws`: the maximum-likelihood estimates."""
    x = _draws()
    return float(x.mean()), float(x.var())


def _fit(stopped: bool) -> tuple[np.ndarray, int, NewtonStop | None]:
    """L-BFGS-B on -loglik / scale in (mu, ln sigma), from a start far from the optimum, with the settings
    `rig.models.fitting.optimise` uses, and the Newton stop if `stopped`: (optimum, evaluations, the stop)."""
    x = _draws()
    mean, var = _normal_sample()
    scale = N * (0.5 * math.log(2 * math.pi * var) + 0.5) + 1.0
    callback = NewtonStop(scale) if stopped else None

    def f(y: np.ndarray) -> tuple[float, np.ndarray]:
        # summed sample by sample, as a likelihood over pixels is: its rounding is what the stop must not chase
        mu, ls = y
        s2 = math.exp(2 * ls)
        r2 = (x - mu) ** 2 / s2
        ll = float(np.sum(-0.5 * math.log(2 * math.pi) - ls - 0.5 * r2))
        g = np.array([float(np.sum(x - mu)) / s2, float(np.sum(r2 - 1.0))])
        if callback is not None:
            callback.seen(y, -g / scale)
        return -ll / scale, -g / scale

    r = minimize(f, np.array([0.0, 0.0]), method="L-BFGS-B", jac=True, callback=callback,
                 options={"maxiter": 500, "ftol": 1e-15, "gtol": 1e-10})
    return r.x, r.nfev, callback


def test_the_stop_ends_within_a_small_fraction_of_a_standard_error_and_sooner():
    mean, var = _normal_sample()
    x, nfev, stop = _fit(True)
    assert stop.stopped and 0.0 <= stop.gain_nats < STOP_NATS
    # the stop promises < STOP_NATS to gain: within sqrt(4 STOP_NATS) = 0.002 standard error of the optimum
    se_mu, se_ls = math.sqrt(var / N), math.sqrt(1 / (2 * N))
    assert abs(x[0] - mean) / se_mu < 0.01
    assert abs(x[1] - 0.5 * math.log(var)) / se_ls < 0.01
    _, nfev_plain, _ = _fit(False)
    assert nfev < nfev_plain


def test_the_stop_waits_for_one_step_per_parameter_before_trusting_its_estimate():
    stop = NewtonStop(scale=1.0)
    stop.seen(np.zeros(3), np.ones(3) * 1e-12)

    class Result:
        x = np.zeros(3)

    for _ in range(3):  # the start and three iterates at the same point: no curvature, no estimate, no stop
        stop(Result())
    assert not stop.stopped


@pytest.mark.numeric
def test_the_bfgs_estimate_meets_the_secant_equation_and_is_exact_in_one_dimension():
    a = np.array([[4.0, 1.0], [1.0, 3.0]])
    xs = [np.array([1.0, -2.0]), np.array([0.4, -0.5]), np.array([0.1, 0.05])]
    h = inverse_hessian([(x, a @ x) for x in xs])
    s, y = xs[2] - xs[1], a @ (xs[2] - xs[1])
    # The last update is h = V h0 V' + rho s s', V = I - rho s y', and V' y = 0: h y = s exactly in exact arithmetic.
    # Rounded, h's entries are within 8 u of |V| |h0| |V'| + rho |s| |s'| (two 2 x 2 products, V's own rounding, the
    # sum), V' y is within u (2 rho |y| |s'| |y| + |V'| |y|) of 0 instead, and the product h y rounds within 2 u |h| |y|
    # (a BLAS kernel may fuse it: no more)
    u = np.finfo(np.float64).eps / 2
    rho = 1.0 / float(s @ y)
    v = np.eye(2) - rho * np.outer(s, y)
    s0, y0 = xs[1] - xs[0], a @ (xs[1] - xs[0])
    h0 = inverse_hessian([(xs[0], a @ xs[0]), (xs[1], a @ xs[1])], prior=np.eye(2) * float(s @ y) / float(y @ y))
    assert float(s0 @ y0) > 0 and h0 is not None
    big_v, big_s, big_y = np.abs(v), np.abs(s), np.abs(y)
    bound = u * (8 * (big_v @ np.abs(h0) @ big_v.T @ big_y + rho * big_s * (big_s @ big_y))
                 + 2 * big_v @ np.abs(h0) @ (2 * rho * big_y * (big_s @ big_y) + big_v.T @ big_y)
                 + 2 * np.abs(h) @ big_y)
    assert np.all(np.abs(h @ y - s) <= bound), (h @ y - s, bound)
    # one dimension: V = 1 - fl(1/5) 5 = 0 exactly (fl(1/5) 5 rounds to 1 in round-to-nearest, on any IEEE machine,
    # and an elementwise product fuses with nothing), so h = rho s s = fl(1/5): exact
    h1 = inverse_hessian([(np.array([2.0]), np.array([10.0])), (np.array([1.0]), np.array([5.0]))])
    assert h1[0, 0] == 1 / 5.0
