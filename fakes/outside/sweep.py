"""A perpendicular sweep of a flat wall as the active stereo camera records it: per stop, the deterministic maps
(signal, disparity noise, true disparity, where the right imager sees the wall) and the frames (depth counts, IR DN).

Per pixel at range Z: the projector's irradiance E on the wall, its radiance L = rho E / pi, the photo-electrons S of
each imager (camera equation), the disparity noise sigma_d(S) (stereo.py), then per frame
d = f b / Z + delta_d(t) + sigma_d * N(0, 1) and the depth count round(f b / d / unit). A miscalibrated camera
(calibration.py) sees the wall at Z_stage + w, adds its constant offset delta to d and divides by (1 + e) f b.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .calibration import Miscalibration
from .camera import StereoCamera
from .dots import DotPattern
from .projector import Projector
from .sensor import Imager
from .stereo import Matcher, depth_counts
from .thermal import RunClock, ThermalDrift
from .wall import PrintedWall, UniformWall

STOPS_M = tuple(round(0.5 + 0.25 * i, 2) for i in range(11))   # 0.5 to 3.0 m in 0.25 m steps


@dataclass(frozen=True)
class Sweep:
    camera: StereoCamera = field(default_factory=StereoCamera)
    projector: Projector = field(default_factory=Projector)
    imager: Imager = field(default_factory=Imager)
    matcher: Matcher = field(default_factory=Matcher)
    wall: UniformWall | PrintedWall = field(default_factory=UniformWall)
    drift: ThermalDrift = field(default_factory=ThermalDrift)
    clock: RunClock = field(default_factory=RunClock)
    miscalibration: Miscalibration = field(default_factory=Miscalibration)
    stops_m: tuple[float, ...] = STOPS_M
    frames_per_stop: int = 100
    depth_unit_m: float = 1e-4

    @property
    def fb_px_m(self) -> float:
        """f b in native px * m: d = f b / Z."""
        return self.camera.native_f_px * self.camera.baseline_m

    @property
    def reported_fb_px_m(self) -> float:
        """The f b the camera divides by: (1 + e) f b (calibration.py); f b when calibrated."""
        return self.miscalibration.reported_fb_px_m(self.fb_px_m)


@dataclass(frozen=True)
class StopMaps:
    """What is fixed at one stop, each (H, W): signal_e is the window's mean electrons (both imagers averaged),
    ir_signal_e the pixel's own mean electrons (with its dot), sigma_d_px the disparity noise (native px). z_m is the
    stage's reading, wall_z_m the wall's true range (z_m + w; the same when calibrated), disparity_px its true
    disparity f b / wall_z_m."""

    z_m: float
    signal_e: np.ndarray
    ir_signal_e: np.ndarray
    sigma_d_px: np.ndarray
    disparity_px: float
    valid: np.ndarray
    wall_z_m: float


def stop_maps(sweep: Sweep, stage_z_m: float, dots: DotPattern) -> StopMaps:
    cam, proj, imager = sweep.camera, sweep.projector, sweep.imager
    z_m = sweep.miscalibration.wall_z_m(stage_z_m)                       # the wall the camera sees
    x_n, y_n = cam.normalised_rays()
    x_m, y_m = x_n * z_m, y_n * z_m
    irradiance = proj.wall_irradiance_w_m2(x_n, y_n, z_m)
    window_m = sweep.matcher.window_px * z_m / cam.native_f_px          # the window's patch of wall
    radiance_window = sweep.wall.window_albedo(x_m, y_m, window_m) * irradiance / np.pi
    radiance_pixel = sweep.wall.albedo_at(x_m, y_m) * irradiance / np.pi
    cos_phi_left = 1 / np.sqrt(1 + x_n**2 + y_n**2)
    x_n_right = x_n - cam.baseline_m / z_m                               # the same wall point seen from x = +b
    cos_phi_right = 1 / np.sqrt(1 + x_n_right**2 + y_n**2)
    signal = (imager.electrons(radiance_window, cos_phi_left) + imager.electrons(radiance_window, cos_phi_right)) / 2
    shift = proj.pattern_shift_native_px(cam.native_f_px, z_m)
    ir_signal = imager.electrons(radiance_pixel, cos_phi_left) * dots.relative_brightness(shift)
    return StopMaps(z_m=stage_z_m, signal_e=signal, ir_signal_e=ir_signal,
                    sigma_d_px=sweep.matcher.disparity_sigma_px(signal, imager.read_noise_e),
                    disparity_px=sweep.fb_px_m / z_m, valid=cam.right_imager_sees(z_m), wall_z_m=z_m)


@dataclass
class Streams:
    """Independent random streams from one seed: scenes rendered with the same seed share the dot pattern, the
    printed wall's layout and the standard-normal draws of the disparity noise."""

    dots: np.random.SeedSequence
    wall: np.random.SeedSequence
    depth: np.random.Generator
    ir: np.random.Generator

    @classmethod
    def from_seed(cls, seed: int) -> "Streams":
        dots, wall, depth, ir = np.random.SeedSequence(seed).spawn(4)
        return cls(dots, wall, np.random.default_rng(depth), np.random.default_rng(ir))


def render_stop(sweep: Sweep, index: int, maps: StopMaps, streams: Streams) -> tuple[np.ndarray, np.ndarray]:
    """(depth counts (n, H, W) uint16, IR (n, H, W) uint8) of stop `index`."""
    n = sweep.frames_per_stop
    t_s = sweep.clock.frame_times_s(index, n)
    offset = sweep.drift.offset_px(t_s)[:, None, None] + sweep.miscalibration.disparity_offset_px
    noise = streams.depth.standard_normal((n, *maps.signal_e.shape))
    disparity = maps.disparity_px + offset + maps.sigma_d_px * noise
    depth = depth_counts(disparity, sweep.reported_fb_px_m, sweep.depth_unit_m, maps.valid)
    ir = sweep.imager.ir_frames(streams.ir, maps.ir_signal_e, n)
    return depth, ir
