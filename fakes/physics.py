"""The physics of the fake stereo camera, from the paper (Huber et al., "Cubic Range Error
Model for Stereo Vision with Illuminators"), as a pipeline that effects can join.

Per pixel and per stop:
  signal_e     pattern (projector on) or scene-texture (projector off) photo-electrons per
               image; with the projector on it falls as 1/Z^2 (paper eq. intensity_change_assisted),
               with it off it is constant (eq. integral_flux_unassisted).
  image_var_e2 noise variance of one image in e^2: shot noise = signal_e (eq. poisson_normal_approx).
  sigma_d_px   disparity noise: sigma_d^2 = (var_l + var_r) / (W * (c * signal_e)^2)
               (eq. disparity_error_unassisted; c = pattern contrast per px, W = window pixels).
Per frame: d = f*b/Z + sigma_d * N(0,1); range Z = f*b/d (eq. dist_to_disp), rounded to the
depth unit; 0 where the signal is too weak to match.
With the projector on this gives sigma_Z = k * Z^3 (eq. error_prop_assisted), off k * Z^2
(eq. error_prop_unassisted).

Effects (see `fakes.effects`) join at named points: `illumination` (scale signal_e),
`image_noise` (add to image_var_e2), `disparity_noise` (add to sigma_d^2 in px^2) and
`frame` (change one frame's disparities or validity). The protocols never see them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

#: the native sensor the electron counts below refer to (a RealSense D435 depth stream)
NATIVE_WIDTH, NATIVE_HEIGHT = 848, 480
NATIVE_FX_PX = 425.0


class StopHooks(Protocol):
    """What the stop's field needs of an effect (fakes/effects.py's `Effect` has these and more): its static part
    on the projected light, the image noise and the disparity noise of the stop."""

    def illumination(self, f: StopField) -> None: ...

    def image_noise(self, f: StopField) -> None: ...

    def disparity_noise(self, f: StopField) -> None: ...


@dataclass
class SensorPhysics:
    """Base physics, D435-like at 848x480. Electron counts are per native pixel.

    pattern_e_per_ms_at_1m: projector pattern photo-electrons per ms of exposure from a matte
        wall at Z = 1 m.
    texture_e_per_ms: photo-electrons per ms from the wall's texture in daylight (room light),
        independent of Z; what passive stereo matches on.
    contrast: the pattern's intensity gradient per px as a fraction of its intensity.
    window_px: pixels in the matching window (W in the paper's eq. disparity_error_unassisted).
    min_signal_e: below this signal a pixel has no match and reads 0.
    """

    pattern_e_per_ms_at_1m: float = 267.0
    texture_e_per_ms: float = 42.5
    contrast: float = 0.1
    window_px: int = 49
    min_signal_e: float = 20.0


@dataclass
class StopField:
    """Per-pixel quantities for one wall position and one set of settings (fixed over a stop).

    Arrays have the image's shape. Effects read and modify them before frames are drawn.
    """

    z_m: np.ndarray  # true range along the optical axis, m
    xn: np.ndarray  # normalised image coordinate (u - cx) / fx
    yn: np.ndarray  # normalised image coordinate (v - cy) / fy
    cos_incidence: np.ndarray  # cosine of the angle between the pixel's ray and the wall normal
    fb_px_m: float  # f * b in px * m
    projector_on: bool
    exposure_ms: float
    gain: float
    signal_e: np.ndarray  # photo-electrons of pattern/texture per image
    ambient_e: np.ndarray  # photo-electrons of uniform ambient light per image (no contrast)
    image_var_e2: np.ndarray  # noise variance per image, e^2
    binning: float = 1.0  # native pixels per rendered pixel
    px_scale: float = 1.0  # rendered px per native px (disparities here are in rendered px)
    sigma_d2_px2: np.ndarray = field(default_factory=lambda: np.zeros(0))
    valid: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    @property
    def d_true_px(self) -> np.ndarray:
        return self.fb_px_m / self.z_m

    @property
    def slant_m(self) -> np.ndarray:
        """Distance along each pixel's ray to the wall, m: r = Z * sqrt(1 + xn^2 + yn^2)."""
        return self.z_m * np.sqrt(1.0 + self.xn**2 + self.yn**2)


@dataclass
class FrameContext:
    """What a per-frame effect may use: the stop's field, time and a random generator."""

    field: StopField
    rng: np.random.Generator
    time_s: float  # simulated time since the camera was opened, s
    index_in_stop: int


def wall_range_m(xn: np.ndarray, distance_m: float, tilt_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Range Z along the optical axis to a wall through (0, 0, distance_m), tilted about y.

    Wall plane: sin(t) X + cos(t) Z = distance_m cos(t); along the ray X = xn Z this gives
    Z = distance_m / (1 + tan(t) xn). Returns (Z in m, wall normal's z and x components).
    """
    t = np.deg2rad(tilt_deg)
    z = distance_m / (1.0 + np.tan(t) * xn)
    return z, np.array([np.sin(t), np.cos(t)])


def build_field(
    physics: SensorPhysics,
    *,
    shape: tuple[int, int],
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    baseline_m: float,
    distance_m: float,
    tilt_deg: float,
    projector_on: bool,
    exposure_us: float,
    gain: float,
    effects: list[StopHooks],
    room_lit: bool = False,
    roughness_m: np.ndarray | float = 0.0,
) -> StopField:
    """The per-pixel field of one stop, with every effect's static part applied.

    room_lit: daylight on the wall. With the projector off it lights the wall's texture (the
    paper's day-time passive runs); with the projector on it only adds light without pattern
    contrast. Without it (night) the projector is the only light.
    roughness_m: the wall's fixed relief along Z at each pixel (a real wall is not flat to the
    depth unit; it makes each pixel's rounding phase different).
    """
    h, w = shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    xn = (u - cx) / fx
    yn = (v - cy) / fy
    z_m, (nx, nz) = wall_range_m(xn, distance_m, tilt_deg)
    z_m = z_m + roughness_m
    ray_norm = np.sqrt(1.0 + xn**2 + yn**2)
    cos_inc = np.abs(nx * xn + nz) / ray_norm
    # Rendering below native resolution bins native pixels: each rendered pixel collects
    # (native/rendered)^2 times the electrons, so sigma_Z does not depend on the resolution.
    binning = (NATIVE_WIDTH / w) * (NATIVE_HEIGHT / h)
    exposure_ms = exposure_us / 1000.0
    daylight_e = physics.texture_e_per_ms * exposure_ms * binning if room_lit else 0.0
    if projector_on:
        signal = physics.pattern_e_per_ms_at_1m * exposure_ms * binning / z_m**2
    else:
        signal = np.full(shape, daylight_e)
    f = StopField(
        z_m=z_m,
        xn=xn,
        yn=yn,
        cos_incidence=cos_inc,
        fb_px_m=fx * baseline_m,
        projector_on=projector_on,
        exposure_ms=exposure_ms,
        gain=gain,
        signal_e=signal,
        ambient_e=np.full(shape, daylight_e if projector_on else 0.0),
        image_var_e2=np.zeros(shape),
        binning=binning,
        px_scale=fx / NATIVE_FX_PX,
    )
    for e in effects:
        e.illumination(f)
    f.image_var_e2 = f.image_var_e2 + f.signal_e + f.ambient_e  # shot noise of all light
    for e in effects:
        e.image_noise(f)
    gradient2 = physics.window_px * (physics.contrast * f.signal_e) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        f.sigma_d2_px2 = 2.0 * f.image_var_e2 / gradient2  # left + right images
    for e in effects:
        e.disparity_noise(f)
    with np.errstate(divide="ignore", invalid="ignore"):
        f.sigma_d2_px2 = np.where(f.signal_e > 0, f.sigma_d2_px2, np.inf)
    f.valid = f.signal_e >= physics.min_signal_e * binning
    return f


def base_truth(physics: SensorPhysics, *, fx: float, baseline_m: float, width: int, height: int,
               exposure_us: float, projector_on: bool) -> tuple[float, float]:
    """(k, lambda) of sigma_Z = k Z^lambda that the base physics implies, with no effects.

    From eq. error_prop_*: sigma_Z = Z^2 / (f b) * sigma_d, with sigma_d^2 = 2 / (W c^2 S),
    S = S1 / Z^2 (projector on, lambda = 3) or S = S_texture (off, lambda = 2).
    """
    binning = (NATIVE_WIDTH / width) * (NATIVE_HEIGHT / height)
    exposure_ms = exposure_us / 1000.0
    if projector_on:
        s = physics.pattern_e_per_ms_at_1m * exposure_ms * binning
        lam = 3.0
    else:
        s = physics.texture_e_per_ms * exposure_ms * binning
        lam = 2.0
    sigma_d_px = np.sqrt(2.0 / (physics.window_px * physics.contrast**2 * s))
    return float(sigma_d_px / (fx * baseline_m)), lam
