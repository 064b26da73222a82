"""The diagnosis as PNG plots: where the model fails, the candidate effects, and the error before and after."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..diagnosis import BinComparison, Diagnosis  # noqa: E402
from .shape_plot import plot_shape  # noqa: E402
from .log_ticks import label_log_axis  # noqa: E402
from .output_file import save_figure  # noqa: E402
from .verdict_state import headline_state, plot_colour  # noqa: E402


def _margin_in(labels: list[str], points: float, pad_in: float) -> float:
    """Inches the longest of `labels` needs at a font size of `points` (0.62 em a character, DejaVu Sans' widest
    lower case ones; wider than most), plus pad_in: fixed margins, not the tight layout engine, which measured
    every label with the renderer (0.3 of a diagnosis report's 1.5 s of plotting)."""
    return pad_in + 0.62 * points / 72 * max((len(x) for x in labels), default=1)


def _ratio_panel(ax, b: BinComparison, xlabel: str, title: str) -> None:
    ratio = np.exp(b.log_ratio)
    band = 2 * b.se_log * ratio
    ax.axhline(1.0, color="k", lw=0.8)
    ax.fill_between(b.center, 1 - 2 * b.se_log, 1 + 2 * b.se_log, color="0.85", label="±2 s.e. (sampling noise)")
    colors = np.where(b.flagged, "tab:red", "tab:blue")
    ax.errorbar(b.center, ratio, yerr=band, fmt="none", ecolor="0.4", capsize=2)
    ax.scatter(b.center, ratio, c=colors, zorder=3, s=18)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("σ measured / σ model")
    ax.set_title(title)
    ax.grid(alpha=0.3)


def write_plots(diag: Diagnosis, out_dir: str | Path) -> list[Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    r = diag.residuals
    paths = []
    # fixed margins, not the tight layout engine: every label here is one of the fixed strings below or a short tick
    # (0.6 of the report's 2.0 s went to the engine measuring them; checked by eye on 6-character ticks)
    fig, axes = plt.subplots(2, 3, figsize=(14, 8))
    fig.subplots_adjust(left=0.065, right=0.975, bottom=0.065, top=0.91, wspace=0.28, hspace=0.3)
    _ratio_panel(axes[0, 0], r.by_range, "Z [m]", "by range (0.25 m windows)")
    _ratio_panel(axes[0, 1], r.by_radius, "ρ = radius / f", "by distance from the image centre")
    if r.by_brightness is not None:
        _ratio_panel(axes[0, 2], r.by_brightness, "IR brightness [DN]", "by brightness")
    else:
        axes[0, 2].set_axis_off()
    if r.by_incidence is not None:
        _ratio_panel(axes[1, 0], r.by_incidence, "incidence angle [deg]", "by incidence angle")
    else:
        axes[1, 0].text(0.5, 0.5, "one incidence angle only\n(perpendicular wall, on axis)", ha="center", va="center")
        axes[1, 0].set_axis_off()
    b = r.by_range
    ax = axes[1, 1]
    ax.errorbar(b.center, b.kurt_meas, yerr=2 * b.se_kurt, fmt="o", ms=4, capsize=2, label="measured")
    ax.plot(b.center, b.kurt_pred, "-", color="tab:orange", label=f"model ({diag.model_fit.model.name})")
    ax.axhline(3, color="k", lw=0.8, ls=":")
    ax.set_xlabel("Z [m]")
    ax.set_ylabel("kurtosis")
    ax.set_title("kurtosis by range (normal = 3)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax = axes[1, 2]
    lim = np.nanmax(np.abs(r.image_map)) if np.isfinite(r.image_map).any() else 0.1
    im = ax.imshow(100 * r.image_map, cmap="RdBu_r", vmin=-100 * lim, vmax=100 * lim)
    fig.colorbar(im, ax=ax, label="ln(σ measured / σ model) [%]")
    ax.set_title("by position in the image (all stops)")
    ax.set_xticks([])
    ax.set_yticks([])
    fig.suptitle(f"Where {diag.model_fit.model.name} fails: red points are off by more than 3 standard errors")
    p = out / "diagnosis-residuals.png"
    save_figure(fig, p, dpi=100)
    plt.close(fig)
    paths.append(p)

    cands = diag.candidates
    names = [c.effect.name for c in cands]
    fig, ax = plt.subplots(figsize=(7, 4))
    fig.subplots_adjust(left=_margin_in(names, 10, 0.25) / 7, right=0.96, bottom=0.14, top=0.91)
    vals = [max(-c.dbic, 0.1) for c in cands]
    colors = ["tab:green" if (diag.best is not None and c is diag.best) else ("tab:blue" if c.significant else "0.7")
              for c in cands]
    ax.barh(names[::-1], vals[::-1], color=colors[::-1])
    ax.set_xscale("log")
    ax.axvline(10, color="k", ls=":", lw=0.8)
    label_log_axis(ax.xaxis)
    ax.set_xlabel("evidence: BIC drop when the effect is added (log scale; dotted: significance)")
    ax.set_title("Candidate effects")
    p = out / "diagnosis-candidates.png"
    save_figure(fig, p, dpi=100)
    plt.close(fig)
    paths.append(p)

    if len(diag.steps) > 1 or diag.unexplained is not None:
        p = out / "diagnosis-before-after.png"
        plot_path(diag, p)
        paths.append(p)
    if diag.unexplained is not None:
        prev, prev_error = diag.unexplained.start_fit, diag.unexplained.start_headline.error_pct
        for st in diag.unexplained.steps:
            if st.is_empirical:
                p = out / f"diagnosis-shape-{st.covariate}.png"
                plot_shape(st, prev, prev_error, diag.data, p)
                paths.append(p)
            prev, prev_error = st.fit, st.headline.error_pct
    return paths


def plot_path(diag: Diagnosis, path: Path) -> None:
    """The path: headline error after each step (and the noise level); sigma's residual by range and by radius at
    the start, after the catalogue's effects and at the end."""
    names = ["start"] + [f"+ {s.added.effect.name}" for s in diag.steps[1:]]
    errors = [s.headline.error_pct for s in diag.steps]
    noise = [s.headline.noise_pct for s in diag.steps]
    states = [headline_state(s.headline) for s in diag.steps]
    if diag.unexplained is not None:
        for st in diag.unexplained.steps:
            names.append(f"+ {st.added}")
            errors.append(st.headline.error_pct)
            noise.append(st.headline.noise_pct)
            states.append(headline_state(st.headline))
    fig, (ax, *after) = plt.subplots(1, 3, figsize=(17, 4.4))
    # the step names slant at 20 degrees below the bars
    fig.subplots_adjust(left=0.06, right=0.99, top=0.92, wspace=0.25,
                        bottom=min(0.45, (0.2 + np.sin(np.radians(20)) * _margin_in(names, 8, 0.1)) / 4.4))
    x = np.arange(len(names))
    ax.bar(x, errors, color=[plot_colour(st) for st in states])
    ax.plot(x, noise, "k_", ms=30, mew=2, label="sampling noise alone")
    ax.set_yscale("log")
    label_log_axis(ax.yaxis)
    ax.set_xticks(x, names, rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("headline error [%]")
    ax.set_title("The path: green within noise, red beyond, grey not judged", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    fits = [(diag.model_fit, diag.model_headline, "tab:red"), (diag.catalogue_fit, diag.catalogue_headline, "tab:orange"),
            (diag.final_fit, diag.final_headline, "tab:green")]
    # where the error went: sigma's residual by range and by radius (a radial effect's start and final curves
    # overlap by range, its error being spread over every range), as the headline's checks measured them
    for ax2, covariate, xlabel in zip(after, ("range", "radius"), ("Z [m]", "ρ = radius / f [1]")):
        seen = set()
        for fit, head, color in fits:
            check = head.consistency.find("sigma", covariate) if head.consistency is not None else None
            if fit.model.name in seen or check is None:
                continue
            seen.add(fit.model.name)
            log_ratio = np.log(check.measured / check.predicted)
            ax2.errorbar(check.center, 100 * log_ratio, yerr=200 * check.se / check.measured, fmt="o-", ms=4,
                         capsize=2, color=color, label=fit.model.name)
        ax2.axhline(0, color="k", lw=0.8)
        ax2.set_xlabel(xlabel)
        ax2.set_ylabel("ln(σ measured / σ model) [%]")
        ax2.set_title(f"by {covariate}: headline error {diag.model_headline.error_pct:.2f} % → "
                      f"{diag.final_headline.error_pct:.2f} %", fontsize=10)
        if seen:
            ax2.legend(fontsize=7)
        ax2.grid(alpha=0.3)
    save_figure(fig, path, dpi=100)
    plt.close(fig)
