"""A held-out fold's refit from the whole data's fit (`fit_model(..., warm=)`): the same optimum as a refit from
scratch, within a small fraction of a standard error, in fewer likelihood evaluations."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

import rig.models.fitting.optimise as optimise
from rig.models import ModelData
from rig.models.fitting.grouping import whole_stops
from rig.models.parse import parse_model
from simrig import record_perpendicular


def _counted(monkeypatch) -> list[int]:
    calls = [0]
    gradient = optimise.model_loglik_gradient

    def counted(*a, **k):
        calls[0] += 1
        return gradient(*a, **k)

    monkeypatch.setattr(optimise, "model_loglik_gradient", counted)
    return calls


def test_a_warm_refit_reaches_the_cold_refits_optimum_in_fewer_evaluations(tmp_path, monkeypatch):
    path, _, _ = record_perpendicular(tmp_path / "r.h5", seed=3, width=48, frames=40, effects="noise_floor")
    d = ModelData.from_recording(path)
    model = parse_model("power_law+noise_floor")  # k, lambda and the floor free: the physical second start applies
    full = model.fit(d)
    assert full.metric is not None and list(full.metric[0]) == [n for n, _ in model.free()]
    se = np.array([full.errors[n] for n, _ in model.free()])
    assert np.all(np.isfinite(se))
    calls = _counted(monkeypatch)
    for left_out in (0, 3):
        train = whole_stops(d, d.stop != left_out, statistics=False)
        calls[0] = 0
        cold = model.fit(train, start=full.values, errors=False, exact_loglik=False)
        cold_calls = calls[0]
        calls[0] = 0
        warm = model.fit(train, errors=False, exact_loglik=False, warm=full)
        warm_calls = calls[0]
        calls[0] = 0  # the same single start without the whitening
        model.fit(train, errors=False, exact_loglik=False, warm=replace(full, metric=None, covariance=None))
        plain_calls = calls[0]
        names = [n for n, _ in model.free()]
        gap = np.array([abs(warm.values[n] - cold.values[n]) for n in names]) / se
        # both stop within sqrt(4 STOP_NATS) = 0.002 standard error of the fold's optimum (rig.models.fitting.stopping)
        assert np.all(gap < 0.01), dict(zip(names, gap))
        assert abs(warm.loglik - cold.loglik) < 1e-4 * max(1.0, math.sqrt(len(train)))
        assert warm_calls < plain_calls < cold_calls, (warm_calls, plain_calls, cold_calls)


def test_a_warm_fit_of_another_model_or_of_a_fit_on_a_bound_reaches_the_cold_optimum(tmp_path):
    path, _, _ = record_perpendicular(tmp_path / "r.h5", seed=4, width=32, frames=20)
    d = ModelData.from_recording(path)
    full = parse_model("power_law+noise_floor").fit(d)
    # another model: the warm fit's values start it; its estimates, over other parameters, are not used
    other = parse_model("passive")
    cold = other.fit(d)
    warm = other.fit(d, errors=False, warm=full)
    assert abs(warm.values["k"] - cold.values["k"]) < 0.01 * cold.errors["k"]
    # outliers where the data have none: the fraction ends on its bound, and the refit from it is not whitened
    on_bound = parse_model("power_law+outliers")
    first = on_bound.fit(d)
    free = on_bound.free()
    names = [n for n, _ in free]
    assert dict(free)["outliers.fraction"].at_bound(first.values["outliers.fraction"])
    assert optimise._whitening(first, names, np.zeros(len(names)), free, 1.0) is None
    again = on_bound.fit(d, errors=False, warm=first)
    assert again.loglik >= first.loglik - 1e-3
