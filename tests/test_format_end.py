"""The range's moments near the depth format's end (rig.models.effects.file_physics): the series `_series` against scipy's
adaptive quadrature of the same integral (a generator that shares no formula with either of rig's two methods),
its derivatives against its own differences, and `_transform` taking it where it should."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate
from scipy.stats import norm

from rig.models.effects.file_physics import NEAR_LIMIT_SIGMA, SERIES_MAX_R, _series, _transform, _NODES, _WEIGHTS

FB = 30.0  # f b, px m
Z_MAX = 65535 * 5e-5  # the deepest range a 0.05 mm depth unit holds, m


def _row(r: float, a: float) -> tuple[float, float]:
    """(z, v): the range and range variance of a pixel whose relative disparity error is r and whose disparity
    error reaches the format's end at a standard deviations (a = (z / z_max - 1) / r)."""
    z = Z_MAX * (1 + a * r)
    return z, (r * z) ** 2


def _by_scipy(z: float, v: float) -> tuple[float, float, float]:
    """(variance, fourth cumulant, fill) of Z = f b / (f b / z + sigma_d x), x ~ N(0, 1) kept where Z <= z_max."""
    sigma_d = math.sqrt(v) * FB / z**2
    a = (FB / Z_MAX - FB / z) / sigma_d

    def moment(g):
        return integrate.quad(lambda x: g(FB / (FB / z + sigma_d * x)) * norm.pdf(x), a, 12.0, epsabs=0, epsrel=1e-13,
                              limit=200)[0]

    kept = moment(lambda _: 1.0)
    mean = moment(lambda y: y) / kept
    m2 = moment(lambda y: (y - mean) ** 2) / kept
    m4 = moment(lambda y: (y - mean) ** 4) / kept
    return m2, m4 - 3 * m2**2, kept


@pytest.mark.numeric
@pytest.mark.parametrize("r", [0.005, 0.02, SERIES_MAX_R])
@pytest.mark.parametrize("a", [-NEAR_LIMIT_SIGMA, -4.0, -2.0, -1.0])
def test_the_series_gives_the_moments_an_independent_quadrature_gives(r, a):
    """Two approximations of the same integrals: what separates them is the series' truncation and the quadrature's
    requested accuracy (epsrel 1e-13), far above the rounding of either (a few ulps; 2e-15 of the variance seen).
    The variance: the series' terms beyond SERIES_TERMS are below 1e-12 of it (rig.models.effects.file_physics), the
    quadrature's within 1e-13, so 1.1e-12 (abs=0: pytest.approx's own 1e-12 would be 4e-9 of a 2.5e-4 m^2 variance).
    The kept share: erfc in closed form (within 2 ulps) against the quadrature's 1e-13. The cumulant, a difference of
    moments, is judged against var^2, with room for a truncation the module does not state (2.1e-12 var^2 seen at
    the series' widest r and its cut nearest the bulk)."""
    z, v = _row(r, a)
    var, k4, fill = _series(z, v, FB, Z_MAX, np.empty(9))[:3]
    ref_var, ref_k4, ref_fill = _by_scipy(z, v)
    assert var == pytest.approx(ref_var, rel=1.1e-12, abs=0)
    assert abs(k4 - ref_k4) < 1e-8 * ref_var**2  # the cumulant is a difference of moments: judged against var^2
    assert fill == pytest.approx(ref_fill, rel=1e-13 + 4 * np.finfo(np.float64).eps, abs=0)


@pytest.mark.parametrize("r,a", [(0.01, -5.0), (0.03, -3.0), (SERIES_MAX_R, -1.0)])
def test_the_series_derivatives_are_its_own_slopes(r, a):
    z, v = _row(r, a)
    out = _series(z, v, FB, Z_MAX, np.empty(9)).copy()
    h = 1e-4 * v
    up, down = _series(z, v + h, FB, Z_MAX, np.empty(9)).copy(), _series(z, v - h, FB, Z_MAX, np.empty(9)).copy()
    up2, down2 = _series(z, v + 2 * h, FB, Z_MAX, np.empty(9)).copy(), _series(z, v - 2 * h, FB, Z_MAX, np.empty(9)).copy()
    slope = (8 * (up - down) - (up2 - down2)) / (12 * h)
    for value in range(3):
        assert out[3 + value] == pytest.approx(slope[value], rel=1e-6, abs=1e-9 * abs(out[value] / v)), value


def test_uncensored_rows_near_the_end_take_the_series_and_keep_their_own_cumulant():
    rows = [_row(r, a) for r, a in [(0.02, -5.0), (0.04, -1.5), (0.2, -3.0), (0.02, -0.5), (0.02, -8.0)]]
    z0 = np.array([z for z, _ in rows])
    var = np.array([v for _, v in rows])
    k4_in = np.full(len(rows), 1e-12)
    var_out, k4_out, fill = np.empty(len(rows)), np.empty(len(rows)), np.empty(len(rows))
    partials = np.empty((9, len(rows)))
    assert _transform(var, var.copy(), k4_in, True, np.zeros(1), False, z0, FB, Z_MAX, NEAR_LIMIT_SIGMA, _NODES,
                      _WEIGHTS, var_out, k4_out, fill, True, partials)
    for i in (0, 1):  # a <= -1, r <= 0.05: the series, with the cumulant the row came with added
        s = _series(z0[i], var[i], FB, Z_MAX, np.empty(9))
        assert (var_out[i], k4_out[i], fill[i]) == (s[0], s[1] + k4_in[i], s[2])
        assert partials[1, i] == s[3] and partials[8, i] == 1.0
    for i in (2, 3):  # r = 0.2, or a cut inside the bulk: the quadrature, which drops the incoming cumulant
        assert partials[8, i] == 0.0 and fill[i] < 1.0
    assert fill[4] == 1.0 and partials[8, 4] == 1.0  # 8 standard deviations away: the closed form
