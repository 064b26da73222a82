"""Open a camera and a stage from the strings users type, wired together for a run.

Device strings and their kinds are `drivers.registry`'s (`fake:`, `none:`, `grbl:///dev/ttyUSB0`,
`realsense:serial=123`, ...). This module adds what only the application knows: a simulated
camera and stage share one world; a simulated camera in front of a real stage follows the
stage's measured position; with simulated devices only, waiting advances the simulated clock.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from drivers.camera import DepthCamera
from drivers.registry import DeviceSpec, factory
from drivers.stage import Stage
from fakes.devices import FollowingStage, shared_world

__all__ = ["DeviceSpec", "RigDevices", "open_devices"]


@dataclass
class RigDevices:
    """A camera and a stage built from device strings, unopened, and how to wait between steps.

    With simulated devices only, waiting advances the simulated clock instead of sleeping.
    """

    camera: DepthCamera
    stage: Stage
    world: Any = None
    simulated: bool = False

    def sleep(self, seconds: float) -> None:
        if self.simulated:
            self.world.time_s += seconds
        else:
            time.sleep(seconds)


def open_devices(camera: str, stage: str, *, tilt_deg: float = 0.0, distance_m: float = 1.0) -> RigDevices:
    """Build the camera and stage from device strings. Devices are returned unopened."""
    cam_spec, stage_spec = DeviceSpec.parse(camera), DeviceSpec.parse(stage)
    make_camera = factory("camera", cam_spec.kind, camera)
    make_stage = factory("stage", stage_spec.kind, stage)
    context: dict[str, Any] = {"distance_m": distance_m, "tilt_deg": tilt_deg}
    world = shared_world(context)
    cam = make_camera(cam_spec, context)
    stg = make_stage(stage_spec, context)
    if cam_spec.kind == "fake" and stage_spec.kind != "fake":
        stg = FollowingStage(stg, world)
    simulated = cam_spec.kind == "fake" and stage_spec.kind in ("fake", "none")
    return RigDevices(cam, stg, world, simulated)
