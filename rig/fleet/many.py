"""The fits of many recordings at once: the paper's (`rig fit --many DIR`, a lab characterising a shelf of cameras)
and one model's for a comparison (`rig compare a.h5 b.h5`, `rig repeatability`: `fit_for_comparison`).

Each recording is read and fitted in a worker process of a pool (one per core by default), and reported
as it finishes; a recording that cannot be fitted is reported with its one-line reason and the others go on.
The work of one recording is independent of the others', so the same function runs unchanged on a Dask cluster
(`rig.fleet.executors`: --scheduler, or RIG_SCHEDULER; docs/performance.md, "Past one machine"). Paths leave this
process absolute (`portable`), for workers with other working directories, and come back as they were given.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterator

from protocols.recording import Recording, RecordingError

from ..analysis import fit_recording, in_window, recording_notes
from ..diagnosis import headline
from ..diagnosis.bins import pooled_sigma, sigma_by_range
from ..models import Catalogue, load_samples
from ..recordings.recording_fits import PAPER, FitJob, RecordingResult, model_for, summarise
from ..reports.result_json import document, fit_json
from .executors import run_each


@dataclass
class ManyRow:
    """One recording's fit, or why it has none."""

    path: Path
    k: float = float("nan")
    se_k: float = float("nan")
    lam: float = float("nan")
    se_lam: float = float("nan")
    headline_pct: float = float("nan")
    verdict: str = ""
    pixel_stops: int = 0
    error: str = ""
    document: dict | None = None  # the recording's `rig fit --json` document (docs/json.md)


def recordings_in(folder: Path) -> list[Path]:
    """The recordings of a folder (*.h5, not hidden), in name order."""
    return sorted(p for p in folder.glob("*.h5") if not p.name.startswith("."))


def fit_one(path: Path) -> ManyRow:
    """The paper's fit of one recording and its headline error (in a worker: plain data back)."""


    try:
        r = fit_recording(path)
        h = headline(r.fit, r.samples.positive_variance())
    except (ValueError, RecordingError, OSError) as e:
        return ManyRow(path, error=str(e))
    doc = document("fit", path, r.notes, [fit_json(r.fit, h)], best=r.fit.model.name)
    return ManyRow(path, r.fit.k, r.fit.se_k, r.fit.lam, r.fit.se_lam, h.error_pct, h.verdict(), r.fit.n_obs, document=doc)


def portable(path: str | Path) -> Path:
    """`path` as a worker finds it whatever its working directory: absolute, from this process's (links are kept,
    not resolved: a worker on another machine may see the link and not its target)."""
    return Path(path).absolute()


def fit_many(paths: list[Path], jobs: int | None = None, scheduler: str | None = None,
             timeout_s: float | None = None) -> Iterator[ManyRow]:
    """Fit every recording, `jobs` at a time (default: one per core), or on the Dask cluster at `scheduler`
    (`rig.fleet.executors`, with its `timeout_s`); rows come as recordings finish, each with its path as given."""
    given = {portable(p): Path(p) for p in paths}
    for row in run_each(fit_one, list(given), jobs=jobs, scheduler=scheduler, timeout_s=timeout_s):
        path = given[row.path]
        yield replace(row, path=path, document=row.document and {**row.document, "file": str(path)})


def fit_all_for_comparison(jobs: list[FitJob], workers: int | None = None, scheduler: str | None = None,
                           timeout_s: float | None = None) -> Iterator[RecordingResult]:
    """`fit_for_comparison` of every job, `workers` at a time or on the cluster at `scheduler` (`fit_many`), as they
    finish, each with its path as given; a recording given twice is fitted once (its first job) and reported twice."""
    sent: dict[str, FitJob] = {}
    given: dict[str, list[str]] = {}
    for job in jobs:
        path = str(portable(job.path))
        sent.setdefault(path, replace(job, path=path))
        given.setdefault(path, []).append(job.path)
    for r in run_each(fit_for_comparison, list(sent.values()), jobs=workers, scheduler=scheduler, timeout_s=timeout_s):
        for path in given[r.path]:
            yield replace(r, path=path)


def fit_for_comparison(job: FitJob) -> RecordingResult:
    """Fit `job.model` to the recording at `job.path` (in a worker: plain data back, errors as a one-line `error`)."""

    try:
        return _fit(job)
    except (ValueError, RecordingError, OSError) as e:
        return RecordingResult(job.path, error=str(e).splitlines()[0] if str(e) else type(e).__name__)


def _fit(job: FitJob) -> RecordingResult:


    notes: list[str] = []
    if job.model in (None, PAPER):
        r = fit_recording(job.path, z_min_m=job.z_min_m, z_max_m=job.z_max_m)
        fit, d, notes, on = r.fit, r.samples.positive_variance(), list(r.notes), r.projector_on
        measured = r.measured
    else:
        with Recording(job.path) as rec:
            d = in_window(load_samples(rec).positive_variance(), job.z_min_m, job.z_max_m)
            notes = recording_notes(rec)
            labels = rec.stop_labels()
        on = bool(d.projector_on.any())
        catalogue = Catalogue.default()
        for f in job.effects:
            catalogue = catalogue.with_file(f)
        model, note = model_for(job.model, on, catalogue)
        notes += [note] if note else []
        fit = model.fit(d)
        measured = pooled_sigma(d, d.stop, labels) if len(labels) > 1 else sigma_by_range(d)
    h = headline(fit, d)
    with Recording(job.path) as rec:
        return summarise(job.path, fit, d, h, measured, rec, notes, on)
