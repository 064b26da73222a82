"""Fit a recording with the paper's model and summarise it: what `rig fit` and `rig demo` print.

    from rig.analysis import fit_recording
    print(fit_recording("active.h5").fit.report())

Also what every analysis command shares about a recording: its notes (`recording_notes`) and the
--z-min/--z-max window of ranges to fit (`check_window`, `in_window`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from protocols.recording import Recording
from protocols.region_of_interest import region_words

from .diagnosis.bins import BinnedSigma, pooled_sigma, sigma_by_range
from .models import ModelData, ModelFit, fit_power_law, load_samples
from .models.data.independence import independence
from .recordings.camera_setup import json_attr
from .models.fitting.progress import ProgressCounter

#: the note a recording gives when planned stops are missing (protocols.recording.Recording.notes)
_MISSING_STOPS = re.compile(r"^\d+ of \d+ planned stops \(missing ")
#: what `rig import` records: written whole to a temporary file and renamed at the end, or not at all
IMPORTED = "import"


@dataclass
class RecordingFit:
    path: Path
    protocol: str
    projector_on: bool
    samples: ModelData  # every pixel with two or more samples (in the --z-min/--z-max window, if given)
    fit: ModelFit  # the paper's power law
    labels: list[str]  # the stops, in order
    notes: list[str]  # what to know about the recording itself (interrupted, stops missing, entries skipped)
    region: str = ""  # the part of the image recorded, in words ("": the whole image; protocols.region_of_interest)

    @cached_property
    def measured(self) -> BinnedSigma:
        """Measured sigma per stop (perpendicular) or per 0.25 m window (tilted): for plots, made when asked for."""
        if len(self.labels) > 1:
            return pooled_sigma(self.samples, self.samples.stop, self.labels)
        return sigma_by_range(self.samples)


def fit_recording(path: str | Path, *, z_min_m: float | None = None, z_max_m: float | None = None,
                  counter: ProgressCounter | None = None) -> RecordingFit:
    """`counter`, if given, is told of the two steps: reading the recording, fitting (rig.models.fitting.progress).
    A window (`z_min_m`, `z_max_m`) that is inverted or keeps no pixel is a ValueError naming it (`in_window`)."""
    check_window(z_min_m, z_max_m)
    counter = counter or ProgressCounter(None, 2)
    counter.step("reading the recording")
    with Recording(path) as rec:
        samples = load_samples(rec)
        labels = rec.stop_labels()
        protocol = rec.protocol
        notes = recording_notes(rec)
        region = region_words(json_attr(rec.attrs, "camera"))
    frames = independence(samples.stops)
    if frames.correlated:  # the fit's errors are widened for it (rig.models.data.independence); say why, and the fix
        notes = [*notes, frames.sentence()]
    projector = samples.sources[0].projector_on if samples.sources else True
    samples = in_window(samples, z_min_m, z_max_m)
    counter.step("fitting k and lambda")
    fit = fit_power_law(samples)
    return RecordingFit(Path(path), protocol, projector, samples, fit, labels, notes, region)


def recording_notes(rec: Recording) -> list[str]:
    """What a reader of a fit must know about the recording (`Recording.notes`), less what cannot apply: an
    imported recording is written whole or not at all and names its stops after its folders, so a note that
    its planned stops (by distance) are missing, and that `rig run --resume` records them, is never true of it."""
    notes = rec.notes()
    if rec.protocol == IMPORTED:
        notes = [n for n in notes if not _MISSING_STOPS.match(n)]
    return notes


def check_window(z_min_m: float | None, z_max_m: float | None) -> None:
    """A ValueError naming the --z-min/--z-max window when it cannot hold a pixel whatever the recording: not a
    number, or inverted (--z-min above --z-max)."""
    for option, v in (("--z-min", z_min_m), ("--z-max", z_max_m)):
        if v is not None and not math.isfinite(v):
            raise ValueError(f"{option} {v}: the window's ends are ranges in metres; give a number, e.g. {option} 1.5")
    if z_min_m is not None and z_max_m is not None and z_min_m >= z_max_m:
        what = "inverted" if z_min_m > z_max_m else "empty"
        raise ValueError(f"the window --z-min {z_min_m:g} --z-max {z_max_m:g} is {what}: --z-min must be below --z-max"
                         + (f"; swap them: --z-min {z_max_m:g} --z-max {z_min_m:g}" if what == "inverted" else ""))


#: the nearest range a stereo depth camera measures (m): a window value under it, read as millimetres, is no range
NEAREST_RANGE_M = 0.1


def in_window(d: ModelData, z_min_m: float | None, z_max_m: float | None) -> ModelData:
    """The pixels of `d` whose mean range is in the window (m; None: open on that side). A window that keeps no
    pixel is a ValueError naming it and the recording's span, and saying so when it looks like millimetres."""
    check_window(z_min_m, z_max_m)
    if z_min_m is None and z_max_m is None:
        return d
    out = d.in_range(0.0 if z_min_m is None else z_min_m, math.inf if z_max_m is None else z_max_m)
    if len(out) or not len(d):
        return out
    lo, hi = float(d.z_m.min()), float(d.z_m.max())
    given = [(o, v) for o, v in (("--z-min", z_min_m), ("--z-max", z_max_m)) if v is not None]
    window = " ".join(f"{o} {v:g}" for o, v in given)
    message = f"no pixel in the window {window}: the recording's pixels span {lo:.3f}-{hi:.3f} m"
    lo_mm = -math.inf if z_min_m is None else z_min_m / 1000
    hi_mm = math.inf if z_max_m is None else z_max_m / 1000
    # millimetres only where each value, read as mm, is a range a depth camera sees (0.1 m and more): --z-min 5 is 5 m
    # past the farthest stop, not 5 mm
    plausible_mm = all(v / 1000 >= NEAREST_RANGE_M for _, v in given)
    if max(v for _, v in given) > hi and lo_mm <= hi and hi_mm >= lo and plausible_mm:
        raise ValueError(f"{message}; the window is in metres, and this looks like millimetres: "
                         + " ".join(f"{o} {v / 1000:g}" for o, v in given))
    raise ValueError(f"{message}; give a window (in metres) that overlaps it")
