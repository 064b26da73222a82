"""The fit page's measured/predicted panel: sigma measured over sigma the model predicts, by range and by radius,
with +-2 standard errors, as the headline's own checks (rig.diagnosis.consistency) binned them: 1 where the model is
right, and where it is not, which way and where."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .output_file import save_figure  # noqa: E402
from .verdict_state import headline_state, plot_colour  # noqa: E402

#: (covariate of a consistency check, its axis label)
PANELS = (("range", "Z [m]"), ("radius", "ρ = radius / f [1]"))


def plot_measured_predicted(headline, model_name: str, path: str | Path) -> Path | None:
    """measured / predicted sigma by range and by radius (+-2 s.e.); the points coloured by the headline's verdict.
    None when the headline holds no sigma check to draw (nothing judged)."""
    checks = [(headline.consistency.find("sigma", c) if headline.consistency is not None else None, label)
              for c, label in PANELS]
    checks = [(c, label) for c, label in checks if c is not None and len(c.center)]
    if not checks:
        return None
    fig, axes = plt.subplots(1, len(checks), figsize=(5.5 * len(checks), 3.8), squeeze=False)
    colour = plot_colour(headline_state(headline))
    for ax, (check, label) in zip(axes[0], checks):
        ratio = check.measured / check.predicted
        ax.axhline(1.0, color="k", lw=0.8)
        ax.errorbar(check.center, ratio, yerr=2 * check.se / check.predicted, fmt="o", ms=4, capsize=2, color=colour,
                    label=f"measured / {model_name} (±2 s.e.)")
        ax.set_xlabel(label)
        ax.set_ylabel("σ measured / σ predicted [1]")
        ax.set_title(f"by {check.covariate}", fontsize=10)
        ax.grid(alpha=0.3)
        lo, hi = np.nanmin(ratio - 2 * check.se / check.predicted), np.nanmax(ratio + 2 * check.se / check.predicted)
        ax.set_ylim(min(lo, 0.98) - 0.01, max(hi, 1.02) + 0.01)  # 1 always in view, at least +-2 %
    axes[0][0].legend(fontsize=8, loc="best")
    fig.suptitle(f"{model_name}: headline error {headline.error_pct:.2f} % ({headline.state})", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=100)
    plt.close(fig)
    return path
