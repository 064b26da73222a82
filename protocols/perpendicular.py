"""The perpendicular experiment: the camera faces a wall square-on and steps away from it.

Paper, "Experimental setup": 300 frames at each distance from 0.5 m to 3.0 m in 0.25 m steps,
with fixed camera settings.
"""

from __future__ import annotations

from typing import Any, Iterator, Sequence

import numpy as np

from .capture_settings import CaptureSettings
from .plan import Configure, Home, Move, Plan, Settle, Step
from .plan_values import ProtocolParam, distance_m
from .protocol_spec import ProtocolSpec

DEFAULT_STOPS_M = tuple(float(z) for z in np.round(np.arange(0.5, 3.0001, 0.25), 3))


def stop_label(z_m: float) -> str:
    return f"{z_m:.3f}m"


def check_stops(where: str, name: str, value: Any) -> list[float]:
    """A list of camera-to-wall distances in m, at least one, none repeated (to the mm: the stops' labels)."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise ValueError(f"{where}: {name} = {value!r} must be a list of distances in m, e.g. [0.5, 0.75, 1.0]")
    stops = [distance_m(where, name, z) for z in value]
    if not stops:
        raise ValueError(f"{where}: no stops given; pass {name}, e.g. [0.5, 0.75, 1.0]")
    if len(set(stop_label(z) for z in stops)) != len(stops):
        raise ValueError(f"{where}: {name} repeats a distance (to the mm); give each stop once")
    return stops


def steps(settings: CaptureSettings, *, stops_m: list[float], frames_per_stop: int) -> Iterator[Step]:
    """Home, configure, warm up (when asked), then at each stop: move, settle, capture `frames_per_stop` frames."""
    yield Home()
    yield Configure(settings.camera())
    yield from settings.warm_up()
    for z in stops_m:
        yield Move(z)
        yield Settle(settings.settle_s)
        yield settings.capture(stop_label(z), frames_per_stop)


PERPENDICULAR = ProtocolSpec(
    "perpendicular", steps,
    params=(ProtocolParam("stops_m", list, DEFAULT_STOPS_M, "m", "Stops [m]", "camera-to-wall distances of the stops",
                          check_stops, option="--stops"),),
    stops_param="stops_m", frames_per_stop=300, default_stage="fake:",
    summary="the camera faces a wall square-on and steps away from it")


def perpendicular(stops_m: Sequence[float] = DEFAULT_STOPS_M, **params: Any) -> Plan:
    """The plan (`PERPENDICULAR`): at each of `stops_m` capture `frames_per_stop` frames (default 300).

    `params`: frames_per_stop and the capture settings by name (`protocols.capture_settings.CaptureSettings`:
    projector_on, exposure_us, gain, settle_s, ir, ambient_frames, keep_raw, warm_up_*).
    """
    return PERPENDICULAR.plan(stops_m=stops_m, **params)
