"""Per-pixel sufficient statistics of depth over a stop's frames, computed while streaming.

Each frame is folded in as it arrives; a stop's frames are never held in memory together.
Depth arrives as integer depth units. Each pixel's samples are shifted by an integer
reference (its first valid sample), and power sums of the shifted values are kept, in one
compiled pass per frame (numba; no per-frame temporaries):
S1 and S2 in int64, so count, mean and the sum of squared deviations are exact; S3 and S4 in
float64 (exact while the shifted values stay below 2^13 units, otherwise rounded to 1e-16 of
the sum). Central moments follow from the shifted sums at the end.

Frames are checked for independence in the same pass: over each pixel's consecutive pairs (frame t
and t-1 both valid), the number of pairs and, in int64 (exact), sum x_t x_{t-1} and sum (x_t + x_{t-1})
of the shifted samples. With the pixel's mean they give the lag-1 autocovariance sum
C1 = sum over pairs of (z_t - mean)(z_{t-1} - mean) (the standard estimator's numerator, Box & Jenkins
r_1 = c_1 / c_0). Whole frames identical to the previous one at every pixel valid in both are counted.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from drivers.compiled import njit


@dataclass
class PixelStats:
    """Per-pixel statistics of one stop, in metres.

    count: valid samples per pixel; mean_m: their mean range in m; m2_m2, m3_m3, m4_m4: sums
    over samples of (z - mean)^k, in m^k (central sums, not divided by the count).
    lag1_pairs: consecutive pairs of frames in which the pixel was valid in both; lag1_m2: sum over
    them of (z_t - mean)(z_{t-1} - mean), in m^2; frames_repeated: frames identical to the previous
    one at every pixel valid in both. None: not checked (recordings made before rig recorded them).
    """

    count: np.ndarray
    mean_m: np.ndarray
    m2_m2: np.ndarray
    m3_m3: np.ndarray
    m4_m4: np.ndarray
    lag1_pairs: np.ndarray | None = None
    lag1_m2: np.ndarray | None = None
    frames_repeated: int | None = None

    @property
    def variance_m2(self) -> np.ndarray:
        """Unbiased per-pixel variance (divides by count - 1); NaN where count < 2."""
        return self.variance_m2_in(...)

    def variance_m2_in(self, region: Any) -> np.ndarray:
        """`variance_m2` of the pixels `region` indexes (such as the slices of `center_box`), computed there only."""
        count = self.count[region]
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(count > 1, self.m2_m2[region] / (count - 1), np.nan)

    @property
    def kurtosis(self) -> np.ndarray:
        """Per-pixel kurtosis n * M4 / M2^2 (3 for a normal distribution); NaN where undefined."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where((self.count > 3) & (self.m2_m2 > 0), self.count * self.m4_m4 / self.m2_m2**2, np.nan)


class PixelMomentAccumulator:
    """Fold uint16 depth frames (0 = no data) into exact per-pixel moments.

    One compiled pass per frame (`_fold`, numba): no temporaries, no fancy indexing. A pixel's
    shift is its first valid sample; 0 marks "none yet", since a valid sample is never 0.
    """

    def __init__(self, shape: tuple[int, int], depth_scale_m: float):
        self.shape = tuple(shape)
        self.depth_scale_m = depth_scale_m
        self.count = np.zeros(shape, np.uint32)
        self.shift = np.zeros(shape, np.uint16)
        self.s1 = np.zeros(shape, np.int64)
        self.s2 = np.zeros(shape, np.int64)
        self.s3 = np.zeros(shape, np.float64)
        self.s4 = np.zeros(shape, np.float64)
        #: the previous frame's sample (0: none, or not valid); consecutive valid pairs; over them, the exact
        #: sums of x_t x_{t-1} and of x_t + x_{t-1} (x: the shifted sample)
        self.prev = np.zeros(shape, np.uint16)
        self.pairs = np.zeros(shape, np.uint32)
        self.lag_xy = np.zeros(shape, np.int64)
        self.lag_x_plus_y = np.zeros(shape, np.int64)
        #: frames identical to the previous one at every pixel valid in both (at least one such pixel)
        self.frames_repeated = 0
        #: valid pixels in the last frame folded in
        self.last_valid = 0

    def add(self, depth: np.ndarray) -> float:
        """Fold in one frame of depth units (zeros are missing data).

        Returns the frame's mean over valid pixels of 1/z - 1/z_ref in 1/m (z_ref: the pixel's
        first sample): proportional to a disparity offset common to all pixels (d = f b / z),
        whatever the scene's shape; its variance over frames measures drift. NaN if no pixel is valid.
        """
        if depth.shape != self.shape:
            raise ValueError(f"frame shape {depth.shape} differs from the stop's {self.shape}")
        if depth.dtype != np.uint16 or not (depth.flags.c_contiguous and depth.flags.writeable):
            # one compiled variant of `_fold`, not one per layout: numba compiles read-only frames (a bag's, the SDK's)
            # and strided ones (a window of a frame) separately, ~1 s each on a first run
            depth = np.array(depth, dtype=np.uint16, order="C")
        n_valid, inv_sum, n_paired, n_changed = _fold(depth, self.shift, self.count, self.s1, self.s2, self.s3, self.s4,
                                                      self.prev, self.pairs, self.lag_xy, self.lag_x_plus_y)
        self.last_valid = int(n_valid)
        if n_paired > 0 and n_changed == 0:
            self.frames_repeated += 1
        if n_valid == 0:
            return float("nan")
        return inv_sum / n_valid / self.depth_scale_m

    def result(self) -> PixelStats:
        """The stop's statistics, in one compiled pass over the pixels (`_central`)."""
        shape = self.shape
        mean, m2, m3, m4, lag1 = (np.empty(shape) for _ in range(5))
        _central(self.count, self.shift, self.s1, self.s2, self.s3, self.s4, self.depth_scale_m, mean, m2, m3, m4)
        _lag1(self.count, self.s1, self.pairs, self.lag_xy, self.lag_x_plus_y, self.depth_scale_m, lag1)
        return PixelStats(count=self.count.copy(), mean_m=mean, m2_m2=m2, m3_m3=m3, m4_m4=m4,
                          lag1_pairs=self.pairs.copy(), lag1_m2=lag1, frames_repeated=self.frames_repeated)


@njit(cache=True, nogil=True)
def _central(count, shift, s1, s2, s3, s4, scale, mean, m2, m3, m4):  # pragma: no cover - compiled
    """Central moments from the shifted power sums, per pixel: n M2 = n S2 - S1^2 exactly in integers, then with
    a = S1 / n, M3 = S3 - 3 a S2 + 2 n a^3 and M4 = S4 - 4 a S3 + 6 a^2 S2 - 3 n a^4; in m, m^2, m^3, m^4 (mean NaN
    and the sums 0 where there is no sample)."""
    h, w = count.shape
    for r in range(h):
        for c in range(w):
            k = np.int64(count[r, c])
            if k == 0:
                mean[r, c] = np.nan
                m2[r, c] = m3[r, c] = m4[r, c] = 0.0
                continue
            n = np.float64(k)
            inv_n = 1.0 / n
            a = np.float64(s1[r, c]) * inv_n  # shifted mean, in units
            s2f = np.float64(s2[r, c])
            m2[r, c] = np.float64(k * s2[r, c] - s1[r, c] * s1[r, c]) * inv_n * scale * scale
            m3[r, c] = (s3[r, c] - 3 * a * s2f + 2 * n * a**3) * scale**3
            m4[r, c] = (s4[r, c] - 4 * a * s3[r, c] + 6 * a * a * s2f - 3 * n * a**4) * scale**4
            mean[r, c] = (np.float64(shift[r, c]) + a) * scale


@njit(cache=True, nogil=True)
def _lag1(count, s1, pairs, lag_xy, lag_x_plus_y, scale, out):  # pragma: no cover - compiled
    """Per pixel, C1 = sum over pairs of (x_t - a)(x_{t-1} - a) = P - a Q + p a^2 with a = S1 / n, P = sum x_t x_{t-1},
    Q = sum (x_t + x_{t-1}), p pairs (the shift cancels), in m^2; 0 where there is no pair."""
    h, w = count.shape
    for r in range(h):
        for c in range(w):
            p = pairs[r, c]
            if p == 0:
                out[r, c] = 0.0
                continue
            a = np.float64(s1[r, c]) / np.float64(count[r, c])
            out[r, c] = (np.float64(lag_xy[r, c]) - a * np.float64(lag_x_plus_y[r, c]) + np.float64(p) * a * a) * scale * scale


@njit(cache=True, nogil=True)
def _fold(depth, shift, count, s1, s2, s3, s4, prev, pairs, lag_xy, lag_x_plus_y):  # pragma: no cover - compiled
    """One frame into the shifted power sums S1..S4 of every valid pixel, and into the lag-1 sums of every pixel
    valid in this frame and the last, in one pass.

    Returns (valid pixels, sum over them of 1/z - 1/z_ref in 1/depth-unit, pixels valid in both frames, those of
    them whose sample changed). Each sum is updated in frame order exactly as numpy would: S1, S2 and the lag-1
    sums in int64 (exact), S3 = x^3, S4 = x^4 in float64."""
    n_valid = 0
    inv_sum = 0.0
    n_paired = 0
    n_changed = 0
    h, w = depth.shape
    for r in range(h):
        for c in range(w):
            d = depth[r, c]
            last = prev[r, c]
            prev[r, c] = d
            if d == 0:
                continue
            ref = shift[r, c]
            if ref == 0:
                shift[r, c] = d
                ref = d
            x = np.int64(d) - np.int64(ref)
            count[r, c] += 1
            s1[r, c] += x
            x2 = x * x
            s2[r, c] += x2
            xf = np.float64(x)
            x3 = xf * np.float64(x2)
            s3[r, c] += x3
            s4[r, c] += x3 * xf
            n_valid += 1
            if last != 0:  # a consecutive pair (the shift was set by the earlier sample)
                y = np.int64(last) - np.int64(ref)
                pairs[r, c] += 1
                lag_xy[r, c] += x * y
                lag_x_plus_y[r, c] += x + y
                n_paired += 1
                if last != d:
                    n_changed += 1
            # 1/z - 1/z_ref = -(z - z_ref) / (z z_ref), in depth units
            inv_sum -= xf / (np.float64(d) * np.float64(ref))
    return n_valid, inv_sum, n_paired, n_changed


class MeanImageAccumulator:
    """Running mean of images (e.g. the left IR image), in float64, and per pixel the samples at the image's full
    scale (clipped: the sensor's top, so the true brightness there is unknown and the mean only a lower bound).

    full_scale_dn: the top value the camera gives (e.g. 1023 for 10-bit IR in uint16); None: the integer dtype's
    top (255 for uint8, 65535 for uint16). A float image is not checked (`saturated` stays None).
    """

    def __init__(self, full_scale_dn: int | None = None) -> None:
        self.sum: np.ndarray | None = None
        self.n = 0
        self.full_scale_dn = full_scale_dn
        #: per pixel, samples at or above full scale (exact, uint32); None: not checked
        self.saturated: np.ndarray | None = None

    def add(self, image: np.ndarray) -> None:
        if self.sum is None:
            self.sum = np.zeros(image.shape, np.float64)
            if self.full_scale_dn is None and np.issubdtype(image.dtype, np.integer):
                self.full_scale_dn = int(np.iinfo(image.dtype).max)
            if self.full_scale_dn is not None:
                self.saturated = np.zeros(image.shape, np.uint32)
        self.sum += image
        if self.saturated is not None:
            self.saturated += image >= self.full_scale_dn
        self.n += 1

    def result(self) -> np.ndarray | None:
        return None if self.sum is None else (self.sum / self.n).astype(np.float32)
