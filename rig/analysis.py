"""Fit a recording with the paper's model and summarise it: what `rig fit` and `rig demo` print.

    from rig.analysis import fit_recording
    print(fit_recording("active.h5").fit.report())
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from protocols.recording import Recording

from .diagnosis.bins import BinnedSigma, pooled_sigma, sigma_by_range
from .models import ModelData, ModelFit, fit_power_law, load_samples
from .models.progress import ProgressCounter


@dataclass
class RecordingFit:
    path: Path
    protocol: str
    projector_on: bool
    samples: ModelData  # every pixel with two or more samples (in the --z-min/--z-max window, if given)
    fit: ModelFit  # the paper's power law
    labels: list[str]  # the stops, in order
    notes: list[str]  # what to know about the recording itself (interrupted, stops missing, entries skipped)

    @cached_property
    def measured(self) -> BinnedSigma:
        """Measured sigma per stop (perpendicular) or per 0.25 m window (tilted): for plots, made when asked for."""
        if len(self.labels) > 1:
            return pooled_sigma(self.samples, self.samples.stop, self.labels)
        return sigma_by_range(self.samples)


def fit_recording(path: str | Path, *, z_min_m: float | None = None, z_max_m: float | None = None,
                  counter: ProgressCounter | None = None) -> RecordingFit:
    """`counter`, if given, is told of the two steps: reading the recording, fitting (rig.models.progress)."""
    counter = counter or ProgressCounter(None, 2)
    counter.step("reading the recording")
    with Recording(path) as rec:
        samples = load_samples(rec)
        labels = rec.stop_labels()
        protocol = rec.protocol
        notes = rec.notes()
    projector = samples.sources[0].projector_on if samples.sources else True
    if z_min_m is not None or z_max_m is not None:
        samples = samples.in_range(z_min_m or 0.0, z_max_m or float("inf"))
    counter.step("fitting k and lambda")
    fit = fit_power_law(samples)
    return RecordingFit(Path(path), protocol, projector, samples, fit, labels, notes)
