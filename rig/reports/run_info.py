"""What a report says about the run it comes from: when, with which camera and settings, on which stage.

Read from the recording's root attributes (docs/data-format.md: `started_utc`, `ended_utc`,
`software_version`, `camera` and `stage` as their `describe()`, `protocol`, `protocol_params`)
and the first stop's settings as the camera read them back. Anything the file does not hold is
"not recorded", never a guess.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocols.recording import Recording, RecordingError

from protocols.region_of_interest import region_words

from ..recordings.camera_setup import json_attr

NOT_RECORDED = "not recorded"


@dataclass
class RunInfo:
    """The run's metadata as (key, label, value) rows; `key` names the row for scripts reading the page."""

    rows: list[tuple[str, str, str]] = field(default_factory=list)

    def value(self, key: str) -> str:
        return next(v for k, _, v in self.rows if k == key)


def _text(v: Any) -> str:
    if v is None or v == "":
        return NOT_RECORDED
    if isinstance(v, bool):
        return "on" if v else "off"
    return str(v)


def _setting(requested: dict, read_back: dict, key: str, unit: str = "") -> str:
    """'8500 us' (as requested and read back), or both when they differ."""
    asked, got = requested.get(key), read_back.get(key)
    fmt = (lambda v: _text(v) if isinstance(v, bool) or not isinstance(v, (int, float)) else f"{v:g}{unit}")
    if got is None:
        return NOT_RECORDED if asked is None else f"{fmt(asked)} (requested; not read back)"
    if asked is None or asked == got:
        return fmt(got)
    return f"{fmt(got)} (requested {fmt(asked)})"


def run_info(path: str | Path, report_utc: str, rig_version: str) -> RunInfo:
    """The metadata of the recording at `path`, with the report's own date and rig version."""
    with Recording(path) as rec:
        a = rec.attrs
        camera, stage, params = json_attr(a, "camera"), json_attr(a, "stage"), rec.protocol_params
        labels = rec.stop_labels()
        first = None
        for label in labels:  # the settings of the first stop that reads: a damaged one is skipped, as rig fit skips it
            try:
                first = rec.stop(label)
                break
            except RecordingError:
                continue
        read_back = first.settings_read_back if first is not None else {}
        requested = {**{k: params[k] for k in ("exposure_us", "gain", "projector_on") if k in params},
                     **(first.settings_requested if first is not None else {})}
        protocol = rec.protocol
    ended = a.get("ended_utc")
    tilt = f", wall tilted {params['tilt_deg']:g} deg" if isinstance(params.get("tilt_deg"), (int, float)) else ""
    stage_text = NOT_RECORDED
    if stage:
        limits = stage.get("limits_m")
        numbers = isinstance(limits, list) and len(limits) == 2 and all(isinstance(x, (int, float)) for x in limits)
        travel = f", travel {limits[0]:g}-{limits[1]:g} m" if numbers else ""
        stage_text = f"{stage.get('name', stage.get('kind', 'stage'))}{travel}" + (" (simulated)" if stage.get("simulated") else "")
    rows = [
        ("file", "recording", str(path)),
        ("recorded_utc", "recorded (UTC)", f"{_text(a.get('started_utc'))} to "
                                           f"{ended if ended else 'not finished (interrupted)'}"),
        ("report_utc", "report made (UTC)", report_utc),
        ("rig_version", "rig version (this report)", rig_version),
        ("recorded_with", "recorded with rig", _text(a.get("software_version"))),
        ("camera_model", "camera", _camera_model(camera, a)),
        ("camera_serial", "camera serial", _text(camera.get("serial") or a.get("camera_serial"))),
        ("camera_firmware", "camera firmware", _text(camera.get("firmware"))),
        ("exposure", "exposure", _setting(requested, read_back, "exposure_us", " us")),
        ("gain", "gain", _setting(requested, read_back, "gain")),
        ("projector", "IR projector", _setting(requested, read_back, "projector_on")),
        ("stage", "stage", stage_text),
        ("protocol", "protocol", f"{protocol}{tilt}"),
        ("region", "image recorded", region_words(camera) or "the whole image"),
        ("stops", "stops", f"{len(labels)}: {', '.join(labels[:12])}{', ...' if len(labels) > 12 else ''}"
         + (f"; {params['frames_per_stop']} frames each" if "frames_per_stop" in params else "")),
    ]
    return RunInfo(rows)


def _camera_model(camera: dict, attrs: dict) -> str:
    model = _text(camera.get("model") or attrs.get("camera_model"))
    return model + " (simulated)" if camera.get("simulated") and "simulated" not in model else model
