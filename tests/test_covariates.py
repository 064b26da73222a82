"""The position and brightness covariates, made in compiled passes (`rig.models.covariates.covariate_rows`), are
numpy's formulas: the normalised ray, rho^2, the incidence cosine on each stop's wall plane and the IR at the nearest
pixel, for whole stops, scattered rows and rows in no order, and the same bit for bit."""

import numpy as np
import pytest

from rig.models import ModelData


@pytest.fixture(scope="module")
def data(small_recording) -> ModelData:
    d = ModelData.from_recording(small_recording)
    rng = np.random.default_rng(4)
    for src in d.sources:  # walls turned every way: the cosine depends on the plane, not just on the radius
        n = rng.normal(size=3) + [0, 0, 2]
        src.normal = n / np.linalg.norm(n)
    return d


def _numpy(d: ModelData) -> dict[str, np.ndarray]:
    cal = d.calibration
    x = (d.u_px.astype(np.float64) - cal.cx) / cal.fx
    y = (d.v_px.astype(np.float64) - cal.cy) / cal.fy
    normal = np.array([d.sources[s].normal for s in d.stop])
    cos = np.abs(normal[:, 0] * x + normal[:, 1] * y + normal[:, 2]) / np.sqrt(x * x + y * y + 1.0)
    ir = np.empty(len(d))
    for i, s in enumerate(d.stop):
        image = d.sources[s].ir_dn
        h, w = image.shape
        ir[i] = image[int(np.clip(np.rint(d.v_px[i]), 0, h - 1)), int(np.clip(np.rint(d.u_px[i]), 0, w - 1))]
    return {"x_norm": x, "y_norm": y, "rho2": x * x + y * y, "cos_inc": cos, "ir": ir}


@pytest.mark.parametrize("rows", ["whole", "scattered", "no order"])
def test_covariates_are_numpys_formulas_bit_for_bit(data, rows):
    rng = np.random.default_rng(9)
    d = {"whole": lambda: data.select(np.ones(len(data), bool)),
         "scattered": lambda: data.select(rng.random(len(data)) < 0.4),
         "no order": lambda: data.select(rng.permutation(len(data))[: len(data) // 3])}[rows]()
    d._cols.clear()  # made here, not carried from `data`
    if rows == "no order":
        assert d.stop_slices() is None
    assert all(src.ir_dn is not None for src in d.sources)
    want = _numpy(d)
    for name, expected in want.items():
        assert np.array_equal(d.covariate(name), expected), name
    assert len(np.unique(np.round(want["cos_inc"] * np.sqrt(1 + want["rho2"]), 6))) > 10  # the planes do matter


def test_positions_off_the_image_take_its_edge_and_unknown_ones_no_brightness(data):
    d = data.select(np.arange(6))
    d._cols.clear()
    h, w = d.sources[d.stop[0]].ir_dn.shape
    d.u_px = np.array([-3.0, w + 5.0, 2.5, 3.5, np.nan, 1.0], np.float32)  # 2.5 and 3.5: half to even
    d.v_px = np.array([0.0, h + 2.0, 1.0, 1.6, 1.0, -0.6], np.float32)
    image = d.sources[d.stop[0]].ir_dn
    ir = d.covariate("ir")
    assert ir[0] == image[0, 0] and ir[1] == image[h - 1, w - 1]
    assert ir[2] == image[1, 2] and ir[3] == image[2, 4] and np.isnan(ir[4]) and ir[5] == image[0, 1]


@pytest.mark.parametrize("shape", [(480, 848), (60, 106), (24, 32), (5, 7), (1, 50), (50, 1)])
def test_the_smoothed_brightness_is_scipys_gaussian_filter_bit_for_bit(shape):
    """`smoothed` (compiled) against scipy.ndimage.gaussian_filter, which shares no code with it: the same values to
    the last bit, for camera images and for images smaller than the kernel (reflected many times over)."""
    from scipy.ndimage import gaussian_filter

    from rig.models.covariates import smoothed

    rng = np.random.default_rng(shape[0])
    image = rng.lognormal(3.0, 1.0, shape).astype(np.float32)
    assert np.array_equal(smoothed(image, 7), gaussian_filter(image.astype(np.float64), sigma=7, mode="reflect"))
    clipped = rng.random(shape) < 0.01
    assert np.array_equal(smoothed(clipped, 3), gaussian_filter(clipped.astype(np.float64), sigma=3, mode="reflect"))


def test_the_pixel_noise_of_inverse_range_is_numpys_mean_by_its_definition():
    """The drift's pixel-noise term (`_noise_of_inverse_range`, one compiled pass): the pixels with n > 1 and a finite
    variance and range, and their sum of s2 / Z^4, against numpy."""
    from rig.models.covariates import _noise_of_inverse_range

    rng = np.random.default_rng(12)
    count = rng.integers(0, 12, 5000).astype(np.uint32)
    m2, z = rng.gamma(2.0, 1e-6, 5000), rng.uniform(0.5, 3.0, 5000)
    z[::17] = np.nan
    m2[::23] = np.inf
    with np.errstate(divide="ignore", invalid="ignore"):
        s2 = np.where(count > 1, m2 / (count - 1.0), np.nan)
    ok = np.isfinite(s2) & np.isfinite(z)
    pixels, total = _noise_of_inverse_range(count, m2, z)
    assert pixels == ok.sum() and 0 < pixels < 5000
    assert total == pytest.approx(np.sum(s2[ok] / z[ok] ** 4), rel=1e-12)
