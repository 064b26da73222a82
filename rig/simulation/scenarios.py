"""Simulated recordings with a hidden effect, for testing the diagnosis blind.

`rig simulate --scenario hidden --seed N OUT.h5`: the seed picks one effect (or none) and
draws realistic parameters for it; the recording says nothing about it (the fake camera's
description is concealed) and the answer goes only to OUT.answer.json.

The experiment is the paper's perpendicular one with the projector on (night-time, so any
room light is the hidden `ambient` effect), 11 stops of 0.5-3.0 m, with a few projector-off
frames per stop so ambient light can be measured. The depth unit is 0.05 mm, fine enough that
rounding is below the noise, except where quantization (a coarse depth unit) is the hidden effect.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from fakes.camera import FakeCamera
from fakes.effects import make_effect
from fakes.stage import FakeStage
from fakes.world import FakeWorld, Wall
from protocols import Runner, perpendicular

#: realistic parameter ranges for each effect the fake camera can hide (see fakes/effects.py)
HIDDEN: dict[str, Callable[[np.random.Generator], dict[str, float]]] = {
    "noise_floor": lambda r: {"sigma_px": r.uniform(0.02, 0.05)},
    "read_noise": lambda r: {"read_e": r.uniform(8.0, 20.0)},
    "ambient": lambda r: {"ambient_e_per_ms": r.uniform(10.0, 40.0)},
    "slant_range": lambda r: {},
    "incidence": lambda r: {},
    "outliers": lambda r: {"fraction": r.uniform(0.005, 0.03), "width_px": r.uniform(0.2, 0.6)},
    "quantization": lambda r: {"depth_unit_mm": r.uniform(0.3, 0.6)},
    "drift": lambda r: {"amplitude_px": r.uniform(0.05, 0.15), "tau_s": r.uniform(5.0, 15.0)},
    "censoring": lambda r: {"threshold_px": r.uniform(0.15, 0.3)},
}
CHOICES = ["none", *HIDDEN]

#: The one place where the simulator's effects and the models' effects meet. They are written
#: independently (fakes/effects.py samples the physics, rig/models/effects.py predicts it
#: analytically) and share no code; this table says which model effect the diagnosis should
#: name when a scenario hides a simulator effect. The "quantization" scenario is a coarse depth
#: unit (the recording's own unit), which the model's quantization effect describes; the fake
#: camera's effect of that name is a disparity step and is not used by the scenarios.
MODEL_EFFECT_FOR = {
    "noise_floor": "noise_floor",
    "read_noise": "read_noise",
    "ambient": "ambient",
    "slant_range": "slant_range",
    "incidence": "incidence",
    "outliers": "outliers",
    "quantization": "quantization",
    "drift": "drift",
    "censoring": "censoring",
}
FINE_DEPTH_UNIT_MM = 0.05


@dataclass
class Scenario:
    effect: str
    params: dict[str, float] = field(default_factory=dict)
    seed: int = 0
    width: int = 106
    frames: int = 100
    ambient_frames: int = 5

    def answer(self) -> dict[str, Any]:
        return {"scenario": "hidden", "seed": self.seed, "hidden_effect": self.effect, "parameters": self.params,
                "image": [self.width, round(self.width * 480 / 848)], "frames_per_stop": self.frames}


def hidden_scenario(seed: int, effect: str | None = None, **kw: Any) -> Scenario:
    """The scenario for a seed: the seed picks the effect (unless given) and draws its parameters."""
    rng = np.random.default_rng(seed)
    pick = CHOICES[int(rng.integers(len(CHOICES)))]
    effect = effect or pick
    if effect not in CHOICES:
        raise ValueError(f"unknown effect {effect!r}; choose one of {', '.join(CHOICES)}")
    params = {k: round(float(v), 4) for k, v in HIDDEN[effect](rng).items()} if effect != "none" else {}
    return Scenario(effect, params, seed, **kw)


def record_scenario(sc: Scenario, out: str | Path, *, progress=None) -> Path:
    """Record the scenario to `out` and write the answer beside it as OUT.answer.json."""
    out = Path(out)
    for p in (out, answer_path(out)):
        if p.exists():
            p.unlink()
    params = dict(sc.params)
    depth_unit_mm = params.pop("depth_unit_mm", FINE_DEPTH_UNIT_MM) if sc.effect == "quantization" else FINE_DEPTH_UNIT_MM
    effects = [make_effect(sc.effect, **params)] if sc.effect not in ("none", "quantization") else []
    world = FakeWorld(Wall(distance_m=1.0))
    height = round(sc.width * 480 / 848)
    cam = FakeCamera(world, width=sc.width, height=height, depth_scale_m=depth_unit_mm / 1000, effects=effects,
                     seed=sc.seed, conceal=True, serial=f"SIM-{sc.seed:04d}", light="night")
    stage = FakeStage(world, seed=sc.seed)
    plan = perpendicular(frames_per_stop=sc.frames, projector_on=True, ambient_frames=sc.ambient_frames)
    Runner(cam, stage, progress=progress, sleep=lambda s: setattr(world, "time_s", world.time_s + s)).run(plan, out)
    answer_path(out).write_text(json.dumps(sc.answer(), indent=2) + "\n")
    return out


def answer_path(out: Path) -> Path:
    return out.with_name(out.stem + ".answer.json")
