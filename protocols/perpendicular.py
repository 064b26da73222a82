"""The perpendicular experiment: the camera faces a wall square-on and steps away from it.

Paper, "Experimental setup": 300 frames at each distance from 0.5 m to 3.0 m in 0.25 m steps,
with fixed camera settings.
"""

from __future__ import annotations

from typing import Iterator, Sequence

import numpy as np

from drivers.camera import CameraSettings

from .plan import Capture, Configure, Home, Move, Plan, Settle, Step

DEFAULT_STOPS_M = tuple(float(z) for z in np.round(np.arange(0.5, 3.0001, 0.25), 3))


def stop_label(z_m: float) -> str:
    return f"{z_m:.3f}m"


def perpendicular(
    stops_m: Sequence[float] = DEFAULT_STOPS_M,
    frames_per_stop: int = 300,
    projector_on: bool = True,
    exposure_us: float = 8500.0,
    gain: float = 16.0,
    settle_s: float = 1.0,
    ir: bool = True,
    ambient_frames: int = 0,
    keep_raw: bool = False,
) -> Plan:
    """Home, configure, then at each stop: move, settle, capture `frames_per_stop` frames."""
    stops = [float(z) for z in stops_m]
    if not stops:
        raise ValueError("perpendicular: no stops given; pass stops_m, e.g. [0.5, 0.75, 1.0]")
    if frames_per_stop < 2:
        raise ValueError(f"perpendicular: frames_per_stop={frames_per_stop}; at least 2 frames are needed for a variance")
    settings = CameraSettings(projector_on=projector_on, exposure_us=exposure_us, gain=gain, auto_exposure=False)
    params = dict(stops_m=stops, frames_per_stop=frames_per_stop, projector_on=projector_on, exposure_us=exposure_us,
                  gain=gain, settle_s=settle_s, ir=ir, ambient_frames=ambient_frames, keep_raw=keep_raw)

    def steps() -> Iterator[Step]:
        yield Home()
        yield Configure(settings)
        for z in stops:
            yield Move(z)
            yield Settle(settle_s)
            yield Capture(stop_label(z), frames_per_stop, ir=ir, ambient_frames=ambient_frames, keep_raw=keep_raw)

    return Plan("perpendicular", params, steps)
