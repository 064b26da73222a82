"""The Results screen's work, without Textual: open a recording, diagnose it, refit with effects.

Everything is `rig diagnose`'s: `ModelData.from_recording`, `diagnose` (fit, ranked candidate
effects, the path, headline error, residuals by range and radius, plain-language summary, and
when the catalogue leaves something unexplained, the empirical shape of what remains). Effects
come from the built-in catalogue, installed plugins and an optional effects file the user
wrote (`rig.models.Catalogue`). Opening diagnoses the recording once (a fit per candidate
effect: the slow part). Adding or removing effects is then one fit of `base + effects`, with
its headline error and residuals; the diagnosis's ranking, summary and shape are kept, so the
candidate list stays as it was ranked. The history keeps the headline error after each change
so the screen can chart it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from rig.diagnosis import Diagnosis, Headline, Residuals, default_model, diagnose, headline, residuals
from rig.models import Catalogue, Model, ModelData, ModelFit
from rig.models.effects.empirical import COVARIATES, EmpiricalSigma
from rig.models.fitting.progress import ProgressCounter, ProgressFn, WorkProgress
from protocols.recording import Recording

from .live import format_duration


@dataclass
class HistoryEntry:
    change: str  # "active", "+ slant_range", "- incidence"
    model: str
    headline: Headline


@dataclass
class FitRow:
    name: str
    value: str
    se: str
    unit: str


@dataclass
class BinRow:
    section: str  # "radius" or "range"
    label: str
    ratio: float  # measured / predicted sigma
    pm: float  # two standard errors of the ratio
    flagged: bool


@dataclass
class CandidateRow:
    effect: str
    dbic: float | None  # None for effects already in the model
    significant: bool
    in_model: bool

    def prompt(self) -> str:
        if self.in_model or self.dbic is None:
            return f"{self.effect:<13} in the model"
        return f"{self.effect:<13} {self.dbic:>9.1f}{' *' if self.significant else ''}"


@dataclass
class ShapeCurve:
    """What the catalogue does not explain, as a curve: the sigma multiplier along a covariate."""

    covariate: str
    unit: str
    x: list[float]
    multiplier: list[float]
    title: str


class ResultsSession:
    """One recording, its data and its diagnosis as the operator adds and removes effects.

    `diagnosis` is the one made when the recording was opened; `fit` and `residuals` are those of the model the
    operator has now (the diagnosed one until the first refit)."""

    def __init__(self) -> None:
        self.path: Path | None = None
        self.data: ModelData | None = None
        self.diagnosis: Diagnosis | None = None
        self.fit: ModelFit | None = None
        self.residuals: Residuals | None = None
        self.base: Model | None = None
        self.history: list[HistoryEntry] = []
        self.catalogue = Catalogue.default()
        self.effects_file = ""
        self.notes: list[str] = []  # what to know about the recording itself (one stop, interrupted, ...)

    def load_effects(self, path: str) -> None:
        """Use the built-in effects and those of the file `path` (none: "")."""
        catalogue = Catalogue.default()
        if path:
            catalogue = catalogue.with_file(path)  # EffectFileError (a ValueError) says what is wrong in one line
        self.catalogue, self.effects_file = catalogue, path

    def open(self, path: str | Path, effects_file: str | None = None, progress: ProgressFn | None = None) -> Diagnosis:
        path = Path(path)
        if effects_file is not None and effects_file != self.effects_file:
            self.load_effects(effects_file)
        data = ModelData.from_recording(path)
        with Recording(path) as rec:
            notes = rec.notes()
        diag = diagnose(data, source=str(path), catalogue=self.catalogue, progress=progress)
        self.path, self.data, self.diagnosis, self.notes = path, data, diag, notes
        self.fit, self.residuals = diag.model_fit, diag.residuals
        self.base = default_model(data)
        self.history = [HistoryEntry(diag.model_fit.model.name, diag.model_fit.model.name, diag.model_headline)]
        return diag

    @property
    def effects(self) -> list[str]:
        """Effects in the current model."""
        return [] if self.fit is None else [e.name for e in self.fit.model.effects]

    def refit(self, effects: list[str], progress: ProgressFn | None = None) -> ModelFit:
        """Fit the base model plus `effects`: one fit, then its headline error and residuals. The diagnosis (its
        ranked candidates, summary and shape) is kept as it was made when the recording was opened."""
        if self.data is None or self.base is None:
            raise ValueError("no recording is open; press ctrl+o to open one")
        known = self.catalogue.effects
        unknown = [e for e in effects if e not in known and not e.startswith("empirical(")]
        if unknown:
            raise ValueError(f"unknown effect(s) {unknown}; known: {', '.join(known)}")
        before = self.effects
        effects = [e for e in before if e in effects] + [e for e in effects if e not in before]  # the model's order
        model = self.catalogue.parse("+".join([self.base.name, *effects]))
        counter = ProgressCounter(progress, 2)
        counter.step(f"fitting {model.name}")
        fit = model.fit(self.data)
        counter.step("checking its predictions")
        score, found = headline(fit, self.data), residuals(fit, self.data)
        counter.finish()
        self.fit, self.residuals = fit, found
        added = [e for e in effects if e not in before]
        removed = [e for e in before if e not in effects]
        change = " ".join([f"+ {e}" for e in added] + [f"- {e}" for e in removed]) or "refit"
        self.history.append(HistoryEntry(change, model.name, score))
        return fit

    # -- what the screen shows --------------------------------------------------------------
    def fit_rows(self) -> list[FitRow]:
        d, f = self.diagnosis, self.fit
        if d is None or f is None:
            return []
        rows = []
        for name, p in f.model.parameters():
            v = f.values[name]
            se = f.errors.get(name, math.nan) if p.vary else math.nan
            rows.append(FitRow(name, f"{v:.5g}", "fixed" if not p.vary else f"{se:.2g}", p.unit))
        pl = d.power_law_fit
        for name in ("k", "lambda"):
            if name in pl.values:
                rows.append(FitRow(f"power law: {name}", f"{pl.values[name]:.5g}", f"{pl.errors.get(name, math.nan):.2g}", ""))
        return rows

    def bin_rows(self) -> list[BinRow]:
        found = self.residuals
        if found is None:
            return []
        rows = []
        for section, b in (("radius", found.by_radius), ("range", found.by_range)):
            for lab, lr, se, fl in zip(b.labels, b.log_ratio, b.se_log, b.flagged):
                r = float(np.exp(lr))
                rows.append(BinRow(section, lab, r, 2 * float(se) * r, bool(fl)))
        return rows

    def candidate_rows(self) -> list[CandidateRow]:
        """The diagnosis's candidates as it ranked them, in its order, whatever has been refitted since; those now in
        the model say so (after any effect of the model the diagnosis did not rank)."""
        d = self.diagnosis
        if d is None:
            return []
        model, ranked = self.effects, [c.effect.name for c in d.candidates]
        rows = [CandidateRow(e, None, False, True) for e in model if e not in ranked]
        rows += [CandidateRow(c.effect.name, None, False, True) if c.effect.name in model
                 else CandidateRow(c.effect.name, c.dbic, c.significant, False) for c in d.candidates]
        return rows

    def summary(self) -> str:
        d = self.diagnosis
        if d is None:
            return ""
        return d.summary()

    def shape(self) -> ShapeCurve | None:
        """The empirical shape of what the catalogue leaves unexplained (a sigma shape), if any."""
        d = self.diagnosis
        u = d.unexplained if d is not None else None
        step = next((s for s in u.steps if isinstance(s.term, EmpiricalSigma)), None) if u is not None else None
        if step is None or self.data is None:
            return None
        unit, read = COVARIATES[step.covariate]
        c = read(self.data)
        x = np.linspace(float(np.nanmin(c)), float(np.nanmax(c)), 40)
        m = np.exp(step.term.log_multiplier(x, step.fit.values))
        title = f"not explained: sigma x shape over {step.covariate} ({step.headline.error_pct:.2f} % after)"
        return ShapeCurve(step.covariate, unit, [float(v) for v in x], [float(v) for v in m], title)


class ProgressText:
    """A diagnosis's progress in words for the status line: what is being done, how far, and when it should end
    (the time so far per step, times the steps left)."""

    def __init__(self, what: str, clock: Callable[[], float] = time.monotonic) -> None:
        self.what, self.clock = what, clock
        self.started = clock()

    def text(self, p: WorkProgress) -> str:
        """While the work may still add steps (`more_may_come`: a diagnosis beyond noise may add effects), the
        steps and the time left are lower bounds and say so ("at least")."""
        elapsed = self.clock() - self.started
        left = elapsed / p.done * (p.total - p.done) if p.done > 0 else None
        of, about = ("at least ", "at least ") if p.more_may_come else ("", "about ")
        return (f"{self.what}: {p.task}, step {min(p.done + 1, p.total)} of {of}{p.total} ({100 * p.fraction:.0f} %), "
                f"{format_duration(elapsed)} so far, {about}{format_duration(left)} left")
