"""The per-stop figures of Intel's Depth Quality Tool, from a stop's mean depth image.

On the central region of interest (ROI: the central `roi` fraction of the width and of the
height, 40 % unless given; the tool lets the user choose it):

  fill rate        fraction of ROI pixels with depth
  spatial noise    RMS of the perpendicular residuals of the ROI's 3-D points to a plane fitted
                   to them (least squares, by SVD), in m and in % of the median range
  subpixel RMS     the same residuals as disparity in px: RMS of f*b/Z - f*b/Z_plane, where
                   Z_plane is where the pixel's ray meets the fitted plane
  range error      median range in the ROI minus the true distance (the stage position)

A stop's mean depth image averages the frames, so its spatial noise is the wall's flatness
plus the temporal noise divided by sqrt(frames); the tool's single-frame figure is larger.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

DEFAULT_ROI = 0.4


@dataclass
class DepthQuality:
    fill_rate: float
    n_pixels: int
    median_m: float
    spatial_noise_m: float
    spatial_noise_pct: float
    subpixel_rms_px: float
    plane_tilt_deg: float
    truth_m: float = float("nan")
    range_error_m: float = float("nan")
    range_error_pct: float = float("nan")
    roi: float = DEFAULT_ROI

    def to_dict(self) -> dict:
        return asdict(self)

    def summary(self) -> str:
        """One line, as `rig devices --check` prints it."""
        parts = [f"fill rate {100 * self.fill_rate:.1f} %"]
        if self.n_pixels >= 3 and math.isfinite(self.spatial_noise_m):
            parts += [f"spatial noise {1000 * self.spatial_noise_m:.2f} mm ({self.spatial_noise_pct:.3f} %)",
                      f"subpixel RMS {self.subpixel_rms_px:.4f} px", f"median {self.median_m:.4f} m",
                      f"plane tilt {self.plane_tilt_deg:.2f} deg"]
            if math.isfinite(self.range_error_m):
                parts.append(f"range error {1000 * self.range_error_m:+.1f} mm ({self.range_error_pct:+.2f} %) "
                             f"vs {self.truth_m:.3f} m")
            else:
                parts.append("range error n/a (give the true distance)")
        else:
            parts.append("too few pixels with depth for the other figures")
        return ", ".join(parts)


def roi_slices(shape: tuple[int, int], roi: float = DEFAULT_ROI) -> tuple[slice, slice]:
    """The central `roi` fraction of each side of an image (at least 3 px)."""
    h, w = shape
    bh, bw = max(3, int(round(h * roi))), max(3, int(round(w * roi)))
    return slice((h - bh) // 2, (h - bh) // 2 + bh), slice((w - bw) // 2, (w - bw) // 2 + bw)


def depth_quality(mean_depth_m: np.ndarray, *, fx: float, fy: float, cx: float, cy: float, baseline_m: float,
                  truth_m: float | None = None, roi: float = DEFAULT_ROI) -> DepthQuality:
    """The Depth Quality Tool's figures for one stop's mean depth image (m; NaN or 0 = no depth)."""
    z_img = np.asarray(mean_depth_m, dtype=np.float64)
    rs, cs = roi_slices(z_img.shape, roi)
    v, u = np.mgrid[rs, cs]
    z = z_img[rs, cs]
    ok = np.isfinite(z) & (z > 0)
    fill = float(ok.mean()) if ok.size else 0.0
    truth = float(truth_m) if truth_m is not None else float("nan")
    nan = float("nan")
    if ok.sum() < 3:
        return DepthQuality(fill, int(ok.sum()), nan, nan, nan, nan, nan, truth, nan, nan, roi)
    z, u, v = z[ok], u[ok].astype(np.float64), v[ok].astype(np.float64)
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], axis=1)
    pts = rays * z[:, None]
    centroid = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centroid, full_matrices=False)
    normal = vt[-1]
    if normal[2] < 0:
        normal = -normal
    residual = (pts - centroid) @ normal
    spatial = float(np.sqrt(np.mean(residual**2)))
    median = float(np.median(z))
    z_plane = (centroid @ normal) / (rays @ normal)
    fb = fx * baseline_m
    subpixel = float(np.sqrt(np.mean((fb / z - fb / z_plane) ** 2)))
    tilt = float(np.degrees(np.arccos(min(1.0, abs(normal[2])))))
    err = median - truth
    return DepthQuality(fill, int(z.size), median, spatial, 100 * spatial / median, subpixel, tilt, truth, err,
                        100 * err / truth if truth else nan, roi)
