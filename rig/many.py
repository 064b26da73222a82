"""The paper's fit of many recordings at once (`rig fit --many DIR`): a lab characterising a shelf of cameras.

Each recording is read and fitted in a worker process of a pool (one per core by default), and reported
as it finishes; a recording that cannot be fitted is reported with its one-line reason and the others go on.
The work of one recording is independent of the others', so the same function runs unchanged on an engine
that spreads it over machines (docs/performance.md, "Scale").
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator


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
    from protocols.recording import RecordingError

    from .analysis import fit_recording
    from .diagnosis import headline
    from .reports.result_json import document, fit_json

    try:
        r = fit_recording(path)
        h = headline(r.fit, r.samples.positive_variance())
    except (ValueError, RecordingError, OSError) as e:
        return ManyRow(path, error=str(e))
    doc = document("fit", path, r.notes, [fit_json(r.fit, h)], best=r.fit.model.name)
    return ManyRow(path, r.fit.k, r.fit.se_k, r.fit.lam, r.fit.se_lam, h.error_pct, h.verdict(), r.fit.n_obs, document=doc)


def fit_many(paths: list[Path], jobs: int | None = None) -> Iterator[ManyRow]:
    """Fit every recording, `jobs` at a time (default: one per core); rows come as recordings finish."""
    jobs = max(1, jobs or os.cpu_count() or 1)
    if jobs == 1 or len(paths) <= 1:
        for p in paths:
            yield fit_one(p)
        return
    with ProcessPoolExecutor(max_workers=min(jobs, len(paths))) as pool:
        futures = [pool.submit(fit_one, p) for p in paths]
        for f in as_completed(futures):
            yield f.result()
