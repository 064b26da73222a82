"""The perpendicular experiment: the camera faces a wall square-on and steps away from it.

Paper, "Experimental setup": 300 frames at each distance from 0.5 m to 3.0 m in 0.25 m steps,
with fixed camera settings.
"""

from __future__ import annotations

from typing import Any, Iterator, Sequence

import numpy as np

from .capture_settings import CaptureSettings
from .plan_values import distance_m, frames
from .plan import Configure, Home, Move, Plan, Settle, Step

DEFAULT_STOPS_M = tuple(float(z) for z in np.round(np.arange(0.5, 3.0001, 0.25), 3))


def stop_label(z_m: float) -> str:
    return f"{z_m:.3f}m"


def perpendicular(stops_m: Sequence[float] = DEFAULT_STOPS_M, frames_per_stop: int = 300, **capture: Any) -> Plan:
    """Home, configure, then at each stop: move, settle, capture `frames_per_stop` frames.

    `capture`: the capture settings by name (`protocols.capture_settings.CaptureSettings`:
    projector_on, exposure_us, gain, settle_s, ir, ambient_frames, keep_raw).
    """
    settings = CaptureSettings.from_options("perpendicular", capture)
    if isinstance(stops_m, (str, bytes)) or not hasattr(stops_m, "__iter__"):
        raise ValueError(f"perpendicular: stops_m = {stops_m!r} must be a list of distances in m, e.g. [0.5, 0.75, 1.0]")
    stops = [distance_m("perpendicular", "stops_m", z) for z in stops_m]
    if not stops:
        raise ValueError("perpendicular: no stops given; pass stops_m, e.g. [0.5, 0.75, 1.0]")
    if len(set(stop_label(z) for z in stops)) != len(stops):
        raise ValueError("perpendicular: stops_m repeats a distance (to the mm); give each stop once")
    frames_per_stop = frames("perpendicular", "frames_per_stop", frames_per_stop)
    params = dict(stops_m=stops, frames_per_stop=frames_per_stop, **settings.to_params())

    def steps() -> Iterator[Step]:
        yield Home()
        yield Configure(settings.camera())
        for z in stops:
            yield Move(z)
            yield Settle(settings.settle_s)
            yield settings.capture(stop_label(z), frames_per_stop)

    return Plan("perpendicular", params, steps, stops_param="stops_m")
