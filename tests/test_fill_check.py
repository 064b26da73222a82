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
from rig.diagnosis.residuals import StopSums
from rig.models import ModelData, parse_model


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
    # one share per pixel, equal frames: the stop's mean share has variance p (1 - p) / total under the model
    assert check.se[-1] == pytest.approx(math.sqrt(p * (1 - p) / total), rel=1e-9)
    assert check.z[-1] == pytest.approx(expected_lost / math.sqrt(expected_lost * (1 - p)), rel=1e-9)
    # where the model expects nothing lost, the floor of one sample stays
    assert check.se[0] == pytest.approx(1.0 / frames[d.stop == d.stop.min()].sum(), rel=1e-9)
