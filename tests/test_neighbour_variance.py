"""Each pixel's neighbours' variance (`ModelData.neighbour_variance`, a compiled pass over each stop's image) and the
true range made from it (`ModelData.z0_m`), against sums written out pixel by pixel and against scipy's own box
filter, for whole images, images with holes, and rows in no order.

Sums of degrees of freedom are sums of whole numbers: exact, both ways. Sums of M2 are two implementations adding
the same positive terms in other orders: each is held to the bound its operations give (u = eps / 2 per rounding),
not to the last bit."""

import numpy as np
import pytest
from scipy.ndimage import uniform_filter, uniform_filter1d

from rig.models import ModelData
from rig.models.data.shape_statistics import KURTOSIS_WINDOW_PX

EPS = np.finfo(np.float64).eps
U = EPS / 2
#: the compiled pass sums the square's columns (KURTOSIS_WINDOW_PX terms), then the columns' sums along the row: each
#: M2 goes through at most 2 (KURTOSIS_WINDOW_PX - 1) roundings on its way into the square's sum S
SQUARE_ROUNDINGS = 2 * (KURTOSIS_WINDOW_PX - 1)


def _compiled_error(total: np.ndarray, own: np.ndarray) -> np.ndarray:
    """The compiled pass's relative error bound, in u: S within SQUARE_ROUNDINGS u of its exact value (all terms
    positive), less the pixel's own M2 (one rounding; the difference is S / (S - own) times as uncertain as S), over
    the degrees of freedom (one rounding)."""
    return SQUARE_ROUNDINGS * total / (total - own) + 2


def _running_mean_error(x: np.ndarray, axis: int) -> np.ndarray:
    """How far scipy's uniform_filter1d of x >= 0 (KURTOSIS_WINDOW_PX = s values, zeros beyond the image) may be from
    the exact means, in absolute terms: it sums the first window (s - 1 roundings), then keeps a running sum along the
    line, tmp += entering - leaving, rounding the difference and the sum at each step, and divides by s. So the
    error at step k is u (s - 1) |first sum| + u sum over steps j <= k of (|entering - leaving| + |tmp_j|), over s,
    plus the division's u |mean|."""
    s = KURTOSIS_WINDOW_PX
    before = s // 2
    x = np.moveaxis(x, axis, 0)
    padded = np.concatenate([np.zeros((before, *x.shape[1:])), x, np.zeros((s - before - 1, *x.shape[1:]))])
    sums = np.cumsum(padded, axis=0)
    window = sums[s - 1:] - np.concatenate([np.zeros((1, *x.shape[1:])), sums[:-s]])  # each step's running sum
    steps = np.abs(padded[s:] - padded[:-s]) + window[1:]
    error = U * ((s - 1) * window[:1] + np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(steps, axis=0)]))
    return np.moveaxis(error / s + U * window / s, 0, axis)


def _by_hand(d: ModelData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sum M2 / sum nu over the other rows of the same stop within the square, by brute force; and the bound, in u, of
    how far the compiled pass may be from it (`_compiled_error`, and numpy's sum of the k others: k - 1 roundings,
    then the quotient's one)."""
    half = KURTOSIS_WINDOW_PX // 2
    var, dof, bound = np.full(len(d), np.nan), np.full(len(d), np.nan), np.full(len(d), np.nan)
    for i in range(len(d)):
        near = (d.stop == d.stop[i]) & (np.abs(d.u_px - d.u_px[i]) <= half) & (np.abs(d.v_px - d.v_px[i]) <= half)
        near[i] = False
        nu = (d.n[near] - 1).sum()
        if nu > 4:
            others = d.m2_m2[near].sum()
            var[i], dof[i] = others / nu, nu
            bound[i] = _compiled_error(others + d.m2_m2[i], d.m2_m2[i]) + near.sum()
    return var, dof, bound


def _stops(rng, h=19, w=27, holes=0.0, shuffle=False):
    v, u = np.divmod(np.arange(h * w), w)
    parts = []
    for s in range(3):
        keep = rng.random(h * w) >= (holes if s else 0.0)  # stop 0 whole, the others with holes
        k = int(keep.sum())
        parts.append((u[keep], v[keep], np.full(k, s), rng.uniform(0.5, 3.0, k), rng.gamma(4.0, 2e-7, k),
                      rng.integers(2, 40, k).astype(float)))
    u, v, stop, z, m2, n = (np.concatenate(c) for c in zip(*parts))
    order = rng.permutation(len(z)) if shuffle else np.arange(len(z))
    return ModelData(z_m=z[order], m2_m2=m2[order], m4_m4=3 * m2[order] ** 2, n=n[order], stop=stop[order].astype(np.int32),
                     u_px=u[order].astype(np.float32), v_px=v[order].astype(np.float32))


@pytest.mark.numeric
@pytest.mark.parametrize("holes, shuffle", [(0.0, False), (0.3, False), (0.97, False), (0.3, True)])
def test_the_neighbours_variance_is_the_sums_written_out(holes, shuffle):
    d = _stops(np.random.default_rng(11), holes=holes, shuffle=shuffle)
    var, dof = d.neighbour_variance
    want_var, want_dof, bound = _by_hand(d)
    assert np.array_equal(np.isnan(var), np.isnan(want_var)) and np.array_equal(dof, want_dof, equal_nan=True)
    ok = np.isfinite(var)
    assert ok.any()
    # each within its own bound (about 60 u, 7e-15, for a pixel with 48 neighbours)
    gap = np.abs(var - want_var)[ok] / want_var[ok]
    assert np.all(gap <= bound[ok] * U), np.max(gap / U / bound[ok])
    if holes > 0.9:  # most pixels of the holed stops have too few neighbours: NaN
        assert np.isnan(var[d.stop > 0]).mean() > 0.5


@pytest.mark.numeric
def test_the_neighbours_variance_agrees_with_scipys_box_filter_on_a_camera_image():
    rng = np.random.default_rng(3)
    h, w = 480, 848
    m2 = rng.gamma(3.0, 1e-7, (h, w)) * np.linspace(1, 4, w)  # a variance growing across the image
    n = rng.integers(250, 301, (h, w)).astype(float)
    v, u = np.divmod(np.arange(h * w), w)
    d = ModelData(z_m=rng.uniform(0.5, 3.0, h * w), m2_m2=m2.ravel(), m4_m4=m2.ravel(), n=n.ravel(),
                  stop=np.zeros(h * w, np.int32), u_px=u.astype(np.float32), v_px=v.astype(np.float32))
    size = KURTOSIS_WINDOW_PX**2
    m2_sum = uniform_filter(m2, KURTOSIS_WINDOW_PX, mode="constant") * size - m2
    nu_sum = np.round(uniform_filter(n - 1, KURTOSIS_WINDOW_PX, mode="constant") * size - (n - 1))
    var, dof = d.neighbour_variance
    assert np.array_equal(dof, nu_sum.ravel())  # sums of whole numbers (scipy's rounded back to them): exact
    # scipy's filter is two passes of `_running_mean_error`'s running sum; its mean times size, less the pixel's own
    # M2 and over nu, each one rounding more; the compiled pass: `_compiled_error`. 2.3e-13 at most here, against the
    # 26 eps (6e-15) seen on this machine
    first = uniform_filter1d(m2, KURTOSIS_WINDOW_PX, axis=0, mode="constant")
    mean_error = (uniform_filter1d(_running_mean_error(m2, 0), KURTOSIS_WINDOW_PX, axis=1, mode="constant")
                  + _running_mean_error(first, 1))
    total = m2_sum + m2
    bound = (size * mean_error + U * total + U * m2_sum) / m2_sum + U + U * _compiled_error(total, m2)
    want = m2_sum / nu_sum
    assert np.all(np.abs(var - want.ravel()) <= (bound * want).ravel()), np.max(np.abs(var / want.ravel() - 1) / U)


@pytest.mark.numeric
def test_the_true_range_is_the_formula_with_the_stops_pooled_variance_where_the_neighbours_have_none():
    d = _stops(np.random.default_rng(8), holes=0.9, shuffle=True)
    var, _ = d.neighbour_variance
    assert np.isnan(var).any() and np.isfinite(var).any()
    pooled = {s: d.m2_m2[d.stop == s].sum() / (d.n[d.stop == s] - 1).sum() for s in range(3)}
    v = np.where(np.isfinite(var), var, [pooled[s] for s in d.stop])
    # Z / (1 + t), t = v / Z^2, by the same four roundings both ways: each within 2 u + 3 u t of the exact value, two
    # within 2 eps + 3 eps t. The pooled variance is numpy's pairwise sum here and a sum in row order there, within
    # k eps of each other for a stop's k rows, which moves Z0 by t times that
    t = v / d.z_m**2
    k = np.bincount(d.stop).max()
    np.testing.assert_allclose(d.z0_m, d.z_m / (1 + t), rtol=(2 + t.max() * (3 + k)) * EPS)
    assert np.all(d.z0_m < d.z_m)  # the mean of 1/disparity's samples sits above the true range


@pytest.mark.numeric
def test_the_pixel_kurtosis_is_the_formula_in_numpy():
    """`pixel_kurtosis` (compiled) against the unbiased estimator written with numpy arrays, edge values included:
    no neighbours (nu = 0), a variance of 0, one sample, NaN and infinite M4 give what numpy gives. Not finite where
    numpy's is not (exact conditions: a zero, a NaN); elsewhere within the two implementations' rounding."""
    d = _stops(np.random.default_rng(13), holes=0.5)
    d.m4_m4 = d.m2_m2**2 / np.maximum(d.n - 1, 1) * np.random.default_rng(14).uniform(1, 5, len(d))
    v, nu_v = (a.copy() for a in d.neighbour_variance)
    v[:3], nu_v[3:6], d.n[6:8], d.m4_m4[8], d.m4_m4[9] = 0.0, 0.0, 1.0, np.inf, np.nan
    d.__dict__["neighbour_variance"] = d.__dict__["kurtosis_variance"] = (v, nu_v)
    n = d.n
    with np.errstate(all="ignore"):
        m4_over_sigma4 = d.m4_m4 / v**2 * (nu_v - 2) * (nu_v - 4) / nu_v**2
        first = m4_over_sigma4 * n**2 / (n - 1)
        want = (first - 3 * (2 * n - 3)) / (n**2 - 3 * n + 3)
        got = d.pixel_kurtosis
    assert np.isfinite(want).sum() > len(d) / 3 and not np.isfinite(want[:10]).any()
    finite = np.isfinite(want)
    assert np.array_equal(np.isfinite(got), finite) and np.array_equal(got[~finite], want[~finite], equal_nan=True)
    # the first term T = M4 / v^2 (nu - 2)(nu - 4) / nu^2 n^2 / (n - 1) takes 7 roundings (the differences and squares
    # of whole numbers are exact), T - 3 (2 n - 3) one more, the quotient by a whole number one: each implementation
    # within 7 u |T| / |T - 3 (2 n - 3)| + 2 u of the exact value, two of them within twice that
    with np.errstate(all="ignore"):
        rtol = (7 * np.abs(first) / np.abs(first - 3 * (2 * n - 3)) + 2) * EPS
    assert np.all(np.abs(got[finite] - want[finite]) <= rtol[finite] * np.abs(want[finite]))


@pytest.mark.numeric
@pytest.mark.parametrize("projector_on, power", [(True, 6.0), (False, 4.0)])
def test_a_tilted_stops_kurtosis_variance_is_the_range_scaled_sums_written_out(projector_on, power):
    """On a stop spanning a range (a tilted wall, Z = 0.8 / (1 + 0.6 x)), each neighbour's M2 is scaled to the
    pixel's range by (Z_i / Z_j)^(2 lambda0) before pooling; a perpendicular stop (the second) keeps the plain
    neighbours' variance. Each term is one pow (a few ulps in numba's libm and numpy's) and one product, then a sum of
    k positive terms: within (k + 8) eps of each other."""
    rng = np.random.default_rng(4)
    h, w = 11, 17
    v, u = np.divmod(np.arange(h * w), w)
    tilted = 0.8 / (1 + 0.6 * (u - 8) / 9.0)
    z = np.concatenate([tilted, np.full(h * w, 1.2) + rng.normal(0, 1e-5, h * w)])
    m2 = rng.gamma(4.0, 2e-7, 2 * h * w) * (z / 0.8) ** power
    n = rng.integers(20, 40, 2 * h * w).astype(float)
    stop = np.repeat(np.arange(2, dtype=np.int32), h * w)
    d = ModelData(z_m=z, m2_m2=m2, m4_m4=3 * m2**2, n=n, stop=stop, u_px=np.tile(u, 2).astype(np.float32),
                  v_px=np.tile(v, 2).astype(np.float32), projector_on=np.full(2 * h * w, projector_on))
    var, dof = d.kurtosis_variance
    plain, plain_dof = d.neighbour_variance
    half = KURTOSIS_WINDOW_PX // 2
    for i in range(h * w):  # the tilted stop, by hand
        near = (np.abs(u - u[i]) <= half) & (np.abs(v - v[i]) <= half)
        near[i] = False
        terms = m2[:h * w][near] * (z[i] / z[:h * w][near]) ** power
        assert dof[i] == (n[:h * w][near] - 1).sum()
        want = terms.sum() / dof[i]
        assert abs(var[i] - want) <= (near.sum() + 8) * EPS * want, (i, var[i], want)
    assert np.array_equal(var[h * w:], plain[h * w:]) and np.array_equal(dof[h * w:], plain_dof[h * w:])
    # the scaling takes the range's gradient out: the far edge's variance is not the neighbours' nearer one
    edge = u == 0
    assert np.all(var[:h * w][edge] > plain[:h * w][edge])
