"""The projected dot pattern as a pixel records it: fixed to the projector's rays, so a pixel sees the part of the
pattern that the ray from the projector through its wall point carries. For a projector at the imager that is the same
part at every range (Huber et al. sec. III-B.4); for a projector offset by x_p it slides by f x_p / Z native px.

Each delivered pixel gets a periodic 1-D strip of pattern along the native rows (length period_px): white Gaussian
noise blurred by the optics (Gaussian, blur_px), made log-normal with the relative spread contrast (mean 1). The
window's mean signal, which sets the disparity noise, is the pattern's mean; the pixel's own IR value carries the dot.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class DotPattern:
    seed_sequence: np.random.SeedSequence
    shape: tuple[int, int]
    contrast: float = 0.25     # sigma of log(pattern): relative spread of a pixel's brightness about the mean
    blur_px: float = 1.0
    period_px: int = 128
    _strips: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        rng = np.random.default_rng(self.seed_sequence)
        white = rng.standard_normal((*self.shape, self.period_px))
        freq = np.fft.rfftfreq(self.period_px)
        blur = np.exp(-2 * (np.pi * freq * self.blur_px) ** 2)       # Fourier transform of a Gaussian of sigma blur_px
        g = np.fft.irfft(np.fft.rfft(white, axis=-1) * blur, n=self.period_px, axis=-1)
        g /= g.std(axis=-1, keepdims=True)
        object.__setattr__(self, "_strips", np.exp(self.contrast * g - self.contrast**2 / 2))

    def relative_brightness(self, shift_native_px: float) -> np.ndarray:
        """(H, W): the pattern each pixel sees when the dots have slid by shift_native_px (linear interpolation)."""
        pos = (-shift_native_px) % self.period_px
        i0 = int(np.floor(pos))
        frac = pos - i0
        a = self._strips[..., i0 % self.period_px]
        b = self._strips[..., (i0 + 1) % self.period_px]
        return (1 - frac) * a + frac * b
