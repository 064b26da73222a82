"""`rig validate-diagnosis`: does `rig diagnose` find effects nobody told it about?

For each scenario (`rig.simulation.scenarios`: a catalogue effect, none, a coarse depth unit,
a pair, or an effect the catalogue lacks), record it with several seeds, diagnose each
recording blind, and judge it by what the scenario expects (`scenarios.EXPECTED`):

  catalogue effect (and none, and a coarse depth unit)
      named first: the path's first effect is the hidden one (nothing for none);
      halved: the headline error's part beyond sampling noise (all a model can remove) at most half;
      within noise: every statistic within noise once the path's effects are in
  pair
      found: both effects on the path, in either order; within noise after them
  frames not independent (a temporal post-filter)
      named: the diagnosis says "frames not independent"; and it never ends within noise
  an effect the catalogue lacks
      no false claim: the catalogue's effects alone do not bring every statistic within noise;
      covariate right: what remains follows a covariate the effect can explain;
      within noise: every statistic within noise once the empirical terms are in
  a miscalibration (the depth's bias against the stage's truth: `rig.accuracy.bias_loop`)
      named first: the bias loop's first effect is the one that describes it;
      halved: the regions' RMS misfit at most half the offset-only model's; within noise: by radius and position

Trials run in parallel processes (`--jobs`, default: one per core).
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ..models.fitting.progress import ProgressFn, WorkProgress

from protocols.recording import Recording

from ..accuracy.bias_loop import bias_groups, diagnose_bias, stage_tolerance
from ..diagnosis import diagnose
from ..models import ModelData
from .scenarios import ALL_SCENARIOS, expected, hidden_scenario, record_outside, record_scenario


@dataclass
class Trial:
    effect: str
    seed: int
    kind: str  # catalogue, pair, open
    named: str  # the path's first effect, "none" if none
    path: list[str]
    correct: bool  # named first (catalogue), both found (pair), no false claim (open)
    covariate: str  # what the residual follows after the catalogue ("" if nothing remains)
    covariate_right: bool
    error_before_pct: float
    error_catalogue_pct: float
    error_after_pct: float
    noise_pct: float
    halved: bool
    claims_within_catalogue: bool
    within_noise: bool
    seconds: float
    worst: str = ""  # the worst check still beyond noise at the end
    empirical: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        if self.kind == "independence":  # named "frames not independent", and never "within noise"
            return self.correct and not self.within_noise
        if self.kind in ("open", "outside"):
            return self.correct and self.covariate_right and self.within_noise
        return self.correct and self.halved and self.within_noise


def run_trial(effect: str, seed: int, workdir: Path, **scenario: Any) -> Trial:
    """One blind trial: record the scenario of `seed` hiding `effect` (`scenario`: its size, as
    `hidden_scenario` takes it: width, frames), diagnose it, and score the diagnosis against the answer."""
    t0 = time.monotonic()
    want = expected(effect)
    if want.kind == "bias":
        return _bias_trial(effect, seed, record_scenario(hidden_scenario(seed, effect, **scenario),
                                                         Path(workdir) / f"{effect}-{seed}.h5"), t0)
    if want.kind == "outside":
        path = record_outside(effect, seed, Path(workdir) / f"{effect}-{seed}.h5")
    else:
        path = record_scenario(hidden_scenario(seed, effect, **scenario), Path(workdir) / f"{effect}-{seed}.h5")
    dg = diagnose(ModelData.from_recording(path), source=str(path))
    before, catalogue, final = dg.model_headline, dg.catalogue_headline, dg.final_headline
    added = dg.added
    named = added[0] if added else "none"
    if want.kind == "pair":
        correct = set(want.named) <= set(added)
    elif want.kind == "open":
        correct = not catalogue.within_noise
    elif want.kind == "independence":
        correct = dg.independence.correlated and "Frames not independent" in dg.summary()
    elif want.kind == "outside":
        correct = True  # no effect to name: the scene's effect is in no catalogue, and any path may take it
    else:
        correct = named == (want.named[0] if want.named else "none")
    u = dg.unexplained
    covariate = u.covariate if u is not None else ""
    after = final if want.kind in ("open", "independence", "outside") else catalogue
    worst = after.consistency.worst(extra=1) if after.consistency is not None and not after.within_noise else None
    return Trial(
        effect, seed, want.kind, named, added, correct, covariate,
        covariate in want.covariates if want.kind == "open" or (want.kind == "outside" and covariate) else True,
        before.error_pct, catalogue.error_pct, final.error_pct, after.noise_pct,
        after.excess_pct <= 0.5 * before.excess_pct or not want.named,
        catalogue.within_noise, after.within_noise, time.monotonic() - t0,
        worst.name if worst is not None else "",
        [s.covariate for s in u.empirical_steps] if u is not None else [],
    )


def _bias_trial(effect: str, seed: int, path: Path, t0: float) -> Trial:
    """A miscalibration's trial: the bias loop (`rig.accuracy.bias_loop`) on the recording's stops against the
    stage's truth; its "errors" are the regions' RMS misfit in mm (the noise: the RMS of their own errors)."""
    with Recording(path) as rec:
        g = bias_groups(ModelData.from_recording(path), stage_tolerance(rec))
    dg = diagnose_bias(g)
    start, final = dg.steps[0], dg.final
    named = dg.added[0] if dg.added else "none"
    noise_mm = float(1e3 * np.sqrt(np.mean(g.se**2 + final.tau_m**2 + final.kappa_m**2)))
    worst = "" if final.within_noise else min(final.checks, key=lambda k: final.checks[k][2])
    return Trial(effect, seed, "bias", named, dg.added, named == expected(effect).named[0], "", True, start.rms_mm,
                 final.rms_mm, final.rms_mm, noise_mm, final.rms_mm <= 0.5 * start.rms_mm, False,
                 final.within_noise, time.monotonic() - t0, worst)


def _line(t: Trial) -> str:
    verdict = "ok  " if t.passed else "MISS"
    path = "+".join(t.path) or "nothing added"
    rest = f", residual follows {t.covariate or '-'} ({'+'.join(t.empirical)})" if t.kind == "open" else ""
    beyond = "" if t.within_noise else f"  beyond noise: {t.worst or 'headline'}"
    unit = "mm" if t.kind == "bias" else "%"  # a bias trial's error is the regions' RMS misfit
    return (f"  {t.effect:<24} seed {t.seed:<5} {verdict} path {path}{rest}; error {t.error_before_pct:6.2f} {unit} -> "
            f"{t.error_catalogue_pct:5.2f} {unit} -> {t.error_after_pct:5.2f} {unit} (noise {t.noise_pct:.2f} {unit}, "
            f"{t.seconds:.0f} s){beyond}")


def validate(effects: list[str], seeds: list[int], workdir: Path, out: TextIO = sys.stdout,
             jobs: int | None = None, progress: ProgressFn | None = None) -> list[Trial]:
    """Run every (effect, seed) trial, `jobs` at a time; return them in order. `progress` is told as each trial
    ends (`rig.models.fitting.progress`)."""
    jobs = jobs or os.cpu_count() or 1
    todo = [(e, s) for e in effects for s in seeds]
    trials: dict[tuple[str, int], Trial] = {}

    def done(t: Trial) -> None:
        print(_line(t), file=out, flush=True)
        if progress is not None:
            progress(WorkProgress(f"{t.effect} seed {t.seed} done", len(trials), len(todo), finished=len(trials) == len(todo)))

    if progress is not None:
        progress(WorkProgress(f"{len(todo)} trials, {min(jobs, len(todo))} at a time", 0, len(todo)))
    if jobs <= 1:
        for e, s in todo:
            trials[(e, s)] = t = run_trial(e, s, workdir)
            done(t)
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(run_trial, e, s, workdir): (e, s) for e, s in todo}
            for fut in as_completed(futures):
                trials[futures[fut]] = t = fut.result()
                done(t)
    return [trials[k] for k in todo]


def summary(trials: list[Trial]) -> str:
    """The table (Markdown, as in docs/models.md): for each scenario, in the order of `ALL_SCENARIOS`, how many
    trials met each criterion of its kind, and the median headline error before and after."""
    lines = ["| hidden | kind | named first / both found / no false claim | error halved | residual covariate right | "
             "right covariate among the empirical terms | headline error before -> after (median) | within noise |",
             "|---|---|---|---|---|---|---|---|"]
    present = dict.fromkeys(t.effect for t in trials)
    for effect in [e for e in ALL_SCENARIOS if e in present] + [e for e in present if e not in ALL_SCENARIOS]:
        ts = [t for t in trials if t.effect == effect]
        n, kind = len(ts), ts[0].kind

        def count(flag: str) -> str:
            return f"{sum(bool(getattr(t, flag)) for t in ts)}/{n}"

        want = expected(effect).covariates
        open_like = kind in ("open", "outside")
        on_path = f"{sum(any(c in want for c in t.empirical) for t in ts)}/{n}" if open_like and want else "-"
        halved = count("halved") if kind not in ("open", "independence", "outside") else "-"
        cov = count("covariate_right") if open_like and want else "-"
        before = statistics.median(t.error_before_pct for t in ts)
        after = statistics.median((t.error_after_pct if open_like else t.error_catalogue_pct) for t in ts)
        named = count("correct") if kind != "outside" else "-"
        unit = "mm" if kind == "bias" else "%"
        lines.append(f"| {effect} | {kind} | {named} | {halved} | {cov} | {on_path} | "
                     f"{before:.2f} {unit} -> {after:.2f} {unit} | {count('within_noise')} |")
    return "\n".join(lines)
