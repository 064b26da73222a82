"""When the catalogue's effects leave the model beyond noise: what the residual follows, and its shape.

The families the verdict finds beyond noise (`rig.diagnosis.consistency`) say what kind of
statistic is wrong. For sigma, every empirical shape that could follow it (range, radius, image
position, IR brightness, incidence; `rig.models.effects.empirical`) is fitted on top of the model, and
the one that lowers BIC most is the covariate the residual follows; shapes within
TIE_FRACTION of it are reported as equivalent (radius and incidence are one covariate on a
perpendicular wall). A wrong kurtosis gets empirical tails, a wrong fill rate an empirical fill
gain, a frame mean wandering more than independent pixels allow an empirical correlation
(`empirical(time)`). Terms are added one at a time, worst family first, until every statistic
is within noise or MAX_TERMS are in; a second or third sigma shape (over a covariate neither in
nor tied with the ones in) only when it lowers BIC by more than 10 (`SIGNIFICANT_DBIC`). A shape
whose coefficients the data do not determine (no finite error, `rig.models.undetermined`) is not
added. After every term, every catalogue effect not in the model is tried again on top of it
(`rig.diagnosis.candidates`): a term can take away what hid an effect (rounding to the depth unit
under a beam's shape), and a physical effect found then is added as the catalogue path adds one.
The path says why it stopped (`Unexplained.stopped`). The result is a calibrated model that says
what shape the missing effect has, before anyone knows its physics.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from ..models import Catalogue, Effect, ModelData, ModelFit, empirical, undetermined, with_errors
from ..models.effects.empirical import EmpiricalFrameMean, is_empirical
from ..models.parallel import fit_models
from ..models.fitting.progress import ProgressCounter
from .candidates import SIGNIFICANT_DBIC, Candidate, applicable_candidates, choose, material, rank_candidates
from .consistency import Check
from .scores import Headline, headline

MAX_TERMS = 3
#: sigma shapes fitted for a sigma residual
SHAPES_TRIED = 4
#: shapes whose BIC gain is within this fraction of the best one's are equivalent
TIE_FRACTION = 0.02
#: why an intermediate model of the empirical path has no standard errors (`ModelFit.error_notes`)
INTERMEDIATE = ("not computed: an intermediate model of the diagnosis's empirical path (the final model carries its "
                "errors; rig fit --model with this model gives these)")
#: when two shapes are equivalent, name them in this order (the simplest reading first)
SIGMA_SHAPES = ("range", "radius", "slant", "position", "brightness", "incidence")
#: what each failing family asks for
FAMILY_SHAPE = {"kurtosis": "tails", "fill rate": "fill", "frame-mean variance": "time"}


@dataclass
class ShapeTrial:
    """One empirical shape tried on top of the model."""

    covariate: str
    fit: ModelFit | None
    dbic: float
    why_not: str = ""


@dataclass
class EmpiricalStep:
    """One term added after the catalogue's path: an empirical shape (which family asked for it, what was tried,
    what it did), or a catalogue effect found when the catalogue was tried again on top of the shapes (`candidate`)."""

    family: str  # the check that was worst ("sigma by radius", "kurtosis by range", ...); "catalogue" for an effect
    covariate: str  # the shape chosen; "" for a catalogue effect
    term: Effect
    fit: ModelFit
    headline: Headline
    trials: list[ShapeTrial] = field(default_factory=list)
    candidate: Candidate | None = None  # the catalogue effect this step added, with its evidence
    equivalent_effects: list[Candidate] = field(default_factory=list)
    held: list[str] = field(default_factory=list)  # the shape's coefficients the data do not determine, held at start

    @property
    def added(self) -> str:
        """What this step added: `empirical(radius)`, or a catalogue effect's name."""
        return self.term.name

    @property
    def is_empirical(self) -> bool:
        return self.candidate is None

    @property
    def equivalent(self) -> list[str]:
        """Other covariates whose shape fits about as well (the data cannot tell them apart)."""
        if self.candidate is not None:
            return [c.effect.name for c in self.equivalent_effects if c is not self.candidate]
        best = next((t for t in self.trials if t.covariate == self.covariate), None)
        if best is None or best.fit is None:
            return []
        tol = max(10.0, TIE_FRACTION * abs(best.dbic))
        return [t.covariate for t in self.trials
                if t.fit is not None and t.covariate != self.covariate and t.dbic <= best.dbic + tol]


@dataclass
class Unexplained:
    """What remains after the catalogue: the model it starts from, and the empirical terms that describe it."""

    start_fit: ModelFit
    start_headline: Headline
    steps: list[EmpiricalStep]
    stopped: str = ""  # why the path stopped, in words
    rejected: list[ShapeTrial] = field(default_factory=list)  # shapes chosen but not added (`ShapeTrial.why_not`)

    @property
    def covariate(self) -> str:
        """The covariate the remaining residual follows most strongly (the first term's)."""
        return self.steps[0].covariate if self.steps else ""

    @property
    def empirical_steps(self) -> list[EmpiricalStep]:
        return [s for s in self.steps if s.is_empirical]

    @property
    def final_fit(self) -> ModelFit:
        return self.steps[-1].fit if self.steps else self.start_fit

    @property
    def final_headline(self) -> Headline:
        return self.steps[-1].headline if self.steps else self.start_headline


def _shapes_for(check: Check | None, head: Headline) -> tuple[str, list[str]]:
    """(family name, shapes to try) for the worst failing family. For sigma, the SHAPES_TRIED covariates whose
    own checks are furthest beyond noise (a shape over a covariate the checks show flat cannot win)."""
    if check is None or check.quantity == "sigma":
        cons = head.consistency

        def excess(cov: str) -> float:
            if cov == "slant":  # no check of its own: the ray's length is range and radius together
                return max(excess("range"), excess("radius"))
            c = cons.find("sigma", cov) if cons is not None else None
            return c.excess_z if c is not None else float("-inf")

        ranked = sorted(SIGMA_SHAPES, key=lambda cov: -excess(cov))[:SHAPES_TRIED]
        return (check.name if check is not None else "sigma by range and radius"), [s for s in SIGMA_SHAPES if s in ranked]
    # no shape makes frames independent (lag-1 correlation): nothing to try for that family
    return check.name, [FAMILY_SHAPE[check.quantity]] if check.quantity in FAMILY_SHAPE else []


def explain_residual(fit: ModelFit, head: Headline, d: ModelData, *, counter: ProgressCounter | None = None,
                     jobs: int = 1, catalogue: Catalogue | None = None) -> Unexplained:
    """Add empirical terms to `fit`'s model, worst failing family first, until within noise (or MAX_TERMS). When no
    further shape can be added and the model is still beyond noise, every catalogue effect not in the model is
    tried again on top of the shapes (`catalogue`, the default one if None); the most likely one is added when it
    is significant and removes a material share of the misfit, and the path goes on from there."""
    counter = counter or ProgressCounter(None, 1)
    out = Unexplained(fit, head, [])
    current_fit, current_head = fit, head
    tried: set[str] = set()
    while True:
        if current_head.within_noise:
            out.stopped = "every statistic is within noise"
            break
        if len(out.empirical_steps) < MAX_TERMS:
            shape = _next_shape(out, current_fit, current_head, d, tried, counter, jobs)
        else:
            shape = f"{MAX_TERMS} empirical terms are in, the most the path adds"
        if not isinstance(shape, str):
            current_fit, current_head = shape.fit, shape.headline
            out.steps.append(shape)
            continue
        # no shape to add: before stopping beyond noise, every catalogue effect not in the model is tried again on
        # top of the shapes (the catalogue's own path tried them on `fit`, without)
        again = _catalogue_again(current_fit, current_head, d, catalogue, counter, jobs) if out.steps else None
        if again is None:
            out.stopped = shape + ("; no catalogue effect, tried again on top of the shapes, is significant and material"
                                   if out.steps else "")
            break
        current_fit, current_head = again.fit, again.headline
        out.steps.append(again)
    if len(out.steps) > 1 and not current_head.within_noise:
        # the terms were fitted one at a time; a last refit with everything free lets each settle with the others
        counter.step(f"refitting {current_fit.model.name} with every parameter free")
        joint = current_fit.model.fit(d, start=current_fit.values, errors=False)
        if joint.loglik > current_fit.loglik:
            last = out.steps[-1]
            last.fit, last.headline = joint, headline(joint, d)
            if last.headline.within_noise:
                out.stopped = "every statistic is within noise once every parameter is refitted together"
    # standard errors for the final model only: the Hessian of a model with three shapes (19 parameters) is 760
    # likelihoods, and the intermediate models' were half of a noisy_confidence diagnosis; their fits say why not
    for step in out.steps[:-1]:
        step.fit = replace(step.fit, error_notes={n: INTERMEDIATE for n, _ in step.fit.model.free()})
    if out.steps:
        out.steps[-1].fit = with_errors(out.steps[-1].fit, d)
    return out


def _next_shape(out: Unexplained, current_fit: ModelFit, current_head: Headline, d: ModelData, tried: set[str],
                counter: ProgressCounter, jobs: int) -> EmpiricalStep | str:
    """The empirical shape to add next, refitted with the model's own parameters free, or why there is none, in
    words. Adds the shapes it rules out to `tried`."""
    reason = ""
    while True:
        cons = current_head.consistency
        failing = cons.failing(extra=1) if cons is not None else []
        if not current_head.sigma_within_noise and not any(c.quantity == "sigma" for c in failing):
            # the headline bins (sigma by range and radius), in their place by how far beyond noise they are
            z = (current_head.chi2 - current_head.dof) / max(2 * current_head.dof, 2) ** 0.5
            at = next((i for i, c in enumerate(failing) if c.excess_z < z), len(failing))
            failing = [*failing[:at], None, *failing[at:]]
        family, shapes = "", []
        for check in failing:  # the worst family that still has a shape to try
            family, shapes = _shapes_for(check, current_head)
            shapes = [s for s in shapes if s not in tried]
            if shapes:
                break
        if not shapes:
            return reason or "no empirical shape is left to try for the statistics beyond noise"
        trials = _fit_shapes(shapes, current_fit, d, counter, jobs)
        usable = [t for t in trials if t.fit is not None]
        if not usable:
            return "no empirical shape could be fitted"
        best = min(usable, key=lambda t: t.dbic)
        if best.covariate in SIGMA_SHAPES and any(s.covariate in SIGMA_SHAPES for s in out.steps) and not best.dbic < SIGNIFICANT_DBIC:
            # a further sigma shape only when it lowers BIC significantly: else it would fit the first one's noise
            tried.update(SIGMA_SHAPES)
            reason = f"no further sigma shape lowers BIC by more than {-SIGNIFICANT_DBIC:g}"
            continue
        tol = max(10.0, TIE_FRACTION * abs(best.dbic))
        order = {s: i for i, s in enumerate(shapes)}
        tied = [t for t in usable if t.dbic <= best.dbic + tol]
        chosen = min(tied, key=lambda t: order[t.covariate])
        tried.update(t.covariate for t in tied)  # the shapes the data cannot tell from it are the same reading
        tried.add(chosen.covariate)
        # coefficients the data do not determine would follow the noise: such a shape is reduced to the ones they do
        # (the others held at their neutral start, no change there), and not added when none is left
        name = f"empirical({chosen.covariate})"
        term = chosen.fit.model.effects[[e.name for e in chosen.fit.model.effects].index(name)]
        own = [n for n, _ in chosen.fit.model.free() if n.startswith(name + ".")]
        flat = undetermined(chosen.fit, d, own)
        if own and len(flat) == len(own):  # (a measured term, empirical(time), has no coefficient to determine)
            chosen.why_not = f"not added: the data do not determine {', '.join(sorted(flat))} (the likelihood is flat along them)"
            if chosen.covariate not in {r.covariate for r in out.rejected}:
                out.rejected.append(chosen)
            reason = f"{name} was {chosen.why_not}"
            continue
        start = dict(chosen.fit.values)
        if flat:
            held = {n.removeprefix(name + ".") for n in flat}
            term.params = tuple(replace(q, vary=False) if q.name in held else q for q in term.params)  # type: ignore[misc]
            start.update({f"{name}.{q.name}": q.value for q in term.params if q.name in held})
        # refit with the model's own parameters free too (earlier empirical terms held: they describe, not explain)
        counter.step(f"refitting {chosen.fit.model.name}")
        earlier = frozenset(n for e in current_fit.model.effects if is_empirical(e) for n in chosen.fit.values
                            if n.startswith(e.name + "."))
        refit = chosen.fit.model.fit(d, start=start, errors=False, hold=earlier)
        step = EmpiricalStep(family, chosen.covariate, term, refit, headline(refit, d), trials)
        step.held = sorted(flat)
        return step


def _fit_shapes(shapes: list[str], current_fit: ModelFit, d: ModelData, counter: ProgressCounter,
                jobs: int) -> list[ShapeTrial]:
    """Each shape fitted on top of `current_fit` with only its own parameters free, in the order of `shapes`."""
    trials = []
    counter.expect(len(shapes) + 1)
    fitting: list[tuple[str, Effect]] = []
    for covariate in shapes:
        term = empirical(covariate)
        why = term.applicable(d)
        if why:
            trials.append(ShapeTrial(covariate, None, float("inf"), why))
            continue
        if isinstance(term, EmpiricalFrameMean):
            term.measure(current_fit.predict(d), d)  # measured against the model it joins, not fitted
        else:
            term.start(d, None)  # its knots, from these data, before any worker fits it
        fitting.append((covariate, term))
    if fitting:
        counter.step(f"fitting an empirical shape over {fitting[0][0]}")

    finished = [0]

    def done(i: int) -> None:
        finished[0] += 1
        if finished[0] < len(fitting):
            counter.step(f"fitting an empirical shape over {fitting[i + 1][0]}" if jobs <= 1 else
                         f"fitting empirical shapes ({finished[0]} of {len(fitting)} done)")

    # only the shape's own parameters free: a quick, fair comparison of the shapes
    fits = fit_models([current_fit.model + term for _, term in fitting], d, current_fit.values, jobs=jobs,
                      hold=frozenset(current_fit.values), done=done)
    for (covariate, _), f in zip(fitting, fits):
        if isinstance(f, ValueError):
            trials.append(ShapeTrial(covariate, None, float("inf"), str(f)))
        else:
            trials.append(ShapeTrial(covariate, f, f.bic - current_fit.bic))
    trials.sort(key=lambda t: shapes.index(t.covariate))
    return trials


def _catalogue_again(current_fit: ModelFit, current_head: Headline, d: ModelData, catalogue: Catalogue | None,
                     counter: ProgressCounter, jobs: int) -> EmpiricalStep | None:
    """Every catalogue effect not in the model, fitted on top of it with the empirical terms held (a fair, quick
    ranking: `rig.diagnosis.candidates`); the most likely one, refitted with every parameter but the earlier terms'
    free, as a step when it is significant and removes a material share of the misfit, else None."""
    model = current_fit.model
    n = len(applicable_candidates(model, d, catalogue))
    if not n:
        return None
    counter.expect(n + 2)
    shapes = frozenset(v for e in model.effects if is_empirical(e) for v in current_fit.values if v.startswith(e.name + "."))
    candidates = rank_candidates(model, current_fit, d, catalogue, counter=counter, jobs=jobs, hold=shapes)
    best, equivalent = choose(candidates)
    if best is None:
        return None
    counter.step(f"refitting {best.fit.model.name}")
    fit = best.fit.model.fit(d, start=best.fit.values, errors=False, hold=shapes)
    after = headline(fit, d)
    if not material(after.misfit, current_head.misfit):
        return None  # significant, but it leaves what is wrong where it was
    return EmpiricalStep("catalogue", "", best.effect, fit, after, [], best, equivalent)
