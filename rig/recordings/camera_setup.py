"""What a recording was made with, as plain data, and what of it differs between recordings: the camera's geometry
(depth unit, baseline, intrinsics, resolution), its settings (exposure, gain, projector) and its identity (model,
serial, firmware).

Read from the recording (docs/data-format.md): the /camera attributes, the first stop's settings as the camera read
them back (else as requested, else the plan's), the root `camera` description and `camera_model`/`camera_serial`.
What the file does not hold is None ("not recorded"), never a guess.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from protocols.recording import Recording, RecordingError


@dataclass(frozen=True)
class Item:
    """One thing of the set-up: its key in `read_setup`'s dict, its name in words, the unit it is shown in (with the
    factor from the stored value), and what a difference in it does to the range noise."""

    key: str
    label: str
    unit: str
    factor: float
    effect: str
    #: the parameters of sigma = k Z^lambda a difference in it changes ("*": any)
    moves: tuple[str, ...]


#: the set-up, in the order a comparison names its differences (the geometry first: its effects are exact)
ITEMS = (
    Item("depth_unit_m", "depth unit", "mm", 1e3, "rounding to the depth unit q adds q^2/12 to the variance where the "
         "noise is well above q (Sheppard), and levels the error off at short range", ("k", "lambda")),
    Item("baseline_m", "baseline", "mm", 1e3, "sigma_Z = Z^2 sigma_d / (f b): k scales as 1/b", ("k",)),
    Item("fx_px", "fx", "px", 1.0, "sigma_Z = Z^2 sigma_d / (f b): k scales as 1/f", ("k",)),
    Item("fy_px", "fy", "px", 1.0, "another lens or calibration: the off-axis geometry changes", ("*",)),
    Item("cx_px", "cx", "px", 1.0, "the optical axis moves: effects that grow off axis change", ("*",)),
    Item("cy_px", "cy", "px", 1.0, "the optical axis moves: effects that grow off axis change", ("*",)),
    Item("width_px", "width", "px", 1.0, "another resolution bins or crops pixels: f and the disparity noise in px "
         "change together", ("*",)),
    Item("height_px", "height", "px", 1.0, "another resolution bins or crops pixels", ("*",)),
    Item("exposure_us", "exposure", "us", 1.0, "the signal scales with the exposure: k (as 1/sqrt(exposure) where shot "
         "noise dominates)", ("k",)),
    Item("gain", "gain", "", 1.0, "the image noise changes with the gain: k", ("k",)),
    Item("projector_on", "projector", "", 1.0, "the projector sets the law: lambda = 3 with it on, 2 with it off",
         ("k", "lambda")),
    Item("firmware", "firmware", "", 1.0, "the depth processing (filters, the matcher's step) can change", ("*",)),
    Item("camera_model", "camera model", "", 1.0, "another camera model: any parameter can change", ("*",)),
    Item("camera_serial", "camera serial", "", 1.0, "another unit of the camera: what a comparison of units tests",
         ("*",)),
)
BY_KEY = {i.key: i for i in ITEMS}


def json_attr(attrs: Any, key: str) -> dict[str, Any]:
    """A recording attribute holding a JSON object (`camera`, `stage`), as a dict; {} if absent or not one."""
    try:
        v = json.loads(attrs.get(key, "{}"))
    except (TypeError, ValueError):
        return {}
    return v if isinstance(v, dict) else {}


def _plain(v: Any) -> Any:
    """A value as JSON holds it (numpy scalars as int, float or bool), text as str; '' and NaN (what an import that
    was not told the exposure or gain records) as None: not recorded."""
    if v is None or v == "" or (isinstance(v, (float, np.floating)) and not np.isfinite(v)):
        return None
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v)
    return str(v)


def read_setup(rec: Recording) -> dict[str, Any]:
    """The set-up of the open recording `rec`: {item key: value or None}, the keys of `ITEMS`."""
    cal, attrs = rec.calibration, rec.attrs
    camera, params = json_attr(attrs, "camera"), rec.protocol_params
    labels = rec.stop_labels()
    try:
        first = rec.stop(labels[0], third_moment=False) if labels else None
    except RecordingError:  # a first stop that cannot be read: the plan's settings alone
        first = None
    settings = {**{k: params[k] for k in ("exposure_us", "gain", "projector_on") if k in params},
                **(first.settings_requested if first is not None else {}),
                **(first.settings_read_back if first is not None else {})}
    values = {
        "depth_unit_m": cal.depth_scale_m, "baseline_m": cal.baseline_m, "fx_px": cal.fx, "fy_px": cal.fy,
        "cx_px": cal.cx, "cy_px": cal.cy, "width_px": cal.width, "height_px": cal.height,
        "exposure_us": settings.get("exposure_us"), "gain": settings.get("gain"),
        "projector_on": settings.get("projector_on"), "firmware": camera.get("firmware"),
        "camera_model": camera.get("model") or attrs.get("camera_model"),
        "camera_serial": camera.get("serial") or attrs.get("camera_serial"),
    }
    return {k: _plain(v) for k, v in values.items()}


def shown(item: Item, value: Any) -> str:
    """A value in words: "0.1 mm", "8500 us", "on", "not recorded"."""
    if value is None:
        return "not recorded"
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, (int, float)):
        return f"{value * item.factor:.6g}" + (f" {item.unit}" if item.unit else "")
    return str(value)


def _same(x: Any, y: Any) -> bool:
    """Equal, numbers to 1e-9 of their size (a value written as float32 and read back as float64 is the same)."""
    numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (x, y))
    if numbers:
        return abs(x - y) <= 1e-9 * max(abs(x), abs(y))
    return x == y


@dataclass(frozen=True)
class SetupDifference:
    """One item of the set-up that is not the same in every recording: its values, in the recordings' order."""

    item: Item
    values: tuple[Any, ...]

    def sentence(self, names: list[str]) -> str:
        """"depth unit 0.1 mm in a.h5 against 1 mm in b.h5 (rounding ...)"."""
        where = " against ".join(f"{shown(self.item, v)} in {n}" for v, n in zip(self.values, names))
        return f"{self.item.label} {where} ({self.item.effect})"


def setup_differences(setups: list[dict[str, Any]]) -> list[SetupDifference]:
    """The items whose values are not all the same, in the order of `ITEMS`. An item no recording recorded is no
    difference; one recorded in some only is (its value is not known to be the same)."""
    out = []
    for item in ITEMS:
        values = tuple(s.get(item.key) for s in setups)
        if all(v is None for v in values):
            continue
        if not all(_same(values[0], v) for v in values[1:]):
            out.append(SetupDifference(item, values))
    return out
