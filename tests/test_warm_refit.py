"""A held-out fold's refit from the whole data's fit (`fit_model(..., warm=)`): the same optimum as a refit from
scratch, within a small fraction of a standard error, in fewer likelihood evaluations."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

import rig.models.optimise as optimise
from rig.models import ModelData
from rig.models.grouping import whole_stops
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
        model.fit(train, errors=False, exact_loglik=False, warm=replace(full, metric=None))
        plain_calls = calls[0]
        names = [n for n, _ in model.free()]
        gap = np.array([abs(warm.values[n] - cold.values[n]) for n in names]) / se
        # both stop within sqrt(4 STOP_NATS) = 0.002 standard error of the fold's optimum (rig.models.stopping)
        assert np.all(gap < 0.01), dict(zip(names, gap))
        assert abs(warm.loglik - cold.loglik) < 1e-4 * max(1.0, math.sqrt(len(train)))
        assert warm_calls < plain_calls < cold_calls, (warm_calls, plain_calls, cold_calls)


def test_a_warm_fit_over_other_parameters_is_not_whitened(tmp_path):
    path, _, _ = record_perpendicular(tmp_path / "r.h5", seed=4, width=32, frames=20)
    d = ModelData.from_recording(path)
    full = parse_model("power_law+noise_floor").fit(d, errors=False)
    other = parse_model("passive")
    assert optimise._whitening(full, [n for n, _ in other.free()]) is None
    f = other.fit(d, errors=False, warm=full)  # its values start the fit; its metric, over other names, is not used
    assert f.converged and abs(f.values["lambda"] - full.values["lambda"]) < 1.0
