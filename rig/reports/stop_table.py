"""The per-stop table of a fit (`rig fit --table stops.csv`): what each stop measured and what the model says.

One row per stop of the fitted pixels, in capture order:

    stop               the stop's label ("1.000m")
    range_m            its range: the pixels' mean range weighted by their degrees of freedom, m
    pixels             pixels fitted at this stop (two or more valid samples; inside --z-min/--z-max)
    samples            valid depth samples in them
    measured_sigma_m   pooled measured sigma_Z: sqrt(sum M2 / sum (n - 1)), m
    model_sigma_m      the fitted model's sigma_Z pooled the same way: sqrt(sum (n - 1) var / sum (n - 1)), m
    fill_rate          mean over those pixels of the share of the stop's frames with a valid depth (as
                       `rig diagnose` shows it)

Plain CSV (the csv module, a header row, numbers as Python writes them: they read back exactly).
"""

from __future__ import annotations

import csv
from dataclasses import astuple, dataclass, fields
from pathlib import Path

import numpy as np

from ..models import ModelData, ModelFit
from ..models.data.group_sums import group_sums


@dataclass(frozen=True)
class StopRow:
    stop: str
    range_m: float
    pixels: int
    samples: int
    measured_sigma_m: float
    model_sigma_m: float
    fill_rate: float


COLUMNS = tuple(f.name for f in fields(StopRow))


def stop_rows(fit: ModelFit, d: ModelData) -> list[StopRow]:
    """The table of `fit` on the pixels it was fitted to, `d` (visited a few stops at a time)."""
    labels = d.stops.label if d.stops is not None else None
    totals: dict[int, np.ndarray] = {}
    for c in d.pass_pieces():
        var_model = np.broadcast_to(np.asarray(fit.predict(c).var_m2, dtype=float), c.z_m.shape)
        w = c.nu
        keys, sums = group_sums(c.stop, [1.0, w, w * c.z_m, c.n, c.m2_m2, w * var_model, c.fill])
        for key, row in zip(keys.tolist(), sums):
            totals[key] = totals[key] + row if key in totals else row
    rows = []
    for s in sorted(totals):
        pixels, weight, wz, samples, m2, wvar, fill = totals[s]
        if weight <= 0:
            continue
        rows.append(StopRow(
            stop=labels[int(s)] if labels is not None else str(int(s)),
            range_m=float(wz / weight),
            pixels=int(pixels),
            samples=int(samples),
            measured_sigma_m=float(np.sqrt(m2 / weight)),
            model_sigma_m=float(np.sqrt(wvar / weight)),
            fill_rate=float(fill / pixels),
        ))
    return rows


def write_stop_table(rows: list[StopRow], path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(COLUMNS)
        out.writerows(astuple(r) for r in rows)
    return path
