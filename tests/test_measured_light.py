"""`measured_light`: the shot noise follows the light each pixel measured (issue 49, item 2).

The data: the fake camera's `mottled_beam`, a projector whose light falls in soft patches (fakes/effects.py), which
no law of range, radius or incidence describes. The base model is far off there; the light as measured brings it
near the noise, and the geometric effects do not. Clipped IR is filled from the nearest stop as P (Z'/Z)^2.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rig.cli import main
from rig.diagnosis import headline
from rig.models import Catalogue, ModelData, parse_model, with_errors
from rig.models.data.covariates import StopSource
from rig.models.data.pattern_light import LIGHT_WINDOWS_PX, fill_clipped_light, light_image


@pytest.fixture(scope="module")
def mottled(tmp_path_factory):
    path = tmp_path_factory.mktemp("mottled") / "mottled.h5"
    assert main(["simulate", "--seed", "1001", "--effect", "mottled_beam", "--width", "64", "--frames", "60", "-q",
                 str(path)]) == 0
    return ModelData.from_recording(path)


def _fit(spec: str, d: ModelData):
    fit = with_errors(parse_model(spec).fit(d), d)
    return fit, headline(fit, d)


def test_the_measured_light_takes_the_error_of_a_mottled_beam_near_the_noise(mottled):
    d = mottled
    _, base = _fit("active", d)
    fit, light = _fit("active+measured_light", d)
    _, geometric = _fit("active+slant_range+incidence", d)
    assert not base.within_noise and base.error_pct > 5 * base.noise_pct, base
    # measured here: 4.12 % -> 0.77 % (noise 0.40 %); the geometric laws make it worse (14.0 %)
    assert light.error_pct < base.error_pct / 4, (base, light)
    assert light.error_pct < 3 * light.noise_pct, light
    assert geometric.error_pct > base.error_pct, geometric
    gamma, se = fit.values["measured_light.exponent"], fit.errors["measured_light.exponent"]
    assert math.isfinite(se) and 0 < se < 0.05, fit.errors
    # shot noise alone gives 1 and read noise pushes it toward 2; the smoothing's lost contrast a little above 1
    assert 1.0 < gamma < 2.0, gamma
    assert fit.values["measured_light.window_px"] in LIGHT_WINDOWS_PX


def test_the_diagnosis_does_not_try_it_on_its_own_but_a_model_may_name_it():
    cat = Catalogue.default()
    assert "measured_light" in cat.effects
    assert "measured_light" not in [e.name for e in cat.candidates()]
    assert parse_model("active+slant_range+measured_light").name == "active+slant_range+measured_light"


def _source(light: np.ndarray, mean_m: np.ndarray) -> StopSource:
    return StopSource(None, None, np.array([0.0, 0.0, 1.0]), None, 0.0, math.nan, 10, True,
                      mean_m=mean_m.astype(np.float32), light_raw=light.astype(np.float32))


def test_clipped_light_comes_from_the_nearest_stop_that_saw_it_as_the_inverse_square():
    shape = (6, 8)
    near, mid, far = (np.full(shape, z) for z in (0.5, 1.0, 2.0))
    p_mid = np.linspace(100.0, 200.0, 48).reshape(shape)
    clipped = np.full(shape, np.nan)
    clipped[:, 4:] = 900.0  # the near stop saw its right half; the left half clipped (NaN)
    sources = [_source(clipped, near), _source(p_mid, mid), _source(p_mid / 4, far)]
    sources[2].light_raw[0, 0] = np.nan  # the far stop's corner clipped too: the mid stop is nearer to it than the near
    fill_clipped_light(sources)
    filled = sources[0].light_raw
    # the left half from the mid stop (nearest in range: ln 2 against ln 4 for the far one), times (1.0 / 0.5)^2
    np.testing.assert_allclose(filled[:, :4], p_mid[:, :4] * 4, rtol=2e-7)
    np.testing.assert_array_equal(filled[:, 4:], 900.0)  # what was seen is kept
    assert sources[2].light_raw[0, 0] == pytest.approx(p_mid[0, 0] / 4, rel=2e-7, abs=0)


def test_smoothing_leaves_unknown_light_out_and_keeps_a_uniform_light():
    light = np.full((30, 40), 50.0)
    light[10:20, 10:20] = np.nan  # clipped at every stop
    s = _source(light, np.full(light.shape, 1.0))
    for w in (1.0, 3.0):
        image = light_image(s, w)
        known = np.isfinite(image)
        assert known[0, 0] and not known[15, 15]  # deep inside the hole: less than half the weight known
        np.testing.assert_allclose(image[known], 50.0, rtol=1e-6)  # a normalised convolution: no dark rim
