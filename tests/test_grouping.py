"""Grouped fits (rig.models.fitting.grouping) against fits on every pixel: the same parameters within 0.1 standard error.

The recordings are made by the real runner from the fake camera, at 424x240 (tiles of 10x10 pixels, each
replaced by 7 nodes) and 318x180 (7x7): a wall tilted 35 degrees, where range changes across every tile, a
perpendicular sweep with mismatches, and one with a 1 mm depth unit, where rounding matters. Models whose parameters the data determine (every parameter inside its bounds, with
a finite standard error) are compared parameter by parameter, in units of the ungrouped fit's own standard
error; the log-likelihood each reports is the one of every pixel, so they agree to far less than one unit.
"""

from __future__ import annotations

import numpy as np
import pytest

from protocols import Runner, perpendicular, tilted
from rig.devices import open_devices
from rig.models import ModelData, parse_model
from rig.models.fitting.grouping import GroupedData, group, tile_size, whole_stops
from rig.models.fitting.optimise import _standard_errors, fit_data

pytestmark = pytest.mark.slow


CAMERA = "fake:width=424,height=240,depth_unit_mm=0.1,seed=5,effects=noise_floor(sigma_px=0.02)+slant_range"
#: the sweep's camera has mismatches too, so the outliers' parameters are determined by the data
SWEEP_CAMERA = CAMERA.replace("width=424,height=240", "width=318,height=180") + "+outliers(fraction=0.02,width_px=2.0)"


@pytest.fixture(scope="module")
def tilted_data(tmp_path_factory):
    path = tmp_path_factory.mktemp("grouping") / "tilted.h5"
    devices = open_devices(CAMERA, "fake:")
    Runner(devices.camera, devices.stage, sleep=devices.sleep).run(tilted(tilt_deg=35, distance_m=1.5, frames=60), path)
    return ModelData.from_recording(path)


@pytest.fixture(scope="module")
def sweep_data(tmp_path_factory):
    path = tmp_path_factory.mktemp("grouping") / "sweep.h5"
    devices = open_devices(SWEEP_CAMERA, "fake:")
    plan = perpendicular(stops_m=[0.75, 1.5, 3.0], frames_per_stop=30)
    Runner(devices.camera, devices.stage, sleep=devices.sleep).run(plan, path)
    return ModelData.from_recording(path)


def _agree(d: ModelData, model: str) -> None:
    """The grouped fit's parameters within 0.1 standard error of the fit on every pixel, its log-likelihood (of
    every pixel) within 0.05, and the grouped likelihood's curvature the same: at the same parameters, the
    standard errors from grouped nodes within 10 % of those from every pixel (the finite-difference Hessian of a
    model read from interpolated tables, quantization's, itself moves by 5 % with its step)."""
    m = parse_model(model)
    nodes = fit_data(m, d)
    assert isinstance(nodes, GroupedData), "the data are large enough to be grouped"
    grouped, full = m.fit(d, errors=False), m.fit(d, grouped=False)
    assert grouped.loglik == pytest.approx(full.loglik, abs=0.05)
    names = [n for n, _ in m.free()]
    same_point, _, _ = _standard_errors(m, full.values, nodes, names)
    for name, se in full.errors.items():
        assert np.isfinite(se) and se > 0, (model, name)
        assert abs(grouped.values[name] - full.values[name]) < 0.1 * se, (model, name, grouped.values[name], full.values[name], se)
        assert same_point[name] == pytest.approx(se, rel=0.10), (model, name, same_point[name], se)


@pytest.mark.parametrize("model", ["power_law", "power_law+slant_range", "active+slant_range+noise_floor"])
def test_grouped_fits_agree_with_every_pixel_on_a_tilted_wall(tilted_data, model):
    _agree(tilted_data, model)


@pytest.mark.parametrize("model", ["power_law+slant_range", "active+slant_range+noise_floor+outliers"])
def test_grouped_fits_agree_with_every_pixel_on_a_perpendicular_sweep(sweep_data, model):
    _agree(sweep_data, model)


@pytest.fixture(scope="module")
def coarse_unit_data(tmp_path_factory):
    """A 1 mm depth unit at 0.5-0.75 m: the noise is a quarter to half a unit, so each pixel's rounded variance turns
    on where its mean sits between two levels."""
    path = tmp_path_factory.mktemp("grouping") / "coarse.h5"
    devices = open_devices(CAMERA.replace("depth_unit_mm=0.1", "depth_unit_mm=1").replace("width=424,height=240", "width=318,height=180"), "fake:")
    Runner(devices.camera, devices.stage, sleep=devices.sleep).run(perpendicular(stops_m=[0.5, 0.75, 1.5], frames_per_stop=30), path)
    return ModelData.from_recording(path)


def test_grouped_fits_with_rounding_agree_with_every_pixel(coarse_unit_data):
    """Quantization: the pixels of small spread are grouped apart by their offset between depth levels."""
    g = fit_data(parse_model("active+quantization+noise_floor"), coarse_unit_data)
    assert isinstance(g, GroupedData) and g is not fit_data(parse_model("active+noise_floor"), coarse_unit_data)
    _agree(coarse_unit_data, "active+quantization+noise_floor")


@pytest.mark.numeric
def test_nodes_carry_the_weights_of_the_pixels_they_stand_for(sweep_data):
    """Per stop, the node weights sum to the pixels' (count, Gamma shapes, a s2): the quadrature is exact
    for what is constant within a tile. Exact in exact arithmetic; rounded, both sums add the same k positive
    weights (the nodes' as tile sums times quadrature weights summing to 1) in other orders: within 2 (k + 10) u,
    1.3e-11 for these 57,240 pixels a stop (5.6e-16 seen; was 1e-9)."""
    from rig.models.fitting.likelihood import likelihood_weights

    g = fit_data(parse_model("active"), sweep_data)
    a, b, kw, _ = likelihood_weights(sweep_data)
    ga, gb, gkw, gpx = g.weights
    u = np.finfo(np.float64).eps / 2
    for s in np.unique(sweep_data.stop):
        m, gm = sweep_data.stop == s, g.stop == s
        rel = 2 * (m.sum() + 10) * u
        assert gpx[gm].sum() == pytest.approx(m.sum(), rel=rel, abs=0)
        assert ga[gm].sum() == pytest.approx(a[m].sum(), rel=rel, abs=0)
        assert gb[gm].sum() == pytest.approx(b[m].sum(), rel=rel, abs=0)
        assert gkw[gm].sum() == pytest.approx(kw[m].sum(), rel=rel, abs=0)
    assert len(g) < len(sweep_data) / 3


def test_every_node_array_has_a_value_per_node(sweep_data, coarse_unit_data):
    """Plain and offset-binned nodes alike: each per-row array, the grid offset included, has one value per row."""
    for d, by_offset in ((sweep_data, False), (coarse_unit_data, True), (sweep_data, True)):
        g = group(d, tile_size(d), by_offset=by_offset)
        for name in ("z_m", "z0_m", "u_px", "v_px", "n", "stop", "grid_offset", "range_group"):
            assert len(getattr(g, name)) == len(g), (name, by_offset)
        assert all(len(w) == len(g) for w in g.weights)


@pytest.mark.numeric
def test_stops_left_out_share_the_whole_datas_nodes_and_statistics(sweep_data):
    """`rig.models.fitting.grouping.whole_stops` (the held-out score's parts): the nodes of the kept stops and the statistics carried
    over from the whole data give the same fit as measuring and grouping the kept stops afresh (within 0.1 SE), and
    the same data-only constant and fill by stop."""
    from scipy.special import gammaln

    from rig.models.fitting.likelihood import gamma_constant

    m = parse_model("active+noise_floor+outliers")
    fit_data(m, sweep_data)  # the whole data's nodes, which whole_stops hands on
    keep = sweep_data.stop != sweep_data.stop[0]
    shared, fresh = whole_stops(sweep_data, keep, statistics=False), sweep_data.select(keep)
    assert isinstance(fit_data(m, shared), GroupedData) and fit_data(m, shared).full is shared
    # the constant: the same terms, summed stop by stop in row order there and at once (pairwise) here, each within
    # (k - 1) u of the exact sum of their sizes: 2 k u sum |t| / |sum t| apart, 2.5e-11 for these 114,480 rows (7.8e-16
    # seen); 1e-12 asked less than the worst case. The measured fill per stop: means of k shares, 2 (k + 1) u
    u = np.finfo(np.float64).eps / 2
    a_ = fresh.gamma_shape
    terms = a_ * np.log(a_) - gammaln(a_) + (a_ - 1) * np.log(fresh.s2_m2)
    k = len(fresh)
    assert gamma_constant(shared) == pytest.approx(gamma_constant(fresh), rel=2 * k * u * np.abs(terms).sum()
                                                   / abs(terms.sum()), abs=0)
    assert np.array_equal(shared.fill_by_stop[0], fresh.fill_by_stop[0])  # stop indices: whole numbers
    assert np.allclose(shared.fill_by_stop[1], fresh.fill_by_stop[1], rtol=2 * (k + 1) * u, atol=0)
    a, b = m.fit(shared, errors=False), m.fit(fresh)
    for name, se in b.errors.items():
        assert abs(a.values[name] - b.values[name]) < 0.1 * se, (name, a.values[name], b.values[name], se)


def test_candidates_are_compared_on_their_own_nodes_and_the_chosen_fit_gets_every_pixels_likelihood(sweep_data):
    """On grouped data a diagnosis ranks each candidate effect by the log-likelihood of the candidate's grouped
    nodes, the model it extends evaluated on the same nodes (rig.diagnosis.candidates): the likelihood-ratio statistic
    is every pixel's within a hundredth of its own sampling spread (here 1.15 of 101,539 for outliers, 2e-5 of 8.08
    for quantization, whose nodes lie apart by grid offset); the fit chosen gets every pixel's log-likelihood back,
    the value `fit_model` reports by default."""
    from rig.diagnosis import diagnose, rank_candidates
    from rig.models import Catalogue, with_exact_loglik
    from rig.models.catalogue import EFFECTS

    names = ["noise_floor", "outliers", "quantization", "read_noise"]
    catalogue = Catalogue({n: EFFECTS[n] for n in names}, {n: "built-in" for n in names})
    model = parse_model("active")
    base = model.fit(sweep_data, errors=False)
    ranked = rank_candidates(model, base, sweep_data, catalogue)
    assert sorted(c.effect.name for c in ranked) == sorted(names)
    for c in ranked:
        assert isinstance(fit_data(c.fit.model, sweep_data), GroupedData), c.effect.name
        every_pixel = c.fit.model.loglik(c.fit.values, sweep_data)
        assert c.fit.loglik != every_pixel  # the nodes' value, not every pixel's
        lrt = max(0.0, 2 * (every_pixel - base.loglik))
        # the statistic's own sampling spread: a noncentral chi^2 of df degrees and non-centrality ~lrt has variance
        # 2 (df + 2 lrt); the nodes' error is held to a hundredth of it, and 0.1 nats where there is no effect
        spread = np.sqrt(2 * (c.df + 2 * lrt))
        assert c.lrt == pytest.approx(lrt, abs=0.1 + 0.01 * spread), (c.effect.name, c.lrt, lrt, spread)
    assert ranked[0].significant and ranked[0].effect.name in ("noise_floor", "outliers")
    best = ranked[0].fit
    assert with_exact_loglik(best, sweep_data).loglik == best.model.loglik(best.values, sweep_data)
    step = diagnose(sweep_data, model, catalogue=catalogue, max_steps=1, explain=False).steps[1]
    assert step.added.effect.name == ranked[0].effect.name
    assert step.fit.loglik == step.fit.model.loglik(step.fit.values, sweep_data)
