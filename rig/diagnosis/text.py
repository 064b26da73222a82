"""The diagnosis as plain text, as `rig diagnose` prints it."""

from __future__ import annotations

import numpy as np

from ..models.data.covariates import brightness_left_out
from ..models.data.determinacy import lambda_status
from .verdict import Diagnosis


def render_text(diag: Diagnosis) -> str:
    d = diag.data
    lines = [f"Diagnosis of {diag.source or 'the recording'}: {d.n_samples:,} samples in {len(d):,} pixel-stops",
             "", diag.model_fit.report(), "",
             f"Headline error of {diag.model_fit.model.name}: {diag.model_headline}",
             f"(for reference, the paper's free power law: lambda = {diag.power_law_fit.values['lambda']:.4f} "
             f"+/- {diag.power_law_fit.errors.get('lambda', float('nan')):.2g}{_undetermined(diag)})", ""]
    r = diag.residuals
    lines.append(f"Where {diag.model_fit.model.name} fails (measured / predicted sigma; * = off by more than 3 standard errors):")
    for title, b in (("by range", r.by_range), ("by radius from the image centre", r.by_radius),
                     ("by IR brightness", r.by_brightness), ("by incidence angle", r.by_incidence)):
        if b is None:
            continue
        if b is r.by_brightness and brightness_left_out(d):
            title += (f" ({brightness_left_out(d):,} pixel-stops left out: saturated IR, whose brightness is only a lower "
                      "bound)")
        lines.append(f"  {title}:")
        for lab, lr, se, fl in zip(b.labels, b.log_ratio, b.se_log, b.flagged):
            lines.append(f"    {lab:<24} {np.exp(lr):7.3f}  (+/- {2 * se * np.exp(lr):.3f}){' *' if fl else ''}")
    b = r.by_range
    lines.append("  kurtosis by range (measured / model; normal = 3):")
    for lab, km, kp, sk in zip(b.labels, b.kurt_meas, b.kurt_pred, b.se_kurt):
        lines.append(f"    {lab:<24} {km:6.2f} / {kp:5.2f}  (+/- {2 * sk:.2f})")
    lines.append("  fill rate by stop (measured / model):")
    lines.append("    " + ", ".join(f"{s} {m:.3f}/{p:.3f}" for s, m, p in r.fill_by_stop))
    lines += ["", "Every statistic it predicts, each against its own error (chi2 / bins, p; the verdict needs p >= "
                  f"{r.consistency.threshold_with(1):.1e} for each):"]
    for c in r.consistency.checks:
        # no bin to compare: not judged, so neither ok nor off
        flag = "--  " if not c.dof else "ok  " if c.p_value >= r.consistency.threshold_with(1) else "OFF "
        lines.append(f"  {flag}{c.name:<26} {c.chi2:12.1f} / {c.dof:<3} p {c.p_value:.1e}   worst: {c.describe_worst()}")
    lines += ["", "Candidate effects, by evidence (BIC change; LRT statistic, df, p):"]
    for c in diag.candidates:
        mark = "significant" if c.significant else ""
        lines.append(f"  {c.effect.name:<16} dBIC {c.dbic:12.1f}   LRT {c.lrt:12.1f} df {c.df}  p {c.p_value:.1e}  {mark}")
    for st in diag.steps:
        for name, why in st.not_fitted:
            lines.append(f"  {name:<16} could not be fitted on top of {st.name}: {why}")
    lines += ["", "The path (each step adds the most likely missing effect while something is beyond noise):"]
    for st in diag.steps:
        change = "start" if st.added is None else f"+ {st.added.effect.name} (dBIC {st.added.dbic:.1f})"
        lines.append(f"  {change:<36} {st.name:<48} headline {st.headline.error_pct:6.2f} %  "
                     f"{st.headline.state}")
    u = diag.unexplained
    if u is not None:
        for st in u.steps:
            if st.candidate is not None:
                why = f"   (the catalogue tried again on top of the shapes: dBIC {st.candidate.dbic:.1f})"
            else:
                tried = ", ".join(f"{t.covariate} {t.dbic:.0f}" if t.fit is not None else f"{t.covariate} (n/a)" for t in st.trials)
                why = f"   (for {st.family}; dBIC of the shapes tried: {tried})"
                if st.held:
                    why += f"; held at their start, not determined by the data: {', '.join(st.held)}"
            lines.append(f"  {'+ ' + st.added:<36} {st.fit.model.name:<48} headline "
                         f"{st.headline.error_pct:6.2f} %  {st.headline.state}{why}")
    if diag.stopped:
        lines.append(f"  The path stopped: {diag.stopped}.")
    lines += ["", diag.summary()]
    if len(diag.steps) > 1:
        lines += ["", diag.catalogue_fit.report()]
    if u is not None and u.steps:
        lines += ["", u.final_fit.report()]
    lines += ["", f"Final: {diag.final_fit.model.name}: headline error {diag.final_headline}"]
    return "\n".join(lines)


def _undetermined(diag: Diagnosis) -> str:
    """", NOT DETERMINED: why" when the recording cannot determine the power law's lambda (rig.models.data.determinacy)."""
    status = lambda_status(diag.data)
    return "" if status.determined else f"; NOT DETERMINED: {status.reason.removeprefix('lambda is not determined: ')}"
