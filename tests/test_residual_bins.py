"""The residuals' bins: each pixel's label in every family, made in one compiled pass (`_Layout.families`), is the
one numpy's own digitize, round-half-to-even and float32 arithmetic give, edges, ties and missing brightness
included.

The incidence angle is the one covariate made by a function outside IEEE 754's correctly rounded operations: the
compiled pass calls the C library's acos, numpy its own arccos (a SIMD loop on some processors). Each is held to
1 ulp of the true value (numpy's umath accuracy tests; glibc's libm-test-ulps), so the two angles may differ in
the last bits on one machine and agree on the next; they are compared within `ANGLE_ULPS`, and an angle put on
an edge is one both implementations give exactly."""

import dataclasses

import numpy as np
import pytest

from rig.diagnosis.bins import RADIUS_EDGES
from rig.diagnosis.family_sums import POSITION_TILES
from rig.diagnosis.residuals import _Layout
from rig.models import ModelData

#: the compiled incidence angle against numpy's, in units in the last place of the angle (deg): each arccos within
#: 1 ulp of the true angle (2 between them), and each implementation's product by 180/pi rounded once (half an ulp
#: each), so at most 3
ANGLE_ULPS = 3


def _data(rng, rows=20_000):
    u = rng.integers(0, 848, rows).astype(np.float32)
    v = rng.integers(0, 480, rows).astype(np.float32)
    z = rng.uniform(0.4, 3.2, rows)
    z[:200] = 0.125 * rng.integers(3, 25, 200)  # halfway between two 0.25 m windows: numpy rounds half to even
    rho2 = rng.uniform(0.0, 1.3, rows)
    ir = rng.lognormal(3.0, 1.0, rows)
    ir[rng.random(rows) < 0.05] = np.nan  # brightness left out (saturated nearby)
    cos = rng.uniform(0.6, 1.0, rows)
    cos[:50] = 1.0
    d = ModelData(z_m=z, m2_m2=np.full(rows, 1e-6), m4_m4=np.full(rows, 3e-12), n=np.full(rows, 30.0),
                  stop=np.zeros(rows, np.int32), u_px=u, v_px=v, rho2=rho2, ir=ir, cos_inc=cos)
    return d


def _expected(layout, d):
    """The labels by numpy alone, as the bins are defined (`rig.diagnosis.residuals`)."""
    rho = np.sqrt(d.rho2)
    r_bin = np.round(d.z_m / 0.25).astype(np.int64)
    nx, ny = POSITION_TILES
    tx = np.clip((d.u_px / np.float32(layout.tiles[0]) * np.float32(nx)).astype(np.int64), 0, nx - 1)
    ty = np.clip((d.v_px / np.float32(layout.tiles[1]) * np.float32(ny)).astype(np.int64), 0, ny - 1)
    ok = np.isfinite(d.ir)
    angle = np.degrees(np.arccos(np.clip(d.cos_inc, -1, 1)))
    return {"range": (r_bin, d.z_m), "radius": (np.digitize(rho, layout.rho_edges[1:-1]), rho),
            "range_radius": (r_bin * 10 + np.digitize(rho, RADIUS_EDGES[1:-1]), d.z_m),
            "position": (ty * nx + tx, (ty * nx + tx).astype(float)),
            "brightness": (np.where(ok, np.clip(np.digitize(np.nan_to_num(d.ir), layout.ir_edges[1:-1]), 0, 5), -1),
                           np.where(ok, d.ir, 0.0)),
            "incidence": (np.digitize(angle, layout.angle_edges[1:-1]), angle)}


@pytest.mark.numeric
def test_every_familys_labels_and_covariate_are_numpys():
    d = _data(np.random.default_rng(7))
    layout = _Layout.of(d)
    got = layout.families(d)
    assert got.names == ["range", "radius", "range_radius", "position", "brightness", "incidence"]
    for name, (labels, covariate) in _expected(layout, d).items():
        g_labels, g_cov = got[name]
        if name == "incidence":  # a label may differ only for an angle within ANGLE_ULPS of an edge
            angle, edges = covariate, layout.angle_edges[1:-1]
            near = np.abs(angle[:, None] - edges).min(axis=1) <= ANGLE_ULPS * np.spacing(edges.max())
            np.testing.assert_array_equal(g_labels[~near], labels[~near], err_msg=name)
            np.testing.assert_array_max_ulp(g_cov, covariate, maxulp=ANGLE_ULPS)
            labels = g_labels  # the extremes below: the compiled pass's own
        else:
            np.testing.assert_array_equal(g_labels, labels, err_msg=name)
            np.testing.assert_array_equal(g_cov[labels >= 0], covariate[labels >= 0], err_msg=name)
        used = labels[labels >= 0]
        i = got.names.index(name)
        assert got.lo[i] == used.min() and got.size[i] == used.max() - used.min() + 1, name


@pytest.mark.numeric
def test_values_on_the_edges_fall_where_numpy_puts_them():
    d = _data(np.random.default_rng(11))
    layout = _Layout.of(d)
    # move pixels onto the edges themselves: digitize puts a value equal to an edge in the bin above it
    d.rho2[:4] = layout.rho_edges[1:-1] ** 2
    d.ir[5:10] = layout.ir_edges[1:-1]
    layout = _edges_both_compute(layout, d, rows=slice(10, 14))
    got, expected = layout.families(d), _expected(layout, d)
    assert (got["incidence"][1][10:14] == layout.angle_edges[1:-1]).all()  # on the edges themselves
    for name in ("radius", "brightness", "incidence", "range_radius"):
        np.testing.assert_array_equal(got[name][0], expected[name][0], err_msg=name)


def _edges_both_compute(layout, d, rows, tries=64):
    """`layout` with its inner incidence edges moved to angles the compiled pass and numpy compute alike, and `rows`
    of `d` given the cosines of those angles: near each edge, the cosine of the edge and its neighbours a few ulps
    away are tried, and the first whose two angles are equal becomes the edge (about 9 in 10 are, on any machine)."""
    edges = layout.angle_edges[1:-1]
    start = np.cos(np.radians(edges))
    candidates = [start]
    for _ in range(tries - 1):
        candidates.append(np.nextafter(candidates[-1], 2.0))
    cos = np.stack(candidates)  # try t, edge e
    trial = d.select(np.arange(cos.size) % len(d))
    trial.cos_inc[:] = cos.ravel()
    compiled = layout.families(trial)["incidence"][1].reshape(cos.shape)
    agree = compiled == np.degrees(np.arccos(cos))
    assert agree.any(axis=0).all(), f"no cosine among {tries} near an edge gives one angle both ways"
    first = agree.argmax(axis=0)
    picked = cos[first, np.arange(edges.size)]
    d.cos_inc[rows] = picked
    inner = compiled[first, np.arange(edges.size)]
    assert (np.diff(inner) > 0).all()
    return dataclasses.replace(layout, angle_edges=np.concatenate([layout.angle_edges[:1], inner, layout.angle_edges[-1:]]))


def test_a_family_without_its_covariate_is_left_out():
    rng = np.random.default_rng(3)
    d = _data(rng)
    v_px = d.v_px.copy()
    v_px[0] = np.nan  # a position unknown: no image tiles
    plain = ModelData(z_m=d.z_m, m2_m2=d.m2_m2, m4_m4=d.m4_m4, n=d.n, stop=d.stop, u_px=d.u_px, v_px=v_px,
                      rho2=d.rho2, ir=np.full(len(d), np.nan), cos_inc=np.full(len(d), 0.9))
    layout = _Layout.of(plain)
    assert layout.tiles is None and layout.ir_edges is None and layout.angle_edges is None
    got = layout.families(plain)
    assert got.names == ["range", "radius", "range_radius"]
    np.testing.assert_array_equal(got["range"][0], np.round(d.z_m / 0.25).astype(np.int64))


@pytest.mark.numeric
def test_a_bins_sums_are_the_pooled_quantities_by_their_definitions():
    """compare_bins's sums per group, against numpy's own sums of each quantity as `pixel_columns` defines it:
    pixels, degrees of freedom, M2, nu x predicted variance, and the kurtosis pooling sums of the usable pixels."""
    from rig.diagnosis.bins import BinSums
    from rig.models.parts.prediction import Prediction

    rng = np.random.default_rng(5)
    d = _data(rng)
    n = len(d)
    d.n[:] = rng.integers(20, 40, n)
    var = rng.uniform(0.5e-6, 2e-6, n)
    d.m2_m2[:] = var * (d.n - 1) * rng.gamma(50, 1 / 50, n)
    d.m4_m4[:] = 3 * var**2 * d.n * rng.gamma(20, 1 / 20, n)
    pred = Prediction(var, np.ones(n), np.zeros(n), var_m2=var, k4_m4=0.1 * var**2, frame_mean_gain=1.4)
    groups = rng.integers(-1, 7, n)
    groups.sort()  # runs of one bin, as pixels come
    covariate = d.ir  # NaN in some rows: 0 in the covariate's sum
    sums = BinSums()
    sums.add(d, pred, groups, covariate)

    nu, usable = d.n - 1, d.kurtosis_usable
    assert usable.any()
    w = np.where(usable, d.n, 0.0)
    b = np.where(usable, d.pixel_kurtosis, 0.0)
    shared = 1 + (1.4 - 1) / 2
    weight = nu * var
    expected = {"pixels": np.ones(n), "nu": nu, "m2": d.m2_m2, "weight": weight, "n_excess": w * 0.1,
                "w2_nu": weight**2 * shared * 2 / nu, "w2_n": weight**2 * shared / d.n, "k_count": usable * 1.0,
                "k_wb": w * b, "k_w2b2": (w * b) ** 2}
    from rig.diagnosis.bins import COLUMNS

    for g in range(7):
        rows = groups == g
        got = sums.sums[g]
        for name, col in expected.items():
            np.testing.assert_allclose(got[COLUMNS.index(name)], col[rows].sum(), rtol=1e-12, err_msg=name)
        np.testing.assert_allclose(got[-1], (nu * np.nan_to_num(covariate))[rows].sum(), rtol=1e-12)
    assert -1 not in sums.sums


@pytest.mark.numeric
@pytest.mark.parametrize("per_row", [False, True])
def test_stop_sums_are_numpys_sums_of_each_quantity(per_row):
    """`StopSums.add` (one compiled pass) against numpy's sums of each quantity by its definition, stop by stop,
    with the prediction's common wander, gain and fill given once for all rows or one a row."""
    from rig.diagnosis.stop_sums import StopSums
    from rig.models import Prediction

    rng = np.random.default_rng(21)
    rows = 5_000
    stop = np.sort(rng.choice([0, 2, 3, 7], rows)).astype(np.int32)  # stop 1 and 4-6 absent: no row for them
    n = rng.integers(1, 40, rows).astype(float)
    fill = rng.uniform(0.0, 1.0, rows)
    fill[:20] = 0.0  # no valid frame: frames from the floor 1e-12
    z = rng.uniform(0.5, 3.0, rows)
    d = ModelData(z_m=z, m2_m2=np.full(rows, 1e-6), m4_m4=np.full(rows, 3e-12), n=n, stop=stop, fill=fill)
    var = rng.uniform(1e-7, 1e-5, rows)
    common, gain, fill_p = ((rng.uniform(0, 1e-6, rows), rng.uniform(1, 2, rows), rng.uniform(0.5, 1, rows)) if per_row
                            else (3e-7, 1.4, None))
    pred = Prediction(var, np.ones(rows), np.zeros(rows), var_m2=var, fill=fill_p, common_inv2=common,
                      frame_mean_gain=gain)
    sums = StopSums()
    half = rows // 2  # in two chunks: the second adds to the first's stops
    for part in (slice(0, half), slice(half, rows)):
        c = d.select(np.arange(rows)[part])
        sums.add(c, Prediction(var[part], np.ones(len(c)), np.zeros(len(c)), var_m2=var[part],
                               fill=None if fill_p is None else fill_p[part],
                               common_inv2=common if np.ndim(common) == 0 else common[part],
                               frame_mean_gain=gain if np.ndim(gain) == 0 else gain[part]))
    assert sorted(sums.rows) == [0, 2, 3, 7]
    fp = np.broadcast_to(1.0 if fill_p is None else fill_p, rows)
    cm, g = np.broadcast_to(common, rows), np.broadcast_to(gain, rows)
    frames = n / np.maximum(fill, 1e-12)
    w = np.maximum(n - 1, 0)
    for s in sums.rows:
        m = stop == s
        want = [m.sum(), fill[m].sum(), (fill * (1 - fill) / frames)[m].sum(), frames[m].sum(), fp[m].sum(), z[m].sum(),
                ((var - cm * z**4) / z**4 * g)[m].sum(), cm[m].sum(), (w * cm * z**4)[m].sum(), (w * var)[m].sum(),
                (fp * (1 - fp) / frames)[m].sum()]
        np.testing.assert_allclose(sums.rows[s], want, rtol=1e-12, atol=1e-300)
