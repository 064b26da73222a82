"""The shape of what the catalogue does not explain: an empirical term against the residual it was fitted to."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..diagnosis.residuals import compare_along  # noqa: E402
from ..diagnosis.unexplained import EmpiricalStep  # noqa: E402
from ..models import ModelData, ModelFit  # noqa: E402
from ..models.data.model_data import range_bin_index  # noqa: E402
from ..models.effects.empirical import (COVARIATES, EmpiricalFill, EmpiricalFrameMean, EmpiricalPosition,  # noqa: E402
                                EmpiricalSigma, EmpiricalTails)
from .output_file import save_figure  # noqa: E402

QUANTILE_BINS = 12


def plot_shape(step: EmpiricalStep, before: ModelFit, before_error_pct: float, d: ModelData, path: Path) -> Path:
    """One figure: the residual of the model before the term, binned along the covariate, and the term's shape."""
    term, after = step.term, step.fit
    fig, ax = plt.subplots(figsize=(7.5, 4.4), layout="tight")
    if isinstance(term, EmpiricalSigma):
        unit, read = COVARIATES[term.covariate]
        c = read(d)
        ok = np.isfinite(c)
        edges = np.unique(np.nanquantile(c[ok], np.linspace(0, 1, QUANTILE_BINS + 1)))

        def groups_of(chunk: ModelData) -> np.ndarray:
            x = read(chunk)
            return np.where(np.isfinite(x), np.clip(np.digitize(np.nan_to_num(x), edges[1:-1]), 0, len(edges) - 2), -1)

        b, (var_before, var_after) = compare_along(before, d, groups_of, read, others=(after,))
        ax.errorbar(b.center, np.exp(b.log_ratio), yerr=2 * b.se_log * np.exp(b.log_ratio), fmt="o", ms=4, capsize=2,
                    label=f"measured / {before.model.name} (±2 s.e.)")
        # what the model with the shape predicts against the model without it, in the same bins as the points
        # (the joint refit moves k and the catalogue terms too, so the shape alone is not on the points' scale)
        ids = sorted(var_before)
        ratio = [float(np.sqrt(var_after[g] / var_before[g])) for g in ids]
        centre = [float(x) for x in b.center] if len(b.center) == len(ids) else [float(np.mean(edges[g:g + 2])) for g in ids]
        ax.plot(centre, ratio, "-", color="tab:green", lw=2, label=f"with {term.name} / without (the fitted model)")
        grid = np.linspace(np.nanmin(c), np.nanmax(c), 200)
        ax.plot(grid, np.exp(term.log_multiplier(grid, after.values)), "--", color="tab:green", lw=1,
                label=f"{term.name} alone: the missing effect's shape")
        ax.plot(term.knots, np.exp(term.log_multiplier(term.knots, after.values)), "s", color="tab:green", ms=4)
        ax.set_xlabel(f"{term.covariate} [{unit}]")
        ax.set_ylabel("σ multiplier")
    elif isinstance(term, EmpiricalPosition):
        fig.clf()
        ax = fig.add_subplot(111)
        x = np.linspace(np.nanmin(d.x_norm), np.nanmax(d.x_norm), 80)
        y = np.linspace(np.nanmin(d.y_norm), np.nanmax(d.y_norm), 60)
        xx, yy = np.meshgrid(x, y)
        im = ax.imshow(np.exp(term.log_multiplier(xx, yy, after.values)), origin="upper", cmap="viridis",
                       extent=(x[0], x[-1], y[-1], y[0]))
        fig.colorbar(im, ax=ax, label="σ multiplier")
        ax.set_xlabel("(u - cx) / fx")
        ax.set_ylabel("(v - cy) / fy")
    elif isinstance(term, EmpiricalTails):
        windows = (lambda chunk: range_bin_index(chunk.z_m)), (lambda chunk: chunk.z_m)
        b, _ = compare_along(before, d, *windows)
        ax.errorbar(b.center, b.kurt_meas, yerr=2 * b.se_kurt, fmt="o", ms=4, capsize=2, label="measured kurtosis")
        ax.plot(b.center, b.kurt_pred, "-", color="tab:red", label=before.model.name)
        a, _ = compare_along(after, d, *windows)
        ax.plot(a.center, a.kurt_pred, "-", color="tab:green", label=f"with {term.name}")
        ax.set_xlabel("Z [m]")
        ax.set_ylabel("kurtosis (normal = 3)")
    elif isinstance(term, (EmpiricalFrameMean, EmpiricalFill)):
        z = np.array(sorted(set(d.median_range_by_stop.values())))
        gain = term.gain(z) if isinstance(term, EmpiricalFrameMean) else term.gain(z, after.values)
        ax.plot(z, gain, "o-", color="tab:green", label=f"{term.name}")
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xlabel("Z [m]")
        ax.set_ylabel("frame-mean variance / independent pixels" if isinstance(term, EmpiricalFrameMean)
                      else "fill rate / model's")
    ax.set_title(f"Not in the catalogue: the shape over {step.covariate} (headline error "
                 f"{before_error_pct:.2f} % → {step.headline.error_pct:.2f} %)", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    path = Path(path)
    save_figure(fig, path, dpi=100)
    plt.close(fig)
    return path

