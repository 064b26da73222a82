"""Open a camera and a stage from the strings users type, wired together for a run.

Device strings and their kinds are `drivers.registry`'s (`fake:`, `none:`, `grbl:///dev/ttyUSB0`,
`realsense:serial=123`, ...): every kind, the simulator's included, is a plugin found by its entry point,
so a run on real devices never imports the simulator. The camera and stage are built with one shared
context; the hooks their factories leave in it (`drivers.registry.ON_BUILT`) then wire them together:
the simulated camera makes its wall follow a real stage, and puts a wholly simulated rig on its own clock.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

from drivers.camera import DepthCamera
from drivers.registry import ON_BUILT, DeviceSpec, factory
from drivers.stage import Stage

__all__ = ["DeviceSpec", "RigDevices", "open_devices"]


@dataclass
class RigDevices:
    """A camera and a stage built from device strings, unopened, and how to wait between steps.

    clock: set by devices that run on a simulated clock (the simulated rig): waiting advances it instead of
    sleeping.
    """

    camera: DepthCamera
    stage: Stage
    clock: Callable[[float], None] | None = None

    @property
    def simulated(self) -> bool:
        return self.clock is not None

    def sleep(self, seconds: float) -> None:
        if self.clock is not None:
            self.clock(seconds)
        else:
            time.sleep(seconds)


def open_devices(camera: str, stage: str, *, tilt_deg: float = 0.0, distance_m: float = 1.0) -> RigDevices:
    """Build the camera and stage from device strings. Devices are returned unopened.

    tilt_deg and distance_m place the wall a simulated camera looks at (they mean nothing to a real one)."""
    cam_spec, stage_spec = DeviceSpec.parse(camera), DeviceSpec.parse(stage)
    make_camera = factory("camera", cam_spec.kind, camera)  # both kinds known before either device is built
    make_stage = factory("stage", stage_spec.kind, stage)
    context: dict[str, Any] = {"distance_m": distance_m, "tilt_deg": tilt_deg}
    devices = RigDevices(make_camera(cam_spec, context), make_stage(stage_spec, context))
    for hook in context.get(ON_BUILT, []):
        hook(devices)
    return devices
