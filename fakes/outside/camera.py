"""The stereo camera's geometry: a D435-like pair (848x480 native, 90 deg HFOV, 50 mm baseline) whose depth image
is delivered as a sparse grid of its native pixels (e.g. 64x36), with the intrinsics scaled to that grid.

Sources: Intel, "Subpixel Linearity Improvement for Intel RealSense Depth Camera D400 Series" (white paper):
f_px = 0.5 * X_res / tan(HFOV / 2), HFOV = 90 deg for the D435 at 848 px wide, Depth = f * B / d;
D435 datasheet: baseline 50 mm, depth lens f/2.0, imager pixel 3 um.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StereoCamera:
    """Left imager at the origin (the depth origin), right imager at x = +baseline_m; x right, y down, z forward."""

    native_width_px: int = 848
    native_height_px: int = 480
    native_hfov_deg: float = 90.0
    baseline_m: float = 0.050
    width_px: int = 64          # the grid of native pixels delivered (every 848/64 = 13.25th pixel)
    height_px: int = 36

    @property
    def native_f_px(self) -> float:
        """f = 0.5 X_res / tan(HFOV/2) (Intel subpixel-linearity white paper); square native pixels."""
        return 0.5 * self.native_width_px / np.tan(np.radians(self.native_hfov_deg) / 2)

    @property
    def native_cx_px(self) -> float:
        return (self.native_width_px - 1) / 2

    @property
    def native_cy_px(self) -> float:
        return (self.native_height_px - 1) / 2

    def _native_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Native (column, row) of each delivered pixel's centre: the grid samples the sensor evenly."""
        su = self.native_width_px / self.width_px
        sv = self.native_height_px / self.height_px
        u = (np.arange(self.width_px) + 0.5) * su - 0.5
        v = (np.arange(self.height_px) + 0.5) * sv - 0.5
        return u, v

    def normalised_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """(x_n, y_n), each (H, W): a pixel's ray is (x_n, y_n, 1); the wall point at range Z is (x_n Z, y_n Z, Z)."""
        u, v = self._native_centres()
        f = self.native_f_px
        x_n = (u - self.native_cx_px) / f
        y_n = (v - self.native_cy_px) / f
        return np.broadcast_to(x_n[None, :], (self.height_px, self.width_px)), \
            np.broadcast_to(y_n[:, None], (self.height_px, self.width_px))

    def intrinsics(self) -> dict[str, float]:
        """fx, fy, cx, cy of the delivered grid (px): the native ones scaled by the sampling step."""
        su = self.native_width_px / self.width_px
        sv = self.native_height_px / self.height_px
        return {
            "fx": self.native_f_px / su,
            "fy": self.native_f_px / sv,
            "cx": (self.native_cx_px + 0.5) / su - 0.5,
            "cy": (self.native_cy_px + 0.5) / sv - 0.5,
        }

    def right_imager_sees(self, z_m: float) -> np.ndarray:
        """(H, W) bool: the wall point of each left pixel falls on the right imager's sensor. The right imager at
        x = +b sees the point at x_n - b/Z; points beyond its left edge have no match (the D4xx's invalid band on
        the left of the depth image, as wide as the disparity)."""
        x_n, _ = self.normalised_rays()
        left_edge_n = (-0.5 - self.native_cx_px) / self.native_f_px
        return (x_n - self.baseline_m / z_m) >= left_edge_n
