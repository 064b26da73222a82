"""The plots of `rig compare a.h5 b.h5` and `rig repeatability`: sigma against range for every recording on one
pair of axes, and each parameter run by run with its error bars."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..recordings.comparison import Scatter  # noqa: E402
from ..recordings.recording_fits import RecordingResult  # noqa: E402
from .sigma_plot import finish_sigma_figure, sigma_figure  # noqa: E402
from .output_file import save_figure  # noqa: E402

COLOURS = plt.rcParams["axes.prop_cycle"].by_key()["color"]


def plot_overlay(results: list[RecordingResult], path: str | Path) -> Path:
    """sigma_Z against Z: each recording's measured sigma per stop (+-2 s.e.) and its model's curve, in one colour;
    linear axes left, log-log right (a power law is a straight line of slope lambda)."""
    fig, axes = sigma_figure()
    for ax in axes:
        for i, r in enumerate(x for x in results if not x.error):
            c = COLOURS[i % len(COLOURS)]
            ax.errorbar(r.z_m, 1e3 * np.array(r.sigma_m), yerr=2e3 * np.array(r.se_sigma_m), fmt="o", ms=4, color=c,
                        capsize=3, label=f"{r.name}: measured")
            lam = f", λ={r.values['lambda']:.4f}" if "lambda" in r.values else ""
            ax.plot(r.curve_z_m, 1e3 * np.array(r.curve_sigma_m), "-", color=c,
                    label=f"{r.name}: {r.model} ({r.curve_label}){lam}")
    return finish_sigma_figure(fig, axes, path, "Range error against range", legend_size=7)


def plot_runs(results: list[RecordingResult], scatters: list[Scatter], path: str | Path) -> Path:
    """Each parameter run by run (+-1 Cramer-Rao error), with the runs' mean and +-1 run-to-run standard deviation;
    the runs named by their files, each parameter with its unit, the legend below the panels (never on a run)."""
    path = Path(path)
    fig = runs_figure(results, scatters)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def runs_figure(results: list[RecordingResult], scatters: list[Scatter]):
    """The figure of `plot_runs`, unsaved."""
    fitted = [r for r in results if not r.error]
    names = [r.name for r in fitted]
    fig, axes = plt.subplots(1, len(scatters), figsize=(4.5 * len(scatters), 3.6 + 0.07 * max(map(len, names))),
                             squeeze=False)
    x = np.arange(1, len(fitted) + 1)
    for ax, s in zip(axes[0], scatters):
        v = [r.values[s.parameter] for r in fitted]
        e = [r.errors.get(s.parameter, np.nan) for r in fitted]
        ax.errorbar(x, v, yerr=e, fmt="o", capsize=3, label="run (±1 reported error)")
        ax.axhline(s.mean, color="k", lw=1)
        ax.axhspan(s.mean - s.sd, s.mean + s.sd, color="0.85", label="mean ±1 run-to-run s.d.")
        ax.set_title(f"{s.parameter}: scatter / error = {s.ratio:.2f}", fontsize=10)
        unit = next((r.units[s.parameter] for r in fitted if s.parameter in r.units), "")
        ax.set_ylabel(f"{s.parameter} [{unit or '?'}]")
        ax.set_xlabel("run (recording)")
        ax.set_xticks(x, names, rotation=30, ha="right", fontsize=7)
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.0), ncols=2, fontsize=8, frameon=False)
    return fig
