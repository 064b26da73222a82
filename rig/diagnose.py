"""Where the model fails, and which missing physical effect most likely explains it.

`diagnose(data)` fits the model (by default the physical one: `active` with the projector on,
`passive` without), tries every applicable effect not in it, and ranks them by evidence:
the drop in BIC and the likelihood-ratio p-value. An effect is significant when BIC falls by
more than 10 (very strong evidence) and p < 0.001. It is reported as missing only if the
model without it is off by more than sampling noise (see `rig.metrics.headline`): with
hundreds of millions of samples, effects too small to matter are still significant.

Effects that fit the data about equally well (an improvement within 2 % of the best) cannot
be told apart by the fit; among them the one with fewer free parameters is preferred, because
it predicts the size of the effect from geometry or a measurement (the projector-off frames,
the per-frame series, the depth unit) instead of fitting it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .metrics import BinComparison, Headline, compare_bins, headline, range_bins
from .models import BASES, EFFECTS, Effect, Model, ModelData, ModelFit, likelihood_ratio, power_law

SIGNIFICANT_DBIC = -10.0
SIGNIFICANT_P = 1e-3
EQUIVALENT_FRACTION = 0.02


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


@dataclass
class Residuals:
    """Measured against predicted sigma by range, radius, brightness, incidence, and kurtosis by range."""

    by_range: BinComparison
    by_radius: BinComparison
    by_brightness: BinComparison | None
    by_incidence: BinComparison | None
    image_map: np.ndarray  # ln(measured / predicted sigma) on a coarse grid over the image
    fill_by_stop: list[tuple[str, float, float]]  # (stop, measured fill, predicted fill)


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


def rank_candidates(model: Model, base: ModelFit, d: ModelData) -> list[Candidate]:
    out = []
    for name, e in EFFECTS.items():
        if name in (x.name for x in model.effects) or e.applicable(d):
            continue
        m = model + e
        try:
            f = m.fit(d, start=base.values)
        except ValueError:
            continue
        stat, df, p = likelihood_ratio(base, f)
        out.append(Candidate(e, f, f.bic - base.bic, stat, df, p))
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


def residuals(fit: ModelFit, d: ModelData) -> Residuals:
    pred = fit.predict(d)
    r_bin, r_labels = range_bins(d.z_m)
    by_range = compare_bins(d, pred, r_bin, d.z_m, r_labels)
    rho = np.sqrt(d.rho2)
    edges = np.linspace(0, rho.max() + 1e-9, 6)
    rq = np.digitize(rho, edges[1:-1])
    by_radius = compare_bins(d, pred, rq, rho, {i: f"rho {edges[i]:.2f}-{edges[i + 1]:.2f}" for i in range(5)})
    by_brightness = None
    if np.isfinite(d.ir).sum() > 100:
        ok = np.isfinite(d.ir)
        q = np.nanquantile(d.ir, np.linspace(0, 1, 7))
        bq = np.where(ok, np.clip(np.digitize(np.nan_to_num(d.ir), q[1:-1]), 0, 5), -1)
        labels = {i: f"IR {q[i]:.0f}-{q[i + 1]:.0f} DN" for i in range(6)}
        sel = bq >= 0
        by_brightness = compare_bins(d.select(sel), _subset(pred, sel), bq[sel], d.ir[sel], labels)
    angle = np.degrees(np.arccos(np.clip(d.cos_inc, -1, 1)))
    by_incidence = None
    if np.ptp(angle) > 1:
        edges = np.linspace(angle.min(), angle.max() + 1e-9, 6)
        ab = np.digitize(angle, edges[1:-1])
        by_incidence = compare_bins(d, pred, ab, angle, {i: f"{edges[i]:.0f}-{edges[i + 1]:.0f} deg" for i in range(5)})
    # image map: ln(measured/predicted) in an 8 x 6 grid of image tiles, all stops pooled
    nx, ny = 8, 6
    tx = np.clip((d.u_px / (d.u_px.max() + 1) * nx).astype(int), 0, nx - 1)
    ty = np.clip((d.v_px / (d.v_px.max() + 1) * ny).astype(int), 0, ny - 1)
    image_map = np.full((ny, nx), np.nan)
    nu = d.nu
    for j in range(ny):
        for i in range(nx):
            m = (tx == i) & (ty == j)
            if m.sum() >= 5:
                image_map[j, i] = 0.5 * np.log((d.s2_m2[m] * nu[m]).sum() / (pred.var_m2[m] * nu[m]).sum())
    fill = []
    for s in np.unique(d.stop):
        m = d.stop == s
        pf = float(np.mean(pred.fill[m])) if pred.fill is not None else 1.0
        fill.append((f"{np.median(d.z_m[m]):.2f} m", float(np.mean(d.fill[m])), pf))
    return Residuals(by_range, by_radius, by_brightness, by_incidence, image_map, fill)


def _subset(pred, mask):
    from .models import Prediction

    return Prediction(pred.shot_m2[mask], pred.illum[mask], pred.image_terms[mask], pred.var_m2[mask],
                      None if pred.k4_m4 is None else pred.k4_m4[mask], None if pred.fill is None else pred.fill[mask])


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


def render_text(diag: Diagnosis) -> str:
    d = diag.data
    lines = [f"Diagnosis of {diag.source or 'the recording'}: {d.n_samples:,} samples in {len(d):,} pixel-stops",
             "", diag.model_fit.report(), "",
             f"Headline error of {diag.model_fit.model.name}: {diag.model_headline}",
             f"(for reference, the paper's free power law: lambda = {diag.power_law_fit.values['lambda']:.4f} "
             f"+/- {diag.power_law_fit.errors.get('lambda', float('nan')):.2g})", ""]
    r = diag.residuals
    lines.append("Where it fails (measured / predicted sigma; * = off by more than 3 standard errors):")
    for title, b in (("by range", r.by_range), ("by radius from the image centre", r.by_radius),
                     ("by IR brightness", r.by_brightness), ("by incidence angle", r.by_incidence)):
        if b is None:
            continue
        lines.append(f"  {title}:")
        for lab, lr, se, fl in zip(b.labels, b.log_ratio, b.se_log, b.flagged):
            lines.append(f"    {lab:<24} {np.exp(lr):7.3f}  (+/- {2 * se * np.exp(lr):.3f}){' *' if fl else ''}")
    b = r.by_range
    lines.append("  kurtosis by range (measured / model; normal = 3):")
    for lab, km, kp, sk in zip(b.labels, b.kurt_meas, b.kurt_pred, b.se_kurt):
        lines.append(f"    {lab:<24} {km:6.2f} / {kp:5.2f}  (+/- {2 * sk:.2f})")
    lines.append("  fill rate by stop (measured / model):")
    lines.append("    " + ", ".join(f"{s} {m:.3f}/{p:.3f}" for s, m, p in r.fill_by_stop))
    lines += ["", "Candidate effects, by evidence (BIC change; LRT statistic, df, p):"]
    for c in diag.candidates:
        mark = "significant" if c.significant else ""
        lines.append(f"  {c.effect.name:<14} dBIC {c.dbic:12.1f}   LRT {c.lrt:12.1f} df {c.df}  p {c.p_value:.1e}  {mark}")
    lines += ["", diag.summary()]
    if diag.best is not None:
        lines += ["", diag.best.fit.report(), "",
                  f"Headline error: {diag.model_headline.error_pct:.2f} % with {diag.model_fit.model.name} -> "
                  f"{diag.refit_headline.error_pct:.2f} % with {diag.best.fit.model.name} "
                  f"(noise alone: {diag.refit_headline.noise_pct:.2f} %; "
                  f"{'what remains is within noise' if diag.refit_headline.within_noise else 'something remains beyond noise'})."]
        if diag.after_best:
            nxt = diag.after_best[0]
            lines.append(f"After adding {diag.best.effect.name}, the next candidate is {nxt.effect.name} (dBIC {nxt.dbic:.1f}): "
                         f"try rig diagnose --model {diag.best.fit.model.name}.")
        else:
            lines.append(f"After adding {diag.best.effect.name}, no further effect is significant.")
    return "\n".join(lines)
