"""Plain-text tables of fits, as `rig demo` prints them."""

from __future__ import annotations

from ..models import ModelFit


def fit_table(rows: list[tuple[str, ModelFit]]) -> str:
    """A plain table: one row per power-law fit (k, lambda, their standard errors, samples, range)."""
    head = f"{'experiment':<22} {'k [m^(1-λ)]':>13} {'± se':>9} {'λ':>8} {'± se':>7} {'samples':>14} {'range [m]':>12}"
    lines = [head, "-" * len(head)]
    for name, f in rows:
        lines.append(f"{name:<22} {f.k:13.5g} {f.se_k:9.2g} {f.lam:8.4f} {f.se_lam:7.4f} {f.n_samples:14,d} "
                     f"{f.z_min_m:5.2f}-{f.z_max_m:4.2f}")
    return "\n".join(lines)
