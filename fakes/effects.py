"""Physical effects the fake camera can switch on, each with a name and parameters.

Every effect overrides only the hooks it needs (see `fakes.physics` for the pipeline):
  illumination(field)     scale field.signal_e / add field.ambient_e
  image_noise(field)      add to field.image_var_e2
  disparity_noise(field)  add to field.sigma_d2_px2
  frame(ctx, d_px, valid) change one frame's disparities (px) or validity, in place
They share no code with the models' effects (rig/models/effects/builtin/); a model effect names the one here that
simulates its physics as its `twin` (`rig.simulation.scenarios.MODEL_EFFECT_FOR` collects them).
Parameters in px are native sensor pixels (848x480); a smaller rendered image scales them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar

import numpy as np

from .physics import FrameContext, StopField

EFFECTS: dict[str, type["Effect"]] = {}


def register(cls: type["Effect"]) -> type["Effect"]:
    EFFECTS[cls.name] = cls
    return cls


@dataclass
class Effect:
    """Base class: a named effect with parameters; hooks do nothing by default."""

    name: ClassVar[str] = "effect"

    def illumination(self, f: StopField) -> None: ...

    def image_noise(self, f: StopField) -> None: ...

    def disparity_noise(self, f: StopField) -> None: ...

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None: ...

    def params(self) -> dict[str, Any]:
        return asdict(self)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, **self.params()}


def make_effect(name: str, **params: Any) -> Effect:
    """Build an effect by name, e.g. make_effect('noise_floor', sigma_px=0.03)."""
    if name not in EFFECTS:
        raise ValueError(f"unknown effect {name!r}; known effects: {', '.join(sorted(EFFECTS))}")
    cls = EFFECTS[name]
    allowed = {f.name for f in fields(cls)}
    unknown = set(params) - allowed
    if unknown:
        raise ValueError(f"effect {name!r} has no parameter(s) {sorted(unknown)}; it takes {sorted(allowed)}")
    return cls(**params)


def parse_effects(text: str) -> list[Effect]:
    """Parse 'noise_floor(sigma_px=0.03)+slant_range' into effects."""
    out: list[Effect] = []
    for part in filter(None, (p.strip() for p in text.split("+"))):
        if "(" in part:
            name, rest = part.split("(", 1)
            args = rest.rstrip(")")
            params = {}
            for kv in filter(None, (a.strip() for a in args.split(","))):
                k, v = kv.split("=", 1)
                params[k.strip()] = float(v)
            out.append(make_effect(name.strip(), **params))
        else:
            out.append(make_effect(part))
    return out


@register
@dataclass
class NoiseFloor(Effect):
    """Disparity noise independent of brightness (matcher / subpixel limit), in px.

    sigma_d^2 += sigma_px^2, so it grows as Z^2 in range (eq. error_prop_unassisted).
    """

    name: ClassVar[str] = "noise_floor"
    sigma_px: float = 0.03

    def disparity_noise(self, f: StopField) -> None:
        f.sigma_d2_px2 = f.sigma_d2_px2 + (self.sigma_px * f.px_scale) ** 2


@register
@dataclass
class ReadNoise(Effect):
    """Sensor read noise in electrons RMS per native pixel, independent of light: var += read_e^2."""

    name: ClassVar[str] = "read_noise"
    read_e: float = 8.0

    def image_noise(self, f: StopField) -> None:
        f.image_var_e2 = f.image_var_e2 + self.read_e**2 * f.binning  # a binned pixel sums `binning` reads


@register
@dataclass
class Ambient(Effect):
    """Uniform ambient light: photon noise without pattern contrast (var += ambient_e).

    ambient_e_per_ms: photo-electrons per ms per native pixel.
    """

    name: ClassVar[str] = "ambient"
    ambient_e_per_ms: float = 40.0

    def illumination(self, f: StopField) -> None:
        f.ambient_e = f.ambient_e + self.ambient_e_per_ms * f.exposure_ms * f.binning


@register
@dataclass
class SlantRange(Effect):
    """Projected light falls with the slant range r along each ray, not with Z.

    signal *= (Z / r)^2, r = Z sqrt(1 + xn^2 + yn^2) (paper, "Further effects"). Projector on only.
    """

    name: ClassVar[str] = "slant_range"

    def illumination(self, f: StopField) -> None:
        if f.projector_on:
            f.signal_e = f.signal_e * (f.z_m / f.slant_m) ** 2


@register
@dataclass
class Incidence(Effect):
    """A matte (Lambertian) wall returns the projected light as cos(incidence angle)."""

    name: ClassVar[str] = "incidence"

    def illumination(self, f: StopField) -> None:
        if f.projector_on:
            f.signal_e = f.signal_e * f.cos_incidence


@register
@dataclass
class Outliers(Effect):
    """Mismatches: with probability `fraction` a sample's disparity is uniform within +-width_px."""

    name: ClassVar[str] = "outliers"
    fraction: float = 0.01
    width_px: float = 1.0

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        hit = ctx.rng.random(d_px.shape, dtype=np.float32) < self.fraction
        n = int(hit.sum())
        if n:
            w = self.width_px * ctx.field.px_scale
            d_px[hit] = ctx.field.d_true_px[hit] + ctx.rng.uniform(-w, w, n)


@register
@dataclass
class Quantization(Effect):
    """The matcher reports disparity in steps of step_px (subpixel resolution): var += step^2/12."""

    name: ClassVar[str] = "quantization"
    step_px: float = 0.125

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        step = np.float32(self.step_px * ctx.field.px_scale)
        np.multiply(np.round(d_px / step), step, out=d_px)


@register
@dataclass
class Drift(Effect):
    """Warm-up drift: disparity offset amplitude_px * exp(-t / tau_s), t since the camera opened."""

    name: ClassVar[str] = "drift"
    amplitude_px: float = 0.05
    tau_s: float = 30.0

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        d_px += np.float32(self.amplitude_px * ctx.field.px_scale * np.exp(-ctx.time_s / self.tau_s))


@register
@dataclass
class Censoring(Effect):
    """The camera drops matches it is not confident in: |disparity error| > threshold_px reads 0."""

    name: ClassVar[str] = "censoring"
    threshold_px: float = 0.2

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        valid &= np.abs(d_px - ctx.field.d_true_px) <= self.threshold_px * ctx.field.px_scale


# --- effects the model catalogue does not have (for the open-world blind test) -----------------------


@register
@dataclass
class BeamFalloff(Effect):
    """The projector's beam is brightest on its axis and falls off as cos^n of the off-axis angle.

    The off-axis angle of a pixel's ray is atan(sqrt(xn^2 + yn^2)); the pattern's irradiance is
    multiplied by cos(angle)^n (a lens-vignetted or diffuser-shaped emitter). Projector on only.
    """

    name: ClassVar[str] = "beam_falloff"
    n: float = 4.0

    def illumination(self, f: StopField) -> None:
        if f.projector_on:
            off_axis = np.arctan(np.hypot(f.xn, f.yn))
            f.signal_e = f.signal_e * np.cos(off_axis) ** self.n


@register
@dataclass
class MottledBeam(Effect):
    """The projector's diffuser spreads its light unevenly: the pattern's intensity varies in soft patches over the
    field of view, fixed to the projector's rays (so to the same pixels at every range, the projector beside the lens).

    The patches are exp(contrast * g), g a smooth random field of unit RMS over the normalised image coordinates:
    eight plane waves of wavelength patch (in xn, yn units) in directions and phases drawn from `seed`. No law of
    range or radius describes it; only the light each pixel measures does. Projector on only.
    """

    name: ClassVar[str] = "mottled_beam"
    contrast: float = 0.5
    patch: float = 0.2
    seed: float = 0.0

    def illumination(self, f: StopField) -> None:
        if f.projector_on:
            rng = np.random.default_rng(int(self.seed))
            angle, phase = rng.uniform(0.0, np.pi, 8), rng.uniform(0.0, 2.0 * np.pi, 8)
            k = 2.0 * np.pi / self.patch
            g = sum(np.cos(k * (np.cos(a) * f.xn + np.sin(a) * f.yn) + ph) for a, ph in zip(angle, phase))
            f.signal_e = f.signal_e * np.exp(self.contrast * g / np.sqrt(4.0))  # eight unit cosines: RMS 2


@register
@dataclass
class LightFalloff(Effect):
    """The projected light falls as 1/r^p along each ray (r: slant range in m), not as 1/r^2.

    A point source in free space gives p = 2; a source whose beam narrows or a medium that
    absorbs gives p > 2. The base physics already has the pattern falling as 1/Z^2; this
    replaces that with 1/r^p (equal at r = 1 m on the axis). Projector on only.
    """

    name: ClassVar[str] = "light_falloff"
    p: float = 2.6

    def illumination(self, f: StopField) -> None:
        if f.projector_on:
            f.signal_e = f.signal_e * f.z_m**2 / f.slant_m**self.p


@register
@dataclass
class NoisyConfidence(Effect):
    """The matcher drops a match when its confidence score is too low, and the score is itself noisy.

    Each sample's score is its disparity error's size plus an independent error of RMS
    score_noise_px; the match is kept while that sum stays below threshold_px (both native px).
    """

    name: ClassVar[str] = "noisy_confidence"
    threshold_px: float = 0.25
    score_noise_px: float = 0.1

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        scale = ctx.field.px_scale
        score = np.abs(d_px - ctx.field.d_true_px) + ctx.rng.normal(0.0, self.score_noise_px * scale, d_px.shape)
        valid &= score <= self.threshold_px * scale


@register
@dataclass
class CorrelatedNoise(Effect):
    """Disparity noise shared by neighbouring pixels (speckle, matching windows overlapping).

    Each frame adds a fresh field of white noise blurred by a Gaussian of length_px, scaled so
    every pixel's own RMS is sigma_px (both native px): the pixels' variances are those of a
    noise floor, but neighbours move together, so the frame's mean depth wanders far more than
    independent pixels would let it.
    """

    name: ClassVar[str] = "correlated_noise"
    sigma_px: float = 0.05
    length_px: float = 3.0

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        from scipy.ndimage import gaussian_filter

        length = max(self.length_px * ctx.field.px_scale, 0.3)
        white = ctx.rng.standard_normal(d_px.shape)
        blurred = gaussian_filter(white, length, mode="wrap")
        gain = _blur_gain(length)
        d_px += (blurred * (self.sigma_px * ctx.field.px_scale / gain)).astype(d_px.dtype)


def _blur_gain(length: float) -> float:
    """RMS of unit white noise after a Gaussian blur of `length` px (from the kernel's own weights)."""
    from scipy.ndimage import gaussian_filter

    size = int(8 * length) + 9
    delta = np.zeros((size, size))
    delta[size // 2, size // 2] = 1.0
    kernel = gaussian_filter(delta, length, mode="constant")
    return float(np.sqrt(np.sum(kernel**2)))


@register
@dataclass
class ScaleMixture(Effect):
    """Heavy tails: a fraction of samples has its disparity error `factor` times wider than the rest.

    A scale mixture of normals: the wide samples' spread grows with the noise itself, so the
    variance stays a power law of range while the distribution's tails get heavier everywhere.
    """

    name: ClassVar[str] = "scale_mixture"
    fraction: float = 0.08
    factor: float = 3.5

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        wide = ctx.rng.random(d_px.shape) < self.fraction
        d_true = ctx.field.d_true_px
        d_px[wide] = d_true[wide] + (d_px[wide] - d_true[wide]) * np.float32(self.factor)


# --- miscalibrations: the depth's bias against the truth (issue 50); none is on unless named ----------------------


@register
@dataclass
class DisparityOffset(Effect):
    """The matcher's disparity is off by a constant (a rectification or subpixel bias): d = d_true + offset_px.

    Z = f b / (f b / Z_true + offset) falls short of the truth by about Z^2 offset / (f b): a bias growing as Z^2.
    `offset_px` is in native px (848 wide), scaled to the rendered image.
    """

    name: ClassVar[str] = "disparity_offset"
    offset_px: float = 0.05

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        d_px += np.float32(self.offset_px * ctx.field.px_scale)


@register
@dataclass
class BaselineError(Effect):
    """The camera converts disparity to depth with a baseline (or focal length) `scale` off: its f b is
    (1 + scale) the true one, so every depth is (1 + scale) times what the disparity says: a bias growing as Z."""

    name: ClassVar[str] = "baseline_error"
    scale: float = 0.003

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        d_px /= np.float32(1.0 + self.scale)  # Z = (1 + scale) f b / d: the same as d / (1 + scale) at the true f b


@register
@dataclass
class RadialDisparity(Effect):
    """A residual radial error of the rectification: the disparity is off by `coefficient_px` rho^2 (rho the pixel's
    normalised radius, native px): the depth's bias is a bowl over the image, growing as Z^2 rho^2."""

    name: ClassVar[str] = "radial_disparity"
    coefficient_px: float = 0.1

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        rho2 = ctx.field.xn**2 + ctx.field.yn**2
        d_px += (self.coefficient_px * ctx.field.px_scale * rho2).astype(np.float32)


@register
@dataclass
class DisparityTilt(Effect):
    """A rectification turned about the vertical: the disparity is off by `coefficient_px` x (x = (u - cx) / fx, native
    px), a bias that grows across the image as Z^2 x. No bias effect of rig's has it: a user writes one."""

    name: ClassVar[str] = "disparity_tilt"
    coefficient_px: float = 0.1

    def frame(self, ctx: FrameContext, d_px: np.ndarray, valid: np.ndarray) -> None:
        d_px += (self.coefficient_px * ctx.field.px_scale * ctx.field.xn).astype(np.float32)
