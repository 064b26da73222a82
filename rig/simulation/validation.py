"""`rig validate-diagnosis`: does `rig diagnose` find effects nobody told it about?

For each effect (and for none), record hidden-effect scenarios with several seeds
(`rig.scenarios`), diagnose each blind, and count how often the hidden effect is named first,
whether adding it halves the headline error (its part beyond sampling noise, which is all a
model can remove) and brings it within noise, and (for none)
whether the diagnosis says nothing significant is missing.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

from ..diagnosis import diagnose
from ..models import ModelData
from .scenarios import MODEL_EFFECT_FOR, hidden_scenario, record_scenario


@dataclass
class Trial:
    effect: str
    seed: int
    named: str
    correct: bool
    error_before_pct: float
    error_after_pct: float
    noise_pct: float
    halved: bool
    within_noise: bool
    seconds: float


def run_trial(effect: str, seed: int, workdir: Path) -> Trial:
    t0 = time.monotonic()
    sc = hidden_scenario(seed, effect)
    path = record_scenario(sc, workdir / f"{effect}-{seed}.h5")
    dg = diagnose(ModelData.from_recording(path), source=str(path), second_round=False)
    named = dg.best.effect.name if dg.best else "none"
    before = dg.model_headline
    after = dg.refit_headline or before
    expected = MODEL_EFFECT_FOR.get(effect, "none")
    return Trial(effect, seed, named, named == expected, before.error_pct, after.error_pct, after.noise_pct,
                 after.excess_pct <= 0.5 * before.excess_pct or effect == "none", after.within_noise,
                 time.monotonic() - t0)


def validate(effects: list[str], seeds: list[int], workdir: Path, out=sys.stdout) -> list[Trial]:
    trials = []
    for effect in effects:
        for seed in seeds:
            t = run_trial(effect, seed, workdir)
            trials.append(t)
            print(f"  {effect:<13} seed {seed:<4} -> {t.named:<13} {'ok ' if t.correct else 'MISS'} "
                  f"error {t.error_before_pct:6.2f} % -> {t.error_after_pct:5.2f} % (noise {t.noise_pct:.2f} %)"
                  f"{'' if t.within_noise else '  beyond noise'}", file=out, flush=True)
    return trials


def summary(trials: list[Trial]) -> str:
    lines = [f"{'hidden effect':<14} {'named first':>11} {'error halved':>13} {'within noise':>13}"]
    for effect in dict.fromkeys(t.effect for t in trials):
        ts = [t for t in trials if t.effect == effect]
        n = len(ts)
        lines.append(f"{effect:<14} {sum(t.correct for t in ts):>7}/{n:<3} {sum(t.halved for t in ts):>9}/{n:<3} "
                     f"{sum(t.within_noise for t in ts):>9}/{n:<3}")
    return "\n".join(lines)
