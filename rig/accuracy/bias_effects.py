"""The effects a bias model is built from: each adds to the depth scale S or to the disparity offset Delta of

    Z = (1 + S) f b / (f b / (t + c) + Delta)            (eq. dist_to_disp with a scale and a disparity error)

at each image region and stop (`bias_loop.BiasGroups`: t the stage's distance, rho^2 the squared normalised radius,
time since the first stop, x and y_norm the normalised position). The wall's offset c is every model's base. An
effect names its parameters (unit, start, bounds) and the residual signature it explains, as a noise effect does
(rig/models/effects/builtin). A user writes one in a Python file, loaded with `rig accuracy --effects FILE.py`:

    from rig.accuracy import BiasEffect, BiasParam

    TILT = BiasEffect("rectification_tilt", (BiasParam("tilt_px", 0.0, -5, 5, "px", "disparity error at x = 1"),),
                      "a rectification rotated about the vertical", "a bias growing across the image, as Z^2 x",
                      lambda p, g: (0.0, p["tilt_px"] * g.x))
"""

from __future__ import annotations

import hashlib
import importlib.util
import sys
from dataclasses import dataclass
from pathlib import Path
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


class BiasEffectFileError(ValueError):
    """A bias-effect file that cannot be used: one line naming the file and the fix."""


def load_bias_effects(path: str | Path) -> dict[str, BiasEffect]:
    """The `BiasEffect` objects a Python file defines at module level, by name; a name of a built-in one, a file
    that does not run, or one that defines none is a one-line BiasEffectFileError."""
    path = Path(path)
    if not path.is_file():
        raise BiasEffectFileError(f"{path} does not exist; pass a Python file that defines BiasEffect objects")
    name = "rig_user_bias_" + hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:12]
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise BiasEffectFileError(f"{path} is not a Python file; name it *.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as e:
        sys.modules.pop(name, None)
        raise BiasEffectFileError(f"{path}: running it failed ({type(e).__name__}: {e}); fix the file") from None
    found = {v.name: v for v in vars(module).values() if isinstance(v, BiasEffect) and v not in BIAS_EFFECTS.values()}
    taken = sorted(set(found) & set(BIAS_EFFECTS))
    if taken:
        raise BiasEffectFileError(f"{path}: the bias effect {taken[0]!r} has the name of a built-in one; rename it")
    return found

