"""Where the model fails, and which missing physical effects most likely explain it.

`diagnose(data)` fits the model (by default the physical one: `active` with the projector on,
`passive` without) and checks every statistic it predicts (`rig.diagnosis.consistency`). While
something is beyond noise, it tries every applicable effect of the catalogue not yet in the
model (the built-in ones, installed plugins' and the user's: `rig.models.Catalogue`), ranks them
by evidence (the drop in BIC and the likelihood-ratio p-value, `rig.diagnosis.candidates`),
adds the most likely one, and goes on from there: the path shows each step's model, headline
error and BIC change. An effect is significant when BIC falls by more than 10 (very strong
evidence) and p < 0.001; with hundreds of millions of samples, effects too small to matter are
still significant, so one is added only while the model without it is beyond noise.

Effects that fit the data about equally well (an improvement within 2 % of the best) cannot
be told apart by the fit; among them the one with fewer free parameters is preferred, because
it predicts the size of the effect from geometry or a measurement (the projector-off frames,
the per-frame series, the depth unit) instead of fitting it.

When no significant effect is left and the model is still beyond noise, the missing effect is
not in the catalogue: the diagnosis says so, finds what the residual follows and fits an
empirical shape to it (`rig.diagnosis.unexplained`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..models import BASES, Catalogue, Model, ModelData, ModelFit, fit_power_law, with_errors, with_exact_loglik
from ..models.data.independence import Independence, independence
from ..models.fitting.progress import ProgressCounter, ProgressFn
from .candidates import (MATERIAL_FRACTION, SIGNIFICANT_DBIC, SIGNIFICANT_P, Candidate, applicable_candidates, choose,
                         material, rank_candidates)
from .residuals import Residuals, residuals
from .scores import Headline, headline
from .unexplained import Unexplained, explain_residual

#: at most this many catalogue effects are added, one at a time
MAX_STEPS = 4


@dataclass
class Step:
    """One model on the diagnosis's path: its fit, headline, the effect that made it, and the ranking made from it."""

    fit: ModelFit
    headline: Headline
    added: Candidate | None = None
    equivalent: list[Candidate] = field(default_factory=list)
    candidates: list[Candidate] = field(default_factory=list)  # effects tried on top of this model
    not_fitted: list[tuple[str, str]] = field(default_factory=list)  # effects whose fit failed, and why

    @property
    def name(self) -> str:
        return self.fit.model.name


@dataclass
class Diagnosis:
    source: str
    data: ModelData
    steps: list[Step]
    power_law_fit: ModelFit
    residuals: Residuals  # of the starting model
    unexplained: Unexplained | None = None
    catalogue_stopped: str = ""  # why the catalogue's path stopped, in words

    @property
    def stopped(self) -> str:
        """Why the whole path stopped, in words."""
        if self.unexplained is not None and self.unexplained.stopped:
            return self.unexplained.stopped
        return self.catalogue_stopped

    # -- the start, the first effect and the end --------------------------------------------
    @property
    def model_fit(self) -> ModelFit:
        return self.steps[0].fit

    @property
    def model_headline(self) -> Headline:
        return self.steps[0].headline

    @property
    def candidates(self) -> list[Candidate]:
        return self.steps[0].candidates

    @property
    def best(self) -> Candidate | None:
        return self.steps[1].added if len(self.steps) > 1 else None

    @property
    def equivalent(self) -> list[Candidate]:
        return self.steps[1].equivalent if len(self.steps) > 1 else []

    @property
    def refit_headline(self) -> Headline | None:
        return self.steps[1].headline if len(self.steps) > 1 else None

    @property
    def after_best(self) -> list[Candidate]:
        return [c for c in self.steps[1].candidates if c.significant] if len(self.steps) > 1 else []

    @property
    def added(self) -> list[str]:
        """The catalogue effects the path added, in order."""
        return [s.added.effect.name for s in self.steps[1:] if s.added is not None]

    @property
    def catalogue_fit(self) -> ModelFit:
        """The last model of the path: the start plus every catalogue effect added."""
        return self.steps[-1].fit

    @property
    def catalogue_headline(self) -> Headline:
        return self.steps[-1].headline

    @property
    def final_fit(self) -> ModelFit:
        return self.unexplained.final_fit if self.unexplained is not None else self.catalogue_fit

    @property
    def final_headline(self) -> Headline:
        return self.unexplained.final_headline if self.unexplained is not None else self.catalogue_headline

    @property
    def independence(self) -> Independence:
        """Whether the recording's frames are independent samples (`rig.models.data.independence`)."""
        return independence(self.data.stops)

    # -- words ------------------------------------------------------------------------------
    def summary(self) -> str:
        """A few plain sentences: what is missing, or that nothing is, and what remains; first, when the frames are
        not independent, that (no model assumes otherwise, so nothing else is trustworthy)."""
        ind = self.independence
        first = ind.sentence() + " " if ind.correlated else ""
        return first + self._summary()

    def _summary(self) -> str:
        m = self.model_fit.model.name
        if not self.model_headline.judged:
            return (f"Nothing can be judged on these data: {self.model_headline.verdict().removeprefix('NOT JUDGED: ')}"
                    f" ({len(self.data)} pixel-stops in all).")
        shape = _shape_sentence(self.model_headline)
        if len(self.steps) == 1:
            if self.model_headline.within_noise:
                minor = [c.effect.name for c in self.candidates if c.significant]
                if minor:
                    return (f"Nothing material is missing from {m}: its headline error is {self.model_headline}. "
                            f"({', '.join(minor)} would raise the likelihood a little, but the model already fits to "
                            "within sampling noise.)")
                return (f"Nothing significant is missing from {m}: no effect lowers BIC by more than "
                        f"{-SIGNIFICANT_DBIC:g}; the headline error is {self.model_headline}.")
            s = (f"{m} is beyond noise ({self.model_headline}){shape}, and no effect of the catalogue explains it "
                 "(none lowers BIC significantly).")
            return s + self._unexplained_sentence()
        first = self.steps[1].added
        e = first.effect
        s = f"Most likely missing: {e.name}. {e.signature[0].upper() + e.signature[1:]}: {e.explanation.rstrip('.')}."
        others = [c.effect.name for c in self.steps[1].equivalent if c is not first]
        if others:
            s += (f" ({', '.join(others)} fits about as well; {e.name} is preferred because it "
                  f"{'has no free parameter' if not first.fit.n_free - self.model_fit.n_free else 'has fewer free parameters'}.)")
        s += shape
        if len(self.steps) > 2:
            s += " Then: " + ", then ".join(f"{st.added.effect.name} ({st.added.effect.explanation})" for st in self.steps[2:]) + "."
        last = self.steps[-1]
        if last.headline.within_noise:
            s += f" With {last.name} every statistic is within noise (headline error {last.headline.error_pct:.2f} %)."
        else:
            s += f" With {last.name} the model is still beyond noise ({last.headline.verdict()})."
            s += self._unexplained_sentence()
        return s

    def _unexplained_sentence(self) -> str:
        u = self.unexplained
        if u is None:
            return ""
        if not u.steps:
            return " The missing effect is not in the catalogue, and no empirical shape could be fitted to it."
        first = u.steps[0]
        also = f" (equally well: {', '.join(first.equivalent)})" if first.equivalent else ""
        s = (f" Not explained by the catalogue: what remains ({first.family}) follows {first.covariate}{also}. "
             f"An empirical shape over {first.covariate} (rig fit --model '{u.steps[0].fit.model.name}')")
        for st in u.steps[1:]:
            s += (f", then over {st.covariate} (for {st.family})" if st.is_empirical else
                  f", then {st.added} (the catalogue tried again on top of the shapes)")
        h = u.final_headline
        s += f" brings the headline error to {h.error_pct:.2f} %: " + (
            "every statistic within noise." if h.within_noise else f"still beyond noise ({h.verdict()}).")
        return s + " Write the physics as an effect (docs/effects.md) to replace it."


def _shape_sentence(h: Headline) -> str:
    """A sentence when the distribution's shape (kurtosis) is wrong, not only its width."""
    c = h.consistency.find("kurtosis", "range") if h.consistency is not None else None
    if c is None or c.p_value >= h.consistency.threshold_with(1):
        return ""
    i = c.worst()
    kind = ("heavier tails than the model's (mismatches, a mixture of noise levels)" if c.measured[i] > c.predicted[i]
            else "lighter tails than the model's (samples cut off, as censoring does)")
    return (f" The distribution's shape is wrong too: kurtosis {c.measured[i]:.2f} measured against "
            f"{c.predicted[i]:.2f} predicted at {c.labels[i]} (+/- {c.se[i]:.2f}): {kind}.")


def default_model(d: ModelData) -> Model:
    """The physical base for the data: active (lambda = 3) with the projector on, passive (lambda = 2) without."""
    return Model(BASES["active"] if d.projector_on.mean() > 0.5 else BASES["passive"])


def base_mismatch(model: Model, d: ModelData) -> str | None:
    """A note when the model's base does not fit how the recording was made: `active` (lambda = 3, projected
    light) on a recording with the projector off at every stop, or `passive` (lambda = 2) with it on at every
    stop; None otherwise."""
    lam, on = model.base.lam, d.projector_on
    if lam == 3.0 and len(on) and not on.any():
        return (f"{model.base.name} assumes the projector is on (lambda = 3: the projected light falls as 1/Z^2), but "
                "this recording was made with the projector off (passive stereo): fit passive (lambda = 2) or power_law instead, "
                f"e.g. --model {model.name.replace(model.base.name, 'passive', 1)}")
    if lam == 2.0 and len(on) and on.all():
        return (f"{model.base.name} assumes constant light (lambda = 2, passive stereo), but this recording was made "
                "with the projector on: fit active (lambda = 3) or power_law instead, "
                f"e.g. --model {model.name.replace(model.base.name, 'active', 1)}")
    return None


def diagnose(d: ModelData, model: Model | None = None, *, source: str = "", catalogue: Catalogue | None = None,
             max_steps: int = MAX_STEPS, explain: bool = True, second_round: bool | None = None,
             progress: ProgressFn | None = None, jobs: int = 1) -> Diagnosis:
    """Fit `model`, add missing catalogue effects one at a time (at most `max_steps`), then, with `explain`,
    describe what remains beyond noise with empirical terms. `second_round=False` is `max_steps=1`.
    `progress` is told of each fit as it begins (`rig.models.fitting.progress`); the candidate effects are fitted in
    `jobs` processes (`rig.models.parallel`)."""
    if second_round is False:
        max_steps = 1
    catalogue = catalogue or Catalogue.default()
    model = model or default_model(d)
    # the steps known now: the model, the power law, one fit per candidate effect, the residuals
    counter = ProgressCounter(progress, 3 + len(applicable_candidates(model, d, catalogue)))
    counter.more_may_come = True  # until the model's fit says whether it is within noise
    counter.step(f"fitting {model.name}")
    fit = model.fit(d)
    steps = [Step(fit, headline(fit, d))]
    # beyond noise, the diagnosis may add effects and empirical terms: steps not counted yet
    counter.more_may_come = not steps[0].headline.within_noise and (max_steps > 0 or explain)
    counter.step("fitting power_law")
    pl = fit_power_law(d)  # the paper's fit, for reference: closed form
    steps[0].candidates = rank_candidates(model, fit, d, catalogue, counter=counter, jobs=jobs,
                                          not_fitted=steps[0].not_fitted)  # shown even when nothing is missing
    stopped = "every statistic is within noise"
    if not steps[0].headline.judged:
        stopped = "nothing can be judged: no range-and-radius bin holds enough pixels"
    while not steps[-1].headline.within_noise and steps[-1].headline.judged:
        if len(steps) > max_steps:
            stopped = f"{max_steps} catalogue effects are in, the most the path adds before empirical terms"
            break
        current = steps[-1]
        if len(steps) > 1:
            counter.expect(1 + len(applicable_candidates(current.fit.model, d, catalogue)))
            current.candidates = rank_candidates(current.fit.model, current.fit, d, catalogue, counter=counter, jobs=jobs,
                                                 not_fitted=current.not_fitted)
        best, equivalent = choose(current.candidates)
        if best is None:
            stopped = f"no catalogue effect lowers BIC by more than {-SIGNIFICANT_DBIC:g} with p < {SIGNIFICANT_P:g}"
            break
        after = headline(best.fit, d)
        if not material(after.misfit, current.headline.misfit):
            # significant, but it leaves what is wrong where it was: not the missing effect
            stopped = (f"{best.effect.name}, the most likely effect left, removes less than {MATERIAL_FRACTION:.0%} of "
                       "the misfit")
            break
        best.fit = with_exact_loglik(with_errors(best.fit, d), d)  # a candidate's was its grouped nodes' (candidates)
        steps.append(Step(best.fit, after, best, equivalent))
        counter.more_may_come = not after.within_noise and (len(steps) <= max_steps or explain)
    unexplained = None
    if explain and not steps[-1].headline.within_noise and steps[-1].headline.judged:
        unexplained = explain_residual(steps[-1].fit, steps[-1].headline, d, counter=counter, jobs=jobs,
                                       catalogue=catalogue)
    counter.more_may_come = False
    counter.step("residuals")
    result = Diagnosis(source, d, steps, pl, steps[0].headline.residuals or residuals(fit, d), unexplained, stopped)
    counter.finish()
    return result
