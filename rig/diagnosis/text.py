"""The diagnosis as plain text, as `rig diagnose` prints it."""

from __future__ import annotations

import numpy as np

from .verdict import Diagnosis


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
