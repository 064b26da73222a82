"""A stop's counting attributes, read with the stop: a value that is not a whole number is that stop's damage.

docs/data-format.md types `index`, `n_frames`, `frames_dropped`, `frames_duplicated`, `frames_repeated` and
`ir_saturated_pixels` as int. A reader that turned an attribute into an int at the point of use (`int(inf)`,
`int(nan)`) raised OverflowError or ValueError there and lost the whole file over one stop; here each is checked when
the stop is read, and a bad one is a RecordingError naming the stop, which readers skip as they skip any damaged stop
(its notes say so, and `rig run ... --resume` records it again).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

from .recording_errors import RecordingError

#: what the message of a damaged stop asks
REPAIR = "re-record it (rig run ... --resume; see docs/data-format.md)"
#: the attributes that count something (whole numbers >= 0)
COUNTS = ("index", "n_frames", "frames_dropped", "frames_duplicated", "frames_repeated", "ir_saturated_pixels")


def whole_number(raw: Any) -> int | None:
    """`raw` as an int if it is a finite whole number >= 0 (a numpy scalar included), else None."""
    if isinstance(raw, bool):
        return None
    try:
        v = float(raw)
    except (TypeError, ValueError):
        return None
    return int(v) if math.isfinite(v) and v >= 0 and v == int(v) else None


def count_attribute(attrs: Mapping[str, Any], key: str, default: int | None, path: str | Path, label: str) -> int | None:
    """The stop's attribute `key` as a whole number >= 0; `default` where it is absent; a RecordingError naming the
    stop where it is present and not one."""
    if key not in attrs:
        return default
    v = whole_number(attrs[key])
    if v is None:
        raw = attrs[key]
        raw = raw.item() if hasattr(raw, "item") else raw  # numpy's scalar as the number it is
        raise RecordingError(f"{path}: stop {label!r} attribute {key} is {raw!r}, not a whole number >= 0; the "
                             f"stop is damaged: {REPAIR}")
    return v


def number_attribute(attrs: Mapping[str, Any], key: str, path: str | Path, label: str) -> float:
    """The stop's attribute `key` as a float (NaN where absent: not known); a RecordingError naming the stop where it
    is not a number."""
    raw = attrs.get(key, math.nan)
    try:
        return float(raw)
    except (TypeError, ValueError):
        raise RecordingError(f"{path}: stop {label!r} attribute {key} is {raw!r}, not a number; see "
                             "docs/data-format.md") from None


def stop_counts(attrs: Mapping[str, Any], has_lag1: bool, path: str | Path, label: str) -> dict[str, int | None]:
    """Every counting attribute of the stop, checked (`count_attribute`; None where absent); `frames_repeated` is
    written with the lag-1 statistics, so a stop with `lag1_pairs` (`has_lag1`) and without it is damaged."""
    counts = {k: count_attribute(attrs, k, None, path, label) for k in COUNTS}
    if counts["frames_repeated"] is None and has_lag1:
        raise RecordingError(f"{path}: stop {label!r} has lag1_pairs but no frames_repeated (written together); the "
                             f"stop is damaged: {REPAIR}")
    return counts


def count_or_zero(attrs: Mapping[str, Any], key: str) -> int:
    """For notes about a stop that is read elsewhere: the count, or 0 where it is absent or damaged (the stop's own
    read names the damage)."""
    v = whole_number(attrs.get(key, 0))
    return 0 if v is None else v
