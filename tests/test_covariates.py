"""The position and brightness covariates, made in compiled passes (`rig.models.data.covariates.covariate_rows`), are
numpy's formulas: the normalised ray, rho^2, the incidence cosine on each stop's wall plane and the IR at the nearest
pixel, for whole stops, scattered rows and rows in no order.

The compiled passes and numpy (or scipy) are two implementations of the same arithmetic: each is held to the error
bound of the operations involved, in units of eps = 2^-52 (u = eps / 2 is a correctly rounded operation's relative
error), not to the last bit, which a compiler that fuses a multiply and an add (GCC on ARM builds scipy so), or a
different order of the same terms, changes. A value looked up (the IR at a pixel) is the same value: exactly."""

import numpy as np
import pytest

from rig.models import ModelData

EPS = np.finfo(np.float64).eps


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


def _tolerances(d: ModelData, want: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The most two implementations of each formula may differ by, relatively, row by row. Each rounding is within
    u of its exact result, so each implementation is within m u of the true value after m roundings (first order),
    and two of them within 2 m u = m eps of each other:
    x = (u - cx) / fx: 2 roundings, so 2 eps; rho^2 = x x + y y: x's 2u doubled in the square, one product and one
    sum: 6 u each, 6 eps; the cosine |nx x + ny y + nz| / sqrt(x^2 + y^2 + 1): the numerator is within
    5 u (|nx x| + |ny y| + |nz|) in absolute terms (x's 2u, the product's u, two sums), which the cancellation of its
    terms makes relative by S / |n . r|; the square root's argument within 7 u, so the root within 4 u; the quotient
    one more: (5 S / |n . r| + 5) eps."""
    cal = d.calibration
    x = (d.u_px.astype(np.float64) - cal.cx) / cal.fx
    y = (d.v_px.astype(np.float64) - cal.cy) / cal.fy
    normal = np.array([d.sources[s].normal for s in d.stop])
    terms = np.abs(normal[:, 0] * x) + np.abs(normal[:, 1] * y) + np.abs(normal[:, 2])
    dot = np.abs(normal[:, 0] * x + normal[:, 1] * y + normal[:, 2])
    return {"x_norm": np.full(len(d), 2 * EPS), "y_norm": np.full(len(d), 2 * EPS), "rho2": np.full(len(d), 6 * EPS),
            "cos_inc": (5 * terms / dot + 5) * EPS}


@pytest.mark.numeric
@pytest.mark.parametrize("rows", ["whole", "scattered", "no order"])
def test_covariates_are_numpys_formulas(data, rows):
    rng = np.random.default_rng(9)
    d = {"whole": lambda: data.select(np.ones(len(data), bool)),
         "scattered": lambda: data.select(rng.random(len(data)) < 0.4),
         "no order": lambda: data.select(rng.permutation(len(data))[: len(data) // 3])}[rows]()
    d._cols.clear()  # made here, not carried from `data`
    if rows == "no order":
        assert d.stop_slices() is None
    assert all(src.ir_dn is not None for src in d.sources)
    want = _numpy(d)
    rtol = _tolerances(d, want)
    for name, expected in want.items():
        got = d.covariate(name)
        if name == "ir":  # the smoothed image's value at the nearest pixel, looked up: the very same value
            assert np.array_equal(got, expected, equal_nan=True), name
        else:
            gap = np.abs(got - expected) / np.abs(expected)
            assert np.all(gap <= rtol[name]), (name, np.max(gap / EPS))
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


def _smoothing_rtol(sigma: int) -> float:
    """How far two implementations of a Gaussian filter of `sigma` px may differ, relatively, on values >= 0.
    scipy's correlate1d sums a symmetric kernel of 2 r + 1 weights (r = int(4 sigma + 0.5)) as w0 x0, then r times
    acc += (x_-j + x_j) w_j: a pair's term is rounded twice and then by each of the r or fewer additions after it,
    so, all terms positive, each pass is within (r + 2) u of its exact sum (a fused multiply-add rounds less).
    Both implementations make the weights with the same numpy calls, so they share them. Two passes, each within
    (r + 2) u: an implementation within 2 (r + 2) u of the exact filter, two of them within 2 (r + 2) eps."""
    return 2 * (int(4.0 * sigma + 0.5) + 2) * EPS


@pytest.mark.numeric
@pytest.mark.parametrize("shape", [(480, 848), (60, 106), (24, 32), (5, 7), (1, 50), (50, 1)])
def test_the_smoothed_brightness_is_scipys_gaussian_filter(shape):
    """`smoothed` (compiled) against scipy.ndimage.gaussian_filter, which shares no code with it: within the two
    filters' rounding (`_smoothing_rtol`: 60 eps at sigma 7, 1.3e-14), for camera images and for images smaller than
    the kernel (reflected many times over). Where no set pixel lies within reach both give 0: exactly."""
    from scipy.ndimage import gaussian_filter

    from rig.models.data.smoothing import smoothed

    rng = np.random.default_rng(shape[0])
    image = rng.lognormal(3.0, 1.0, shape).astype(np.float32)
    np.testing.assert_allclose(smoothed(image, 7), gaussian_filter(image.astype(np.float64), sigma=7, mode="reflect"),
                               rtol=_smoothing_rtol(7), atol=0)
    clipped = rng.random(shape) < 0.01
    np.testing.assert_allclose(smoothed(clipped, 3),
                               gaussian_filter(clipped.astype(np.float64), sigma=3, mode="reflect"),
                               rtol=_smoothing_rtol(3), atol=0)


@pytest.mark.numeric
def test_the_pixel_noise_of_inverse_range_is_numpys_mean_by_its_definition():
    """The drift's pixel-noise term (`_noise_of_inverse_range`, one compiled pass): the pixels with n > 1 and a finite
    variance and range, and their sum of s2 / Z^4, against numpy."""
    from rig.models.data.covariates import _noise_of_inverse_range

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
    # a sum of k positive terms s2 / Z^4, each within 5 u of its exact value in either implementation (s2's quotient;
    # Z^4 as numpy's pow, within 1 ulp = 2 u, or as two products, 3 u; the last quotient): each sum within
    # (k - 1 + 5) u of the exact one whatever the order of adding, two of them within (k + 4) eps (9e-13 here)
    assert total == pytest.approx(np.sum(s2[ok] / z[ok] ** 4), rel=(ok.sum() + 4) * EPS, abs=0)
