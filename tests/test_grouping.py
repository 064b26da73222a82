"""Grouped fits (rig.models.grouping) against fits on every pixel: the same parameters within 0.1 standard error.

The recordings are made by the real runner from the fake camera, at 424x240 (tiles of 10x10 pixels, each
replaced by 7 nodes): a wall tilted 35 degrees, where range changes across every tile, and a perpendicular
sweep. Models whose parameters the data determine (finite standard errors) are compared parameter by
parameter, in units of the ungrouped fit's own standard error; the log-likelihood each reports is the one of
every pixel, so they agree to far less than one unit.
"""

from __future__ import annotations

import numpy as np
import pytest

from protocols import Runner, perpendicular, tilted
from rig.devices import open_devices
from rig.models import ModelData, parse_model
from rig.models.grouping import GroupedData
from rig.models.optimise import fit_data

CAMERA = "fake:width=424,height=240,depth_unit_mm=0.1,seed=5,effects=noise_floor(sigma_px=0.02)+slant_range"


@pytest.fixture(scope="module")
def tilted_data(tmp_path_factory):
    path = tmp_path_factory.mktemp("grouping") / "tilted.h5"
    devices = open_devices(CAMERA, "fake:")
    Runner(devices.camera, devices.stage, sleep=devices.sleep).run(tilted(tilt_deg=35, distance_m=1.5, frames=60), path)
    return ModelData.from_recording(path)


@pytest.fixture(scope="module")
def sweep_data(tmp_path_factory):
    path = tmp_path_factory.mktemp("grouping") / "sweep.h5"
    devices = open_devices(CAMERA, "fake:")
    plan = perpendicular(stops_m=[0.75, 1.5, 2.25, 3.0], frames_per_stop=30)
    Runner(devices.camera, devices.stage, sleep=devices.sleep).run(plan, path)
    return ModelData.from_recording(path)


def _agree(d: ModelData, model: str) -> None:
    m = parse_model(model)
    assert isinstance(fit_data(m, d), GroupedData), "the data are large enough to be grouped"
    grouped, full = m.fit(d), m.fit(d, grouped=False)
    assert grouped.loglik == pytest.approx(full.loglik, abs=0.05)
    for name, se in full.errors.items():
        assert np.isfinite(se) and se > 0, (model, name)
        assert abs(grouped.values[name] - full.values[name]) < 0.1 * se, (model, name, grouped.values[name], full.values[name], se)
        assert grouped.errors[name] == pytest.approx(se, rel=0.05), (model, name, grouped.errors[name], se)


@pytest.mark.parametrize("model", ["power_law", "active+slant_range+noise_floor", "power_law+slant_range", "active+outliers"])
def test_grouped_fits_agree_with_every_pixel_on_a_tilted_wall(tilted_data, model):
    _agree(tilted_data, model)


@pytest.mark.parametrize("model", ["power_law+slant_range", "active+slant_range+noise_floor"])
def test_grouped_fits_agree_with_every_pixel_on_a_perpendicular_sweep(sweep_data, model):
    _agree(sweep_data, model)


def test_quantization_is_fitted_on_the_pixels_themselves(sweep_data):
    """Each pixel's offset from the depth grid is not smooth within a tile: no grouping for it."""
    assert fit_data(parse_model("active+quantization"), sweep_data) is sweep_data
    assert isinstance(fit_data(parse_model("active+noise_floor"), sweep_data), GroupedData)


def test_nodes_carry_the_weights_of_the_pixels_they_stand_for(sweep_data):
    """Per stop, the node weights sum to the pixels' (count, Gamma shapes, a s2): the quadrature is exact
    for what is constant within a tile."""
    from rig.models.likelihood import likelihood_weights

    g = fit_data(parse_model("active"), sweep_data)
    a, b, kw, _ = likelihood_weights(sweep_data)
    ga, gb, gkw, gpx = g.weights
    for s in np.unique(sweep_data.stop):
        m, gm = sweep_data.stop == s, g.stop == s
        assert gpx[gm].sum() == pytest.approx(m.sum(), rel=1e-9)
        assert ga[gm].sum() == pytest.approx(a[m].sum(), rel=1e-9)
        assert gb[gm].sum() == pytest.approx(b[m].sum(), rel=1e-9)
        assert gkw[gm].sum() == pytest.approx(kw[m].sum(), rel=1e-9)
    assert len(g) < len(sweep_data) / 10
