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
    truth_m, truth_source   where the wall was and how that is known ("stage measured", "stage commanded",
                       "plan"; rig.accuracy); empty where nothing says
    depth_accuracy_pct, depth_accuracy_se_pct   the signed median of (Z - truth) / truth, %, and its error
    spatial_rms_m, spatial_rms_noise_m   the RMS about a plane fitted to the stop's depth, m, and what the pixels'
                       temporal noise alone adds to it
    model_bias_m       the bias model's Z - truth at the stop (rig.accuracy.bias), m; empty where it is not fitted

Plain CSV (the csv module, a header row, numbers as Python writes them: they read back exactly).
"""

from __future__ import annotations

import csv
from dataclasses import astuple, dataclass, fields, replace
from pathlib import Path

import numpy as np

from ..accuracy import Accuracy
from .output_file import aside
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
    truth_m: float | str = ""
    truth_source: str = ""
    depth_accuracy_pct: float | str = ""
    depth_accuracy_se_pct: float | str = ""
    spatial_rms_m: float | str = ""
    spatial_rms_noise_m: float | str = ""
    model_bias_m: float | str = ""


COLUMNS = tuple(f.name for f in fields(StopRow))


def stop_rows(fit: ModelFit, d: ModelData, accuracy: Accuracy | None = None) -> list[StopRow]:
    """The table of `fit` on the pixels it was fitted to, `d` (visited a few stops at a time), with each stop's
    `accuracy` where given."""
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
    return [_with_accuracy(r, accuracy) for r in rows] if accuracy is not None else rows


def _with_accuracy(row: StopRow, a: Accuracy) -> StopRow:
    s = next((s for s in a.stops if s.stop == row.stop), None)
    if s is None:
        return row
    bias = float(a.bias.bias_m(s.truth_m)) if a.bias is not None else ""
    return replace(row, truth_m=s.truth_m, truth_source=s.truth_source, depth_accuracy_pct=s.depth_accuracy_pct,
                   depth_accuracy_se_pct=s.depth_accuracy_se_pct, spatial_rms_m=s.spatial_rms_m,
                   spatial_rms_noise_m=s.spatial_rms_noise_m, model_bias_m=bias)


def write_stop_table(rows: list[StopRow], path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with aside(path) as tmp, open(tmp, "w", newline="") as f:  # whole or not at all (rig.reports.output_file)
        out = csv.writer(f)
        out.writerow(COLUMNS)
        out.writerows(astuple(r) for r in rows)
    return path
