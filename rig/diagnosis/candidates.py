"""Candidate effects, ranked by evidence: the drop in BIC and the likelihood-ratio p-value.

An effect is significant when BIC falls by more than 10 (very strong evidence) and p < 0.001.
On data large enough to be grouped (`rig.models.fitting.grouping`), each candidate is compared with the model it extends on
the candidate's grouped nodes, both log-likelihoods of the same nodes, not every pixel's: that took a pass over all
of them per candidate (0.2-0.4 s each on a full sweep; its diagnosis 30.9-33.3 -> 22.2-23.8 s of CPU). The
statistics stay every pixel's within a hundredth of their own sampling spread (tests/test_grouping.py; on the full
sweep they moved by 0.0006-0.05, the path and the final model the same). The chosen effect's fit then gets every
pixel's log-likelihood back (`rig.diagnosis.verdict`), so the path's and the report's figures are every pixel's.
Effects that fit the data about equally well (an improvement within 2 % of the best) cannot be
told apart by the fit; among them the one with fewer free parameters is preferred, because it
predicts the size of the effect from geometry or a measurement (the projector-off frames, the
per-frame series, the depth unit) instead of fitting it.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..models import Catalogue, Effect, Model, ModelData, ModelFit, likelihood_ratio
from ..models.fitting.optimise import loglik_on_nodes_of
from ..models.parallel import fit_models
from ..models.fitting.progress import ProgressCounter

SIGNIFICANT_DBIC = -10.0
SIGNIFICANT_P = 1e-3
EQUIVALENT_FRACTION = 0.02
#: an effect is added only if it removes at least this share of the misfit (`Headline.misfit`): with
#: millions of samples, an effect can be significant and still leave the error where it was
MATERIAL_FRACTION = 0.3


def material(after_misfit: float, before_misfit: float) -> bool:
    """An added effect removes at least MATERIAL_FRACTION of the misfit (`Headline.misfit`) it was added against."""
    return not after_misfit > (1 - MATERIAL_FRACTION) * before_misfit  # (a NaN misfit counts as material, as before)


@dataclass
class Candidate:
    effect: Effect
    fit: ModelFit
    dbic: float
    lrt: float
    df: int
    p_value: float

    @property
    def significant(self) -> bool:
        return self.dbic < SIGNIFICANT_DBIC and self.p_value < SIGNIFICANT_P


def applicable_candidates(model: Model, d: ModelData, catalogue: Catalogue | None = None) -> list[Effect]:
    """The effects of the catalogue not yet in `model` that can be fitted to `d`."""
    have = {x.name for x in model.effects}
    return [e for e in (catalogue or Catalogue.default()).candidates() if e.name not in have and not e.applicable(d)]


def rank_candidates(model: Model, base: ModelFit, d: ModelData, catalogue: Catalogue | None = None, *,
                    counter: ProgressCounter | None = None, jobs: int = 1,
                    not_fitted: list[tuple[str, str]] | None = None,
                    hold: frozenset[str] = frozenset()) -> list[Candidate]:
    """Every applicable effect of the catalogue not yet in `model`, fitted with it (in `jobs` processes; the
    parameters in `hold` held at `base`'s values), best (lowest BIC) first. An effect whose fit fails is left out of
    the ranking, and (effect name, why) is added to `not_fitted` if given, for the report to say."""
    effects = applicable_candidates(model, d, catalogue)
    models = [model + e for e in effects]
    if counter is not None and models:
        counter.step(f"fitting {models[0].name}")

    finished = [0]

    def done(i: int) -> None:
        finished[0] += 1
        if counter is not None and finished[0] < len(models):
            counter.step(f"fitting {models[i + 1].name}" if jobs <= 1 else
                         f"fitting candidate effects ({finished[0]} of {len(models)} done)")

    out = []
    for e, m, f in zip(effects, models, fit_models(models, d, base.values, jobs=jobs, done=done, exact_loglik=False, hold=hold)):
        if isinstance(f, ValueError):  # this effect cannot be fitted to these data
            if not_fitted is not None:
                not_fitted.append((e.name, str(f) or type(f).__name__))
            continue
        ref = loglik_on_nodes_of(base, m, d)  # on what the candidate was fitted on, whose log-likelihood it reports
        stat, df, p = likelihood_ratio(ref, f)
        out.append(Candidate(e, f, f.bic - ref.bic, stat, df, p))
    out.sort(key=lambda c: c.dbic)
    return out


def choose(candidates: list[Candidate]) -> tuple[Candidate | None, list[Candidate]]:
    """The most likely missing effect and the candidates that fit about equally well."""
    sig = [c for c in candidates if c.significant]
    if not sig:
        return None, []
    top = sig[0].dbic
    tol = max(-SIGNIFICANT_DBIC, EQUIVALENT_FRACTION * abs(top))
    equivalent = [c for c in sig if c.dbic <= top + tol]
    best = min(equivalent, key=lambda c: (c.fit.n_free, c.dbic))
    return best, equivalent
