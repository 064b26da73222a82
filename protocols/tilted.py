"""The tilted experiment: the camera held still before a wall tilted about the vertical axis.

Paper, "Experimental setup": 600 frames without moving the camera cover about 0.5-2.0 m
across the image. With a 90 degree horizontal field of view (D435 at fx = 425 px, 848 px
wide) a wall at 0.8 m on the optical axis tilted by 31 degrees spans Z = 0.8 / (1 + tan(31) x)
for x in [-1, 1], i.e. 0.5-2.0 m.
"""

from __future__ import annotations

from typing import Any, Iterator

from .capture_settings import CaptureSettings
from .plan_values import distance_m as check_distance, frames as check_frames, number
from .plan import Configure, Home, Move, Plan, Settle, Step


def tilted(tilt_deg: float = 31.0, distance_m: float = 0.8, frames: int = 600, **capture: Any) -> Plan:
    """Configure, place the camera at `distance_m` from the wall's centre, capture `frames` frames.

    `capture`: the capture settings by name (`protocols.capture_settings.CaptureSettings`).
    """
    settings = CaptureSettings.from_options("tilted", capture)
    frames = check_frames("tilted", "frames", frames)
    tilt_deg = number("tilted", "tilt_deg", tilt_deg, 0.0, 75.0, "degrees (the wall's angle to the image plane)")
    distance_m = check_distance("tilted", "distance_m", distance_m)
    params = dict(tilt_deg=tilt_deg, distance_m=distance_m, frames=frames, **settings.to_params())

    def steps() -> Iterator[Step]:
        yield Home()
        yield Configure(settings.camera())
        yield Move(distance_m)
        yield Settle(settings.settle_s)
        yield settings.capture("tilted", frames)

    return Plan("tilted", params, steps, stops_param="distance_m")
