"""Each pixel's neighbours' variance (`ModelData.neighbour_variance`, a compiled pass over each stop's image) and the
true range made from it (`ModelData.z0_m`), against sums written out pixel by pixel and against scipy's own box
filter, for whole images, images with holes, and rows in no order."""

import numpy as np
import pytest
from scipy.ndimage import uniform_filter

from rig.models import ModelData
from rig.models.shape_statistics import KURTOSIS_WINDOW_PX


def _by_hand(d: ModelData) -> tuple[np.ndarray, np.ndarray]:
    """Sum M2 / sum nu over the other rows of the same stop within the square, by brute force."""
    half = KURTOSIS_WINDOW_PX // 2
    var, dof = np.full(len(d), np.nan), np.full(len(d), np.nan)
    for i in range(len(d)):
        near = (d.stop == d.stop[i]) & (np.abs(d.u_px - d.u_px[i]) <= half) & (np.abs(d.v_px - d.v_px[i]) <= half)
        near[i] = False
        nu = (d.n[near] - 1).sum()
        if nu > 4:
            var[i], dof[i] = d.m2_m2[near].sum() / nu, nu
    return var, dof


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


@pytest.mark.parametrize("holes, shuffle", [(0.0, False), (0.3, False), (0.97, False), (0.3, True)])
def test_the_neighbours_variance_is_the_sums_written_out(holes, shuffle):
    d = _stops(np.random.default_rng(11), holes=holes, shuffle=shuffle)
    var, dof = d.neighbour_variance
    want_var, want_dof = _by_hand(d)
    assert np.array_equal(np.isnan(var), np.isnan(want_var)) and np.array_equal(dof, want_dof, equal_nan=True)
    assert np.isfinite(var).any()
    np.testing.assert_allclose(var, want_var, rtol=1e-13)
    if holes > 0.9:  # most pixels of the holed stops have too few neighbours: NaN
        assert np.isnan(var[d.stop > 0]).mean() > 0.5


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
    assert np.array_equal(dof, nu_sum.ravel())
    np.testing.assert_allclose(var, (m2_sum / nu_sum).ravel(), rtol=1e-12)


def test_the_true_range_is_the_formula_with_the_stops_pooled_variance_where_the_neighbours_have_none():
    d = _stops(np.random.default_rng(8), holes=0.9, shuffle=True)
    var, _ = d.neighbour_variance
    assert np.isnan(var).any() and np.isfinite(var).any()
    pooled = {s: d.m2_m2[d.stop == s].sum() / (d.n[d.stop == s] - 1).sum() for s in range(3)}
    v = np.where(np.isfinite(var), var, [pooled[s] for s in d.stop])
    np.testing.assert_allclose(d.z0_m, d.z_m / (1 + v / d.z_m**2), rtol=1e-15)
    assert np.all(d.z0_m < d.z_m)  # the mean of 1/disparity's samples sits above the true range


def test_the_pixel_kurtosis_is_the_formula_in_numpy_to_the_last_bit():
    """`pixel_kurtosis` (compiled) against the unbiased estimator written with numpy arrays, edge values included:
    no neighbours (nu = 0), a variance of 0, one sample, NaN and infinite M4 give what numpy gives."""
    d = _stops(np.random.default_rng(13), holes=0.5)
    d.m4_m4 = d.m2_m2**2 / np.maximum(d.n - 1, 1) * np.random.default_rng(14).uniform(1, 5, len(d))
    v, nu_v = (a.copy() for a in d.neighbour_variance)
    v[:3], nu_v[3:6], d.n[6:8], d.m4_m4[8], d.m4_m4[9] = 0.0, 0.0, 1.0, np.inf, np.nan
    d.__dict__["neighbour_variance"] = (v, nu_v)
    n = d.n
    with np.errstate(all="ignore"):
        m4_over_sigma4 = d.m4_m4 / v**2 * (nu_v - 2) * (nu_v - 4) / nu_v**2
        want = (m4_over_sigma4 * n**2 / (n - 1) - 3 * (2 * n - 3)) / (n**2 - 3 * n + 3)
        got = d.pixel_kurtosis
    assert np.isfinite(want).sum() > len(d) / 3 and not np.isfinite(want[:10]).any()
    assert np.array_equal(got, want, equal_nan=True)
