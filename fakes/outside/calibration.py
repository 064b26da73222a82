"""Calibration errors of a stereo camera and of the rig's distance reference: what they do to the reported depth.

A rectified pair measures the disparity d of a wall point at range Z: d = f b / Z (f in px, b the baseline; Intel's
subpixel-linearity white paper, Huber et al. eq. 8), and the camera reports Z = (f b)_cal / d with the f b of its own
calibration table. Three errors a real one has, each a line of that relation:

- the matcher's disparity is off by a constant delta (native px): d_reported = f b / Z + delta. A right imager's
  principal point off by delta px (or a relative yaw of delta / f rad) does exactly this; Intel's "tare" calibration
  adjusts such an absolute error against a flat target at a known distance (librealsense rs_device.h,
  rs2_run_tare_calibration: "adjust camera absolute distance to flat target"). Depth reads short by
  Z^2 delta / (f b) to first order.
- the calibration's f b is (1 + e) times the true one (a baseline or focal length off by e; librealsense's on-chip
  calibration has a "focal length" type for the latter): every depth is scaled by (1 + e).
- the wall is farther from the depth origin than the stage's reading by w (the stage's zero against the depth origin,
  which sits inside the camera behind its front glass): the camera sees Z_stage + w.

Together, for one frame: Z_reported = (1 + e) f b / (f b / (Z_stage + w) + delta + sigma_d N(0, 1)). With no noise
the bias is exact, (1 + e) f b / (f b / Z_t + delta) - Z_stage, which is w + e Z - Z^2 delta / (f b) to first order;
the noise adds the curvature of 1/d, + Var(Z) / Z (second order in sigma_d; about the baseline's).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Miscalibration:
    disparity_offset_px: float = 0.0   # delta: added to every disparity the matcher reports, native px
    fb_scale_error: float = 0.0        # e: the camera's f b over the true one, less 1 (here put in its baseline)
    wall_offset_m: float = 0.0         # w: the true wall's range less the stage's reading, m

    def __post_init__(self):
        if not 1.0 + self.fb_scale_error > 0:
            raise ValueError(f"baseline_scale_error = {self.fb_scale_error:g} makes the camera's baseline "
                             "non-positive; give a relative error above -1 (0.003 is 0.3 %)")

    def wall_z_m(self, stage_z_m: float) -> float:
        """Z_t = Z_stage + w: the range of the wall the camera sees."""
        return stage_z_m + self.wall_offset_m

    def reported_baseline_m(self, baseline_m: float) -> float:
        """b (1 + e): the baseline the camera's calibration states (and the manifest carries)."""
        return baseline_m * (1.0 + self.fb_scale_error)

    def reported_fb_px_m(self, fb_px_m: float) -> float:
        """(f b)_cal = (1 + e) f b: the f b the camera divides by (native px * m)."""
        return fb_px_m * (1.0 + self.fb_scale_error)

    def noise_free_bias_m(self, fb_px_m: float, stage_z_m: float) -> float:
        """(1 + e) f b / (f b / Z_t + delta) - Z_stage: the bias with no disparity noise (exact)."""
        z_t = self.wall_z_m(stage_z_m)
        return self.reported_fb_px_m(fb_px_m) / (fb_px_m / z_t + self.disparity_offset_px) - stage_z_m

    def first_order_bias_m(self, fb_px_m: float, stage_z_m: float) -> float:
        """w + e Z - Z^2 delta / (f b): the noise-free bias to first order in delta, e and w."""
        return (self.wall_offset_m + self.fb_scale_error * stage_z_m
                - stage_z_m**2 * self.disparity_offset_px / fb_px_m)
