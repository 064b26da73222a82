"""The effects a bias model is built from: each adds to the depth scale S or to the disparity offset Delta of

    Z = (1 + S) f b / (f b / (t + c) + Delta)            (eq. dist_to_disp with a scale and a disparity error)

at each image region and stop (`bias_loop.BiasGroups`: t the stage's distance, rho^2 the squared normalised radius,
time since the first stop). The wall's offset c is every model's base. An effect names its parameters (unit,
start, bounds) and the residual signature it explains, as a noise effect does (rig/models/effects/builtin).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class BiasParam:
    name: str
    start: float
    low: float
    high: float
    unit: str
    meaning: str


@dataclass(frozen=True)
class BiasEffect:
    """One effect: `add(p, g)` returns its (S, Delta) terms for the groups `g`, `p` its parameters by name."""

    name: str
    params: tuple[BiasParam, ...]
    physics: str
    signature: str
    add: Callable[[dict[str, float], object], tuple[np.ndarray | float, np.ndarray | float]]
    starts: tuple[dict[str, float], ...] = ()  # further starting points of a nonlinear parameter (tried in turn)


def _scale(p, g):
    return p["scale"], 0.0


def _disparity(p, g):
    return 0.0, p["disparity_offset_px"]


def _radial(p, g):
    return 0.0, p["radial_px"] * g.rho2


def _warmup(p, g):
    return 0.0, p["warmup_px"] * np.exp(-g.time_s / p["warmup_time_s"])


BIAS_EFFECTS: dict[str, BiasEffect] = {e.name: e for e in (
    BiasEffect("scale", (BiasParam("scale", 0.0, -0.2, 0.2, "1", "f b is (1 + scale) the true one"),),
               "a baseline or focal-length error: every depth (1 + scale) times too far", "a bias growing as Z", _scale),
    BiasEffect("disparity_offset", (BiasParam("disparity_offset_px", 0.0, -5.0, 5.0, "px",
                                              "a constant added to every disparity"),),
               "a rectification or subpixel bias of the disparity", "a bias growing as Z^2 / (f b)", _disparity),
    BiasEffect("radial_disparity", (BiasParam("radial_px", 0.0, -5.0, 5.0, "px",
                                              "the disparity's error at rho = 1, growing as rho^2"),),
               "a residual radial distortion of the rectification: delta = a rho^2",
               "a bowl over the image, growing as Z^2 rho^2", _radial),
    BiasEffect("warmup", (BiasParam("warmup_px", 0.0, -5.0, 5.0, "px", "the disparity's error at the first stop"),
                          BiasParam("warmup_time_s", 60.0, 1.0, 1e5, "s", "the time it takes to fade by 1/e")),
               "a camera still warming up: delta = w exp(-time / T)", "a bias fading with time, whatever the range",
               _warmup, starts=({"warmup_time_s": 10.0}, {"warmup_time_s": 30.0}, {"warmup_time_s": 100.0})),
)}
