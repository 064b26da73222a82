"""Fit a recording and summarise it: what `rig fit` and `rig demo` print."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .fit import BinnedSigma, PowerLawFit, fit_power_law, pooled_sigma, sigma_by_range
from .recording import Recording
from .samples import PixelSamples, load_samples


@dataclass
class RecordingFit:
    path: Path
    protocol: str
    projector_on: bool
    samples: PixelSamples
    fit: PowerLawFit
    measured: BinnedSigma  # per stop (perpendicular) or per 0.25 m window (tilted)


def fit_recording(path: str | Path, *, z_min_m: float | None = None, z_max_m: float | None = None) -> RecordingFit:
    with Recording(path) as rec:
        samples = load_samples(rec)
        labels = rec.stop_labels()
        projector = rec.stop(labels[0]).projector_on if labels else True
        protocol = rec.protocol
    if z_min_m is not None or z_max_m is not None:
        samples = samples.in_range(z_min_m or 0.0, z_max_m or float("inf"))
    fit = fit_power_law(samples)
    if len(labels) > 1:
        measured = pooled_sigma(samples, samples.stop, labels)
    else:
        measured = sigma_by_range(samples)
    return RecordingFit(Path(path), protocol, projector, samples, fit, measured)


def fit_table(rows: list[tuple[str, PowerLawFit]]) -> str:
    """A plain table: one row per fit."""
    head = f"{'experiment':<22} {'k [m^(1-λ)]':>13} {'± se':>9} {'λ':>8} {'± se':>7} {'samples':>14} {'range [m]':>12}"
    lines = [head, "-" * len(head)]
    for name, f in rows:
        lines.append(f"{name:<22} {f.k:13.5g} {f.se_k:9.2g} {f.lam:8.4f} {f.se_lam:7.4f} {f.n_samples:14,d} "
                     f"{f.z_min_m:5.2f}-{f.z_max_m:4.2f}")
    return "\n".join(lines)
