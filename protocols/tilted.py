"""The tilted experiment: the camera held still before a wall tilted about the vertical axis.

Paper, "Experimental setup": 600 frames without moving the camera cover about 0.5-2.0 m
across the image. With a 90 degree horizontal field of view (D435 at fx = 425 px, 848 px
wide) a wall at 0.8 m on the optical axis tilted by 31 degrees spans Z = 0.8 / (1 + tan(31) x)
for x in [-1, 1], i.e. 0.5-2.0 m.
"""

from __future__ import annotations

from typing import Any, Iterator

from .capture_settings import CaptureSettings
from .plan import Configure, Home, Move, Plan, Settle, Step
from .plan_values import ProtocolParam, between, distance_m as check_distance
from .protocol_spec import ProtocolSpec

def steps(settings: CaptureSettings, *, tilt_deg: float, distance_m: float, frames_per_stop: int) -> Iterator[Step]:
    """Configure, warm up (when asked), place the camera at `distance_m` from the wall's centre, capture `frames_per_stop` frames."""
    yield Home()
    yield Configure(settings.camera())
    yield from settings.warm_up()
    yield Move(distance_m)
    yield Settle(settings.settle_s)
    yield settings.capture("tilted", frames_per_stop)


TILTED = ProtocolSpec(
    "tilted", steps,
    params=(ProtocolParam("tilt_deg", float, 31.0, "deg", "Tilt [deg]", "the wall's angle to the image plane",
                          between(0.0, 75.0, "degrees (the wall's angle to the image plane)")),
            ProtocolParam("distance_m", float, 0.8, "m", "Distance [m]",
                          "camera to the wall's centre, on the optical axis", check_distance)),
    stops_param="distance_m", frames_per_stop=600, default_stage="none:",
    wall={"tilt_deg": "tilt_deg", "distance_m": "distance_m"},
    summary="the camera held still before a tilted wall: one stop spans a range of distances")


def tilted(**params: Any) -> Plan:
    """The plan (`TILTED`): one capture of `frames_per_stop` frames (default 600; `frames`, its old name, is
    still read) with the camera `distance_m` (0.8) from a wall tilted by `tilt_deg` (31).

    `params`: those and the capture settings by name (`protocols.capture_settings.CaptureSettings`).
    """
    return TILTED.plan(**params)
