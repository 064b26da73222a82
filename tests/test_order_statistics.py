"""`rig.models.data.order_statistics` gives numpy's own quantiles (linear method) and medians, bit for bit: for float32 and
float64 values of every kind of spread, odd and even counts, ties, a constant array and NaN (the last two handed
back to numpy or answered directly).

Exact equality is right here, on any processor: the selection returns elements of the array (no arithmetic), and
the only arithmetic, the interpolation between two of them, is numpy's own `quantile` (or `median`) on both sides,
given the same two values and the same fraction. That fraction, (n - 1) q less its floor, is one correctly rounded
product and an exact subtraction (as numpy forms it for the linear method), so it is the same everywhere too."""

import numpy as np
import pytest

from rig.models.data.order_statistics import SMALL, _order_statistics, median, quantiles


def _arrays(rng):
    size = SMALL + 1_237
    yield "uniform", rng.uniform(0, 255, size)
    yield "lognormal float32", rng.lognormal(3.0, 1.2, size).astype(np.float32)
    yield "normal even count", rng.normal(1.5, 0.01, size + 1)
    yield "one far outlier", np.append(rng.normal(0, 1, size), 1e12)
    yield "coarse levels float32", (np.round(rng.uniform(0, 4000, size)) / 4).astype(np.float32)  # many ties per bin
    yield "negative and zero", np.concatenate([rng.normal(0, 1, size), np.zeros(5000)])
    yield "peaked and tied float32", np.round(rng.lognormal(2.5, 0.3, size), 1).astype(np.float32)  # as a sweep's IR


@pytest.mark.numeric
@pytest.mark.parametrize("seed", [0, 1])
def test_quantiles_and_medians_are_numpys_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    q = np.concatenate([np.linspace(0, 1, 7), rng.uniform(0, 1, 5), [0.5, 1 - 1e-12, 1e-12]])
    selected = 0
    for name, x in _arrays(rng):
        got, want = quantiles(x, q), np.quantile(x, q)
        assert got.dtype == want.dtype and np.array_equal(got, want), name
        got_m, want_m = median(x), float(np.median(x))
        assert got_m == want_m or (np.isnan(got_m) and np.isnan(want_m)), name
        selected += _order_statistics(x, np.array([0, len(x) // 2, len(x) - 1])) is not None
    assert selected >= 6  # the histogram selection did the work, not numpy's partition


@pytest.mark.numeric
def test_edge_cases_take_numpys_answer():
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 1, SMALL + 10)
    x[17] = np.nan
    assert _order_statistics(x, np.array([3])) is None  # NaN: numpy's answer, NaN
    assert np.isnan(median(x)) and np.all(np.isnan(quantiles(x, [0.2, 0.8])))
    flat = np.full(SMALL + 3, 2.5, np.float32)
    assert median(flat) == 2.5 and np.array_equal(quantiles(flat, [0, 0.3, 1]), np.quantile(flat, [0, 0.3, 1]))
    small = rng.uniform(0, 1, 101)
    assert median(small) == float(np.median(small))
    with pytest.warns(RuntimeWarning, match="empty"), np.errstate(invalid="ignore"):
        assert np.isnan(median(np.array([])))  # as numpy: NaN, with its warning
    ties = np.repeat(np.arange(3.0), [SMALL, 3 * SMALL, SMALL])  # the wanted bin holds 3/5 of the values: to numpy
    assert _order_statistics(ties, np.array([2 * SMALL])) is None and median(ties) == 1.0
