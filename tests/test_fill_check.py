"""The fill-rate check's standard error when a model expects a handful of samples lost and none were.

A recording made like the demo's (0.05 mm depth unit, so the format ends at 3.28 m, a stop at 3.0 m) ended
"beyond noise" after the right model: the model expected about 6.5 of 636,000 samples at 3.0 m to fall beyond
the format's end, none did, and the check's standard error came from the measured share (variance 0, floored
at one sample), so it read 6.5 standard errors. Under the model the count is binomial with mean 6.5 and
variance 6.5: 2.5 standard errors. The check now takes the larger of the two binomial variances."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rig.diagnosis.consistency import fill_check
from rig.diagnosis.stop_sums import StopSums
from rig.models import ModelData, parse_model


@pytest.mark.numeric
@pytest.mark.parametrize("expected_lost", [4.0, 25.0])
def test_samples_the_model_expects_lost_and_none_were_are_counted_under_the_model(small_recording, expected_lost):
    d = ModelData.from_recording(small_recording)
    last = d.stop == d.stop.max()
    assert np.all(d.fill[last] == 1.0)  # the fixture's far stop lost no sample
    pred = parse_model("active").fit(d, errors=False).predict(d)
    frames = d.n / d.fill
    total = frames[last].sum()
    p = expected_lost / total
    pred.fill = np.where(last, 1.0 - p, 1.0)
    stops = StopSums()
    stops.add(d, pred)
    check = fill_check(d, stops)
    # one share per pixel, equal frames: the stop's mean share has variance p (1 - p) / total under the model.
    # The check forms 1 - fill from fill = 1 - p, which is p within u absolutely, u / p relatively; it sums its k
    # pixels' equal terms (k - 1 roundings) and takes a root and a quotient: se within u / (2 p) + (k + 6) u. Its z
    # takes 1 less the model's mean fill, a sum of k terms near 1 over k, so within (k + 1) u absolutely, divided by
    # the share p lost: z within (k + 3) u / p + (k + 10) u (7e-11 for 4 samples expected lost, 1e-11 for 25)
    u, k = np.finfo(np.float64).eps / 2, last.sum()
    assert check.se[-1] == pytest.approx(math.sqrt(p * (1 - p) / total), rel=u / (2 * p) + (k + 6) * u, abs=0)
    assert check.z[-1] == pytest.approx(expected_lost / math.sqrt(expected_lost * (1 - p)),
                                        rel=(k + 3) * u / p + (k + 10) * u, abs=0)
    # where the model expects nothing lost, the floor of one sample stays: one over a sum of the first stop's frames,
    # here and there added in other orders, 2 k u apart at most. (abs=0: pytest.approx's own 1e-12 would be 2e-9 of se)
    first = d.stop == d.stop.min()
    assert check.se[0] == pytest.approx(1.0 / frames[first].sum(), rel=2 * (first.sum() + 1) * u, abs=0)
