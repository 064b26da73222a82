"""Per-pixel sufficient statistics of depth over a stop's frames, computed while streaming.

Each frame is folded in as it arrives; a stop's frames are never held in memory together.
Depth arrives as integer depth units. Each pixel's samples are shifted by an integer
reference (its first valid sample), and power sums of the shifted values are kept:
S1 and S2 in int64, so count, mean and the sum of squared deviations are exact; S3 and S4 in
float64 (exact while the shifted values stay below 2^13 units, otherwise rounded to 1e-16 of
the sum). Central moments follow from the shifted sums at the end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class PixelStats:
    """Per-pixel statistics of one stop, in metres.

    count: valid samples per pixel; mean_m: their mean range in m; m2_m2, m3_m3, m4_m4: sums
    over samples of (z - mean)^k, in m^k (central sums, not divided by the count).
    """

    count: np.ndarray
    mean_m: np.ndarray
    m2_m2: np.ndarray
    m3_m3: np.ndarray
    m4_m4: np.ndarray

    @property
    def variance_m2(self) -> np.ndarray:
        """Unbiased per-pixel variance (divides by count - 1); NaN where count < 2."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.count > 1, self.m2_m2 / (self.count - 1), np.nan)

    @property
    def kurtosis(self) -> np.ndarray:
        """Per-pixel kurtosis n * M4 / M2^2 (3 for a normal distribution); NaN where undefined."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where((self.count > 3) & (self.m2_m2 > 0), self.count * self.m4_m4 / self.m2_m2**2, np.nan)


class PixelMomentAccumulator:
    """Fold uint16 depth frames (0 = no data) into exact per-pixel moments."""

    def __init__(self, shape: tuple[int, int], depth_scale_m: float):
        self.shape = shape
        self.depth_scale_m = depth_scale_m
        self.count = np.zeros(shape, np.int64)
        self.shift = np.zeros(shape, np.int64)
        self._has_shift = np.zeros(shape, bool)
        self.s1 = np.zeros(shape, np.int64)
        self.s2 = np.zeros(shape, np.int64)
        self.s3 = np.zeros(shape, np.float64)
        self.s4 = np.zeros(shape, np.float64)

    def add(self, depth: np.ndarray) -> float:
        """Fold in one frame of depth units (zeros are missing data).

        Returns the frame's mean over valid pixels of 1/z - 1/z_ref in 1/m (z_ref: the pixel's
        first sample): proportional to a disparity offset common to all pixels (d = f b / z),
        whatever the scene's shape; its variance over frames measures drift. NaN if no pixel is valid.
        """
        if depth.shape != self.shape:
            raise ValueError(f"frame shape {depth.shape} differs from the stop's {self.shape}")
        valid = depth != 0
        new = valid & ~self._has_shift
        if new.any():
            self.shift[new] = depth[new]
            self._has_shift |= new
        x = np.where(valid, depth.astype(np.int64) - self.shift, 0)
        self.count += valid
        self.s1 += x
        x2 = x * x
        self.s2 += x2
        xf = x.astype(np.float64)
        x3 = xf * x2
        self.s3 += x3
        self.s4 += x3 * xf
        n_valid = np.count_nonzero(valid)
        if n_valid == 0:
            return float("nan")
        # 1/z - 1/z_ref = -(z - z_ref) / (z z_ref), in depth units then scaled to 1/m
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = -xf[valid] / (depth[valid].astype(np.float64) * self.shift[valid])
        return float(inv.mean()) / self.depth_scale_m

    def result(self) -> PixelStats:
        n = self.count.astype(np.float64)
        scale = self.depth_scale_m
        with np.errstate(invalid="ignore", divide="ignore"):
            inv_n = np.where(self.count > 0, 1.0 / n, 0.0)
            # exact in integers: n*M2 = n*S2 - S1^2 (in units^2)
            n_m2 = self.count * self.s2 - self.s1 * self.s1
            m2 = n_m2.astype(np.float64) * inv_n
            a = self.s1.astype(np.float64) * inv_n  # shifted mean, in units
            s2f = self.s2.astype(np.float64)
            m3 = self.s3 - 3 * a * s2f + 2 * n * a**3
            m4 = self.s4 - 4 * a * self.s3 + 6 * a * a * s2f - 3 * n * a**4
        mean_units = np.where(self.count > 0, self.shift + a, np.nan)
        return PixelStats(
            count=self.count.astype(np.uint32),
            mean_m=mean_units * scale,
            m2_m2=m2 * scale**2,
            m3_m3=m3 * scale**3,
            m4_m4=m4 * scale**4,
        )


class MeanImageAccumulator:
    """Running mean of images (e.g. the left IR image), in float64."""

    def __init__(self) -> None:
        self.sum: np.ndarray | None = None
        self.n = 0

    def add(self, image: np.ndarray) -> None:
        if self.sum is None:
            self.sum = np.zeros(image.shape, np.float64)
        self.sum += image
        self.n += 1

    def result(self) -> np.ndarray | None:
        return None if self.sum is None else (self.sum / self.n).astype(np.float32)
