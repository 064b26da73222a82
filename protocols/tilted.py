"""The tilted experiment: the camera held still before a wall tilted about the vertical axis.

Paper, "Experimental setup": 600 frames without moving the camera cover about 0.5-2.0 m
across the image. With a 90 degree horizontal field of view (D435 at fx = 425 px, 848 px
wide) a wall at 0.8 m on the optical axis tilted by 31 degrees spans Z = 0.8 / (1 + tan(31) x)
for x in [-1, 1], i.e. 0.5-2.0 m.
"""

from __future__ import annotations

from typing import Iterator

from drivers.camera import CameraSettings

from .plan import Capture, Configure, Home, Move, Plan, Settle, Step


def tilted(
    tilt_deg: float = 31.0,
    distance_m: float = 0.8,
    frames: int = 600,
    projector_on: bool = True,
    exposure_us: float = 8500.0,
    gain: float = 16.0,
    settle_s: float = 1.0,
    ir: bool = True,
    ambient_frames: int = 0,
    keep_raw: bool = False,
) -> Plan:
    """Configure, place the camera at `distance_m` from the wall's centre, capture `frames` frames."""
    if frames < 2:
        raise ValueError(f"tilted: frames={frames}; at least 2 frames are needed for a variance")
    settings = CameraSettings(projector_on=projector_on, exposure_us=exposure_us, gain=gain, auto_exposure=False)
    params = dict(tilt_deg=tilt_deg, distance_m=distance_m, frames=frames, projector_on=projector_on,
                  exposure_us=exposure_us, gain=gain, settle_s=settle_s, ir=ir, ambient_frames=ambient_frames,
                  keep_raw=keep_raw)

    def steps() -> Iterator[Step]:
        yield Home()
        yield Configure(settings)
        yield Move(distance_m)
        yield Settle(settle_s)
        yield Capture("tilted", frames, ir=ir, ambient_frames=ambient_frames, keep_raw=keep_raw)

    return Plan("tilted", params, steps)
