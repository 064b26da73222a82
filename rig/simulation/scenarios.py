"""Simulated recordings with hidden effects, for testing the diagnosis blind.

`rig simulate --scenario hidden --seed N OUT.h5`: the seed picks one effect (or none) and
draws realistic parameters for it; the recording says nothing about it (the fake camera's
description is concealed) and the answer goes only to OUT.answer.json. `--effect NAME` hides a
chosen one: any catalogue effect, a coarse depth unit (`coarse_depth_unit`, 1-4 mm), a pair of
catalogue effects (`slant_range+noise_floor`) or an effect the model catalogue does not have
(`beam_falloff`, `light_falloff`, `noisy_confidence`, `correlated_noise`, `scale_mixture`), frames
smoothed over time (`temporal_filter`), or IR saturated near the wall under hidden ambient light
(`ambient_saturated_ir`).

The experiment is the paper's perpendicular one with the projector on (night-time, so any
room light is the hidden `ambient` effect), 11 stops of 0.5-3.0 m, with a few projector-off
frames per stop so ambient light can be measured. The depth unit is 0.06 mm, fine enough that
rounding is below the noise (except where a coarse depth unit is the hidden effect), and coarse
enough that the deepest range a uint16 holds (3.93 m) is far beyond the last stop (3.0 m).

The simulator (fakes/) samples the physics; the models (rig/models/) predict it analytically;
the two share no code. `EXPECTED` is the one place where they meet: what the diagnosis should
say for each scenario.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from fakes.camera import FakeCamera
from fakes.effects import make_effect
from fakes.outside import SCENES
from fakes.stage import FakeStage
from fakes.world import FakeWorld, Wall
from protocols import Runner, perpendicular
from protocols.folder_import import import_folder
from rig.models.effects.builtin import EFFECTS
from rig.models.parts.component import Effect

#: the catalogue's effects that have a blind scenario, by scenario name: their twin in the simulator
#: (fakes/effects.py), or the effect's own name where the recording's format simulates it (quantization: a coarse
#: depth unit, the recording's own unit, which the model's quantization effect describes; the fake camera's
#: effect of that name is a disparity step and is not used by the scenarios)
_WITH_SCENARIO = {(e.twin or e.name): e for e in EFFECTS.values() if type(e).scenario is not Effect.scenario}
#: realistic parameter ranges for each effect the fake camera can hide: each effect's own `scenario`
#: (rig/models/effects/builtin/), in the catalogue's order
HIDDEN: dict[str, Callable[[np.random.Generator], dict[str, float]]] = {k: e.scenario for k, e in _WITH_SCENARIO.items()}
CHOICES = ["none", *HIDDEN]

#: The one place where the simulator's effects and the models' effects meet, read from each model effect's `twin`:
#: they are written independently (fakes/effects.py samples the physics, rig/models/effects/builtin/ predicts it
#: analytically) and share no code; this table says which model effect the diagnosis should name when a scenario
#: hides a simulator effect.
MODEL_EFFECT_FOR = {k: e.name for k, e in _WITH_SCENARIO.items()}
#: a depth unit coarser than the noise at short range (1-4 mm; noise 0.25-50 mm over the sweep)
COARSE_DEPTH_UNIT = "coarse_depth_unit"
#: pairs of catalogue effects hidden together
PAIRS = ("slant_range+noise_floor", "incidence+outliers", "drift+censoring")
#: effects the model catalogue lacks (fakes/effects.py), their parameter ranges, and the covariates the
#: residual they leave may rightly be said to follow ("tails": the distribution's shape; "time": the frame mean)
_SIMULATOR_ONLY: dict[str, tuple[Callable[[np.random.Generator], dict[str, float]], tuple[str, ...]]] = {
    "beam_falloff": (lambda r: {"n": r.uniform(3.0, 6.0)}, ("radius",)),
    "light_falloff": (lambda r: {"p": r.uniform(2.5, 3.5)}, ("slant", "brightness")),
    "noisy_confidence": (lambda r: {"threshold_px": r.uniform(0.2, 0.3), "score_noise_px": r.uniform(0.06, 0.12)},
                         ("range", "fill")),
    "correlated_noise": (lambda r: {"sigma_px": r.uniform(0.03, 0.06), "length_px": r.uniform(16.0, 32.0)}, ("time",)),
    "scale_mixture": (lambda r: {"fraction": r.uniform(0.05, 0.1), "factor": r.uniform(3.0, 4.0)}, ("tails",)),
    # light in soft patches: what `measured_light` describes when a model names it (tests/test_measured_light.py)
    "mottled_beam": (lambda r: {"contrast": r.uniform(0.3, 0.5), "patch": r.uniform(0.6, 1.2),
                                "seed": float(r.integers(1 << 20))}, ("position", "brightness")),
}
#: of those, the ones no catalogue effect names as its twin (an effect added to the catalogue for one of them turns
#: its scenario into one the diagnosis must name the effect for)
NOT_IN_CATALOGUE = {k: v for k, v in _SIMULATOR_ONLY.items() if k not in MODEL_EFFECT_FOR}
#: frames that are not independent: a camera's temporal post-filter (the fake camera's temporal_alpha, exponential
#: smoothing with weight alpha on the new frame); the diagnosis must say "frames not independent", never "within noise"
NOT_INDEPENDENT: dict[str, Callable[[np.random.Generator], dict[str, float]]] = {
    "temporal_filter": lambda r: {"alpha": r.uniform(0.3, 0.6)},
}
#: IR saturated near the wall (the fake camera's ir_gain, 3-5: the 10-bit IR clips at 1023 on the bright dots of the
#: nearest stops, as real IR does at short range with the projector on) under a hidden effect the brightness
#: covariates carry: the diagnosis must still name that effect, with the clipped pixels kept out of brightness
SATURATED_IR: dict[str, str] = {"ambient_saturated_ir": "ambient"}
#: scenes from a generator written without reading rig's effects, models or fakes (fakes/outside, from the paper,
#: the D435 datasheet and optics texts), imported as a lab's folder of frames is: an active stereo camera's physics
#: and one effect no effect of rig names; the covariates the residual may rightly follow (none for the control)
OUTSIDE: dict[str, tuple[str, ...]] = {
    "outside_baseline": (),
    "outside_gaussian_spot": ("radius", "slant", "brightness", "incidence"),
    "outside_offcentre_projector": ("position", "brightness"),
    "outside_ir_vignetting": ("radius", "slant", "brightness", "incidence"),
    "outside_printed_albedo": ("brightness", "position"),
    "outside_thermal_drift": ("time",),
}
#: miscalibrations of the fake camera (fakes/effects.py) the bias loop must name (`rig.accuracy.bias_loop`): the
#: fake's effect, its parameters' draw, and the bias effect that describes it
BIAS: dict[str, tuple[Callable[[np.random.Generator], dict[str, float]], str]] = {
    "disparity_offset": (lambda r: {"offset_px": r.uniform(0.03, 0.08)}, "disparity_offset"),
    "baseline_error": (lambda r: {"scale": r.uniform(0.002, 0.005)}, "scale"),
    "radial_disparity": (lambda r: {"coefficient_px": r.uniform(0.05, 0.15)}, "radial_disparity"),
    "disparity_warmup": (lambda r: {"amplitude_px": r.uniform(0.1, 0.2), "tau_s": r.uniform(15.0, 40.0)}, "warmup"),
}
#: scenarios whose fake effect has another name: a warm-up of the disparity is the fake camera's `drift` (whose
#: wander within a stop is the noise's `drift` scenario; here the bias it leaves between stops is what is named)
FAKE_EFFECT_OF = {"disparity_warmup": "drift"}
#: every scenario the blind test runs
ALL_SCENARIOS = [*CHOICES, COARSE_DEPTH_UNIT, *PAIRS, *NOT_IN_CATALOGUE, *NOT_INDEPENDENT, *SATURATED_IR, *OUTSIDE,
                 *BIAS]


@dataclass(frozen=True)
class Expected:
    """What the diagnosis should say: the catalogue effects it should name (in any order), and for an
    effect the catalogue lacks, the covariates the remaining residual may rightly be said to follow."""

    named: tuple[str, ...] = ()
    covariates: tuple[str, ...] = ()
    not_independent: bool = False  # frames correlated: "frames not independent", never "within noise"
    outside: bool = False  # a scene of fakes/outside: within noise at the end, by whatever path
    bias: bool = False  # a miscalibration: the bias loop names `named` first and ends within noise

    @property
    def kind(self) -> str:
        if self.bias:
            return "bias"
        if self.not_independent:
            return "independence"
        if self.outside:
            return "outside"
        return "open" if self.covariates else ("pair" if len(self.named) > 1 else "catalogue")


def expected(effect: str) -> Expected:
    if effect in BIAS:
        return Expected((BIAS[effect][1],), bias=True)
    if effect in OUTSIDE:
        return Expected((), OUTSIDE[effect], outside=True)
    if effect in NOT_INDEPENDENT:
        return Expected(not_independent=True)
    if effect in NOT_IN_CATALOGUE:
        return Expected((), NOT_IN_CATALOGUE[effect][1])
    if effect == COARSE_DEPTH_UNIT:
        return Expected(("quantization",))
    if effect in SATURATED_IR:
        return Expected((MODEL_EFFECT_FOR[SATURATED_IR[effect]],))
    if effect in PAIRS:
        return Expected(tuple(MODEL_EFFECT_FOR[e] for e in effect.split("+")))
    return Expected(() if effect == "none" else (MODEL_EFFECT_FOR[effect],))


FINE_DEPTH_UNIT_MM = 0.06


@dataclass
class Scenario:
    """effect: the scenario's name; params: the hidden simulator effects' parameters (effect name -> its
    parameters; for a single catalogue effect, its parameters directly, as earlier answers had them)."""

    effect: str
    params: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    width: int = 106
    frames: int = 100
    ambient_frames: int = 5
    depth_unit_mm: float = FINE_DEPTH_UNIT_MM

    def simulated(self) -> list[tuple[str, dict[str, float]]]:
        """(fake effect, parameters) for each hidden simulator effect."""
        if self.effect in ("none", "quantization", COARSE_DEPTH_UNIT, *NOT_INDEPENDENT):
            return []
        if "+" in self.effect:
            return [(name, dict(self.params.get(name, {}))) for name in self.effect.split("+")]
        if self.effect in SATURATED_IR:
            return [(SATURATED_IR[self.effect], {k: v for k, v in self.params.items() if k != "ir_gain"})]
        return [(FAKE_EFFECT_OF.get(self.effect, self.effect), dict(self.params))]

    def answer(self) -> dict[str, Any]:
        return {"scenario": "hidden", "seed": self.seed, "hidden_effect": self.effect, "parameters": self.params,
                "depth_unit_mm": self.depth_unit_mm, "expected": vars(expected(self.effect)),
                "image": [self.width, round(self.width * 480 / 848)], "frames_per_stop": self.frames}


def _draw(name: str, rng: np.random.Generator) -> dict[str, float]:
    draw = (HIDDEN[name] if name in HIDDEN else NOT_INDEPENDENT[name] if name in NOT_INDEPENDENT else
            BIAS[name][0] if name in BIAS else NOT_IN_CATALOGUE[name][0])
    return {k: round(float(v), 4) for k, v in draw(rng).items()}


def hidden_scenario(seed: int, effect: str | None = None, **kw: Any) -> Scenario:
    """The scenario for a seed: the seed picks the effect (unless given) and draws its parameters. A seed below 0
    is a ValueError naming --seed (the option that gives it)."""
    if seed < 0:
        raise ValueError(f"--seed {seed}: a seed is a whole number from 0 up; give --seed 0 or more")
    rng = np.random.default_rng(seed)
    pick = CHOICES[int(rng.integers(len(CHOICES)))]
    effect = effect or pick
    if effect not in ALL_SCENARIOS:
        raise ValueError(f"unknown effect {effect!r}; choose one of {', '.join(ALL_SCENARIOS)}")
    unit = FINE_DEPTH_UNIT_MM
    params: dict[str, Any] = {}
    if effect == "quantization":
        params = _draw(effect, rng)
        unit = params["depth_unit_mm"]
    elif effect == COARSE_DEPTH_UNIT:
        unit = round(float(rng.uniform(1.0, 4.0)), 3)
        params = {"depth_unit_mm": unit}
    elif effect in PAIRS:
        params = {name: _draw(name, rng) for name in effect.split("+")}
    elif effect in SATURATED_IR:
        params = {**_draw(SATURATED_IR[effect], rng), "ir_gain": round(float(rng.uniform(3.0, 5.0)), 3)}
    elif effect != "none":
        params = _draw(effect, rng)
    return Scenario(effect, params, seed, depth_unit_mm=unit, **kw)


def record_scenario(sc: Scenario, out: str | Path, *, progress=None) -> Path:
    """Record the scenario to `out` and write the answer beside it as OUT.answer.json."""
    out = Path(out)
    for p in (out, answer_path(out)):
        if p.exists():
            p.unlink()
    effects = [make_effect(name, **params) for name, params in sc.simulated()]
    world = FakeWorld(Wall(distance_m=1.0))
    height = round(sc.width * 480 / 848)
    cam = FakeCamera(world, width=sc.width, height=height, depth_scale_m=sc.depth_unit_mm / 1000, effects=effects,
                     seed=sc.seed, conceal=True, serial=f"SIM-{sc.seed:04d}", light="night",
                     temporal_alpha=sc.params.get("alpha") if sc.effect in NOT_INDEPENDENT else None,
                     ir_gain=sc.params.get("ir_gain", 1.0) if sc.effect in SATURATED_IR else 1.0)
    stage = FakeStage(world, seed=sc.seed)
    plan = perpendicular(frames_per_stop=sc.frames, projector_on=True, ambient_frames=sc.ambient_frames)
    Runner(cam, stage, progress=progress, sleep=lambda s: setattr(world, "time_s", world.time_s + s)).run(plan, out)
    answer_path(out).write_text(json.dumps(sc.answer(), indent=2) + "\n")
    return out


def answer_path(out: Path) -> Path:
    return out.with_name(out.stem + ".answer.json")


def record_outside(effect: str, seed: int, path: Path) -> Path:
    """Render the outside scene `effect` (`OUTSIDE`) of `seed` as fakes/outside writes it, a folder of frames with
    its manifest, and import it to `path` as `rig import` does; the folder is removed once imported."""
    frames = Path(path).parent / f"{Path(path).stem}-frames"
    try:
        folder = SCENES[effect.removeprefix("outside_")](seed, frames)
        return import_folder(folder, path)
    finally:
        shutil.rmtree(frames, ignore_errors=True)
