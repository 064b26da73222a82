"""The wall: a Lambertian (matte) reflector of albedo rho(X, Y), radiance L = rho E / pi (Lambert's law), either
uniform (white matte paint) or printed with blotches of dark and light ink between 0.3 and 0.9."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class UniformWall:
    albedo: float = 0.8

    def albedo_at(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        return np.full(np.broadcast(x_m, y_m).shape, self.albedo)

    def window_albedo(self, x_m: np.ndarray, y_m: np.ndarray, footprint_m: float) -> np.ndarray:
        return self.albedo_at(x_m, y_m)

    def describe(self) -> dict:
        return {"kind": "uniform", "albedo": self.albedo}


@dataclass(frozen=True)
class PrintedWall:
    """rho(X, Y) = mid + half * clip(gain * g(X, Y), -1, 1), g = sum of n_waves plane waves cos(k_j . (X, Y) + phi_j)
    / sqrt(n_waves) with wavelengths uniform in [wavelength_min_m, wavelength_max_m] and random directions: blotches
    of flat dark (0.3) and light (0.9) ink with soft edges, fixed on the wall (the same in metres at every range)."""

    seed_sequence: np.random.SeedSequence
    low: float = 0.3
    high: float = 0.9
    n_waves: int = 6
    wavelength_min_m: float = 0.20
    wavelength_max_m: float = 0.60
    gain: float = 2.5
    _waves: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        rng = np.random.default_rng(self.seed_sequence)
        wavelength = rng.uniform(self.wavelength_min_m, self.wavelength_max_m, self.n_waves)
        direction = rng.uniform(0, np.pi, self.n_waves)
        phase = rng.uniform(0, 2 * np.pi, self.n_waves)
        k = 2 * np.pi / wavelength
        object.__setattr__(self, "_waves", (k * np.cos(direction), k * np.sin(direction), phase))

    def albedo_at(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        kx, ky, phase = self._waves
        x = np.asarray(x_m)[..., None]
        y = np.asarray(y_m)[..., None]
        g = np.cos(kx * x + ky * y + phase).sum(axis=-1) / np.sqrt(self.n_waves)
        mid, half = (self.high + self.low) / 2, (self.high - self.low) / 2
        return mid + half * np.clip(self.gain * g, -1.0, 1.0)

    def window_albedo(self, x_m: np.ndarray, y_m: np.ndarray, footprint_m: float, n_sub: int = 4) -> np.ndarray:
        """Mean albedo over a square footprint (the correlation window's patch of wall), n_sub^2 sub-samples."""
        offsets = ((np.arange(n_sub) + 0.5) / n_sub - 0.5) * footprint_m
        total = np.zeros(np.broadcast(x_m, y_m).shape)
        for ox in offsets:
            for oy in offsets:
                total += self.albedo_at(x_m + ox, y_m + oy)
        return total / n_sub**2

    def describe(self) -> dict:
        kx, ky, phase = self._waves
        return {"kind": "printed blotches", "low": self.low, "high": self.high, "gain": self.gain,
                "formula": "rho = mid + half * clip(gain * sum_j cos(kx_j X + ky_j Y + phi_j) / sqrt(n), -1, 1)",
                "kx_per_m": kx.tolist(), "ky_per_m": ky.tolist(), "phase_rad": phase.tolist()}
