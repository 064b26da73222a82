"""Where the model fails, and which missing physical effect most likely explains it.

`diagnose(data)` fits the model (by default the physical one: `active` with the projector on,
`passive` without), tries every applicable effect not in it, and ranks them by evidence:
the drop in BIC and the likelihood-ratio p-value. An effect is significant when BIC falls by
more than 10 (very strong evidence) and p < 0.001. It is reported as missing only if the
model without it is off by more than sampling noise (see `rig.diagnosis.scores`): with
hundreds of millions of samples, effects too small to matter are still significant.

Effects that fit the data about equally well (an improvement within 2 % of the best) cannot
be told apart by the fit; among them the one with fewer free parameters is preferred, because
it predicts the size of the effect from geometry or a measurement (the projector-off frames,
the per-frame series, the depth unit) instead of fitting it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..models import BASES, Model, ModelData, ModelFit, power_law
from .candidates import SIGNIFICANT_DBIC, Candidate, choose, rank_candidates
from .scores import Headline, headline
from .residuals import Residuals, residuals


@dataclass
class Diagnosis:
    source: str
    data: ModelData
    model_fit: ModelFit
    power_law_fit: ModelFit
    model_headline: Headline
    candidates: list[Candidate]
    best: Candidate | None
    equivalent: list[Candidate]
    refit_headline: Headline | None
    residuals: Residuals
    after_best: list[Candidate] = field(default_factory=list)

    def summary(self) -> str:
        """One or two plain sentences: what is missing, or that nothing is."""
        m = self.model_fit.model.name
        if self.best is None:
            minor = [c.effect.name for c in self.candidates if c.significant]
            if minor:
                return (f"Nothing material is missing from {m}: its headline error is {self.model_headline}. "
                        f"({', '.join(minor)} would raise the likelihood a little, but the model already fits to within sampling noise.)")
            return (f"Nothing significant is missing from {m}: no effect lowers BIC by more than "
                    f"{-SIGNIFICANT_DBIC:g}; the headline error is {self.model_headline}.")
        e = self.best.effect
        s = f"Most likely missing: {e.name}. {e.signature[0].upper() + e.signature[1:]}: {e.explanation}."
        others = [c.effect.name for c in self.equivalent if c is not self.best]
        if others:
            s += (f" ({', '.join(others)} fits about as well; {e.name} is preferred because it "
                  f"{'has no free parameter' if not self.best.fit.n_free - self.model_fit.n_free else 'has fewer free parameters'}.)")
        return s


def default_model(d: ModelData) -> Model:
    """The physical base for the data: active (lambda = 3) with the projector on, passive (lambda = 2) without."""
    return Model(BASES["active"] if d.projector_on.mean() > 0.5 else BASES["passive"])


def diagnose(d: ModelData, model: Model | None = None, *, source: str = "", second_round: bool = True) -> Diagnosis:
    model = model or default_model(d)
    base = model.fit(d)
    pl = base if model.name == "power_law" else Model(power_law).fit(d)
    cands = rank_candidates(model, base, d)
    base_head = headline(base, d)
    best, equivalent = choose(cands)
    if base_head.within_noise:
        # significant but immaterial: the model already describes the error to within sampling noise
        best, equivalent = None, []
    refit_head = headline(best.fit, d) if best else None
    after: list[Candidate] = []
    if best is not None and second_round:
        after = [c for c in rank_candidates(best.fit.model, best.fit, d) if c.significant]
    return Diagnosis(source, d, base, pl, base_head, cands, best, equivalent, refit_head,
                     residuals(base, d), after)
