"""The sigma-vs-range plot (like the paper's Fig. 1), as a PNG (matplotlib, no display needed)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..diagnosis.bins import BinnedSigma  # noqa: E402
from ..models import ModelFit  # noqa: E402
from .log_ticks import label_log_axis  # noqa: E402
from .output_file import save_figure  # noqa: E402


@dataclass
class SigmaSeries:
    """One experiment on the sigma-vs-range plot: measured per stop and its fitted curve."""

    label: str
    measured: BinnedSigma
    fit: ModelFit
    color: str


def plot_format_problem(path: str | Path) -> str | None:
    """Why matplotlib cannot write a plot to `path` (its suffix names no format it writes), with the suffixes it
    can; None if it can."""
    suffixes = sorted(fig_formats())
    suffix = Path(path).suffix.lower().lstrip(".")
    if suffix in suffixes:
        return None
    what = f"its suffix .{suffix} is not a format matplotlib writes" if suffix else "it has no suffix to name the format"
    return f"{what}; name it with one of {', '.join('.' + s for s in suffixes)} (e.g. fit.png)"


def fig_formats() -> dict[str, str]:
    """The formats matplotlib can save a figure in, by suffix."""
    from matplotlib.backend_bases import FigureCanvasBase

    return FigureCanvasBase.get_supported_filetypes()


def plot_sigma_vs_range(series: list[SigmaSeries], path: str | Path, title: str = "Range error against range") -> Path:
    """Like the paper's Fig. 1: sigma_Z against Z, measured with error bars and fitted curves.

    Left: linear axes, as in the paper. Right: log-log axes, where a power law is a straight
    line of slope lambda.
    """
    fig, axes = sigma_figure()
    for ax in axes:
        for s in series:
            m = s.measured
            ax.errorbar(m.z_m, 1000 * m.sigma_m, yerr=1000 * 2 * m.se_sigma_m, fmt="o", ms=4, color=s.color,
                        capsize=3, label=f"{s.label}: measured (±2 s.e.)")
            z = np.linspace(min(m.z_m.min(), s.fit.z_min_m) * 0.95, max(m.z_m.max(), s.fit.z_max_m) * 1.03, 200)
            ax.plot(z, 1000 * s.fit.sigma_m(z), "-", color=s.color,
                    label=f"{s.label}: fit k={s.fit.k:.3g}, λ={s.fit.lam:.4f}±{s.fit.se_lam:.1g}")
    return finish_sigma_figure(fig, axes, path, title)


def sigma_figure():
    """The two panels of a sigma-vs-range plot (linear, log-log), with fixed margins: the labels are the fixed ones
    of `finish_sigma_figure` and short "%g" ticks (the tight layout engine measured each)."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    fig.subplots_adjust(left=0.065, right=0.985, bottom=0.12, top=0.92, wspace=0.2)
    return fig, axes


def finish_sigma_figure(fig, axes, path: str | Path, title: str, legend_size: int = 8) -> Path:
    """Label both panels (the right one log-log: a power law is a straight line of slope lambda), write the figure to
    `path` and close it."""
    path = Path(path)
    for ax, loglog in zip(axes, (False, True)):
        ax.set_xlabel("Z [m]")
        ax.set_ylabel("σ_Z [mm]")
        ax.grid(True, which="both", alpha=0.3)
        if loglog:
            ax.set_xscale("log")
            ax.set_yscale("log")
            for axis in (ax.xaxis, ax.yaxis):
                label_log_axis(axis)
            ax.set_title("log-log: slope = λ")
        else:
            ax.set_title(title)
            ax.legend(fontsize=legend_size, loc="upper left")
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path
