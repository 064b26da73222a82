"""The simulated devices as kinds (`fake:` camera, `fake:` stage), registered as any plugin is: by the entry
points `rig.cameras` / `rig.stages` in pyproject.toml, which name these entries. Nothing below the
application names them; loading an entry imports no simulator (its factory and table are imported on use).
"""

from __future__ import annotations

from drivers.camera import GAIN_X1, GainScale
from drivers.registry import DeviceKind

#: what the fake camera takes: a D435's exposure range and its gain scale (rig's own, 16 = x1)
EXPOSURE_RANGE_US = (1.0, 165000.0)
GAIN = GainScale("gain", GAIN_X1, (GAIN_X1, 248.0))

FAKE_CAMERA = DeviceKind("fake", "camera", "fakes.devices:fake_camera", "fakes.camera:FAKE_CAMERA_OPTIONS",
                         summary="the simulated camera (a D435 looking at a flat wall)", simulated=True,
                         exposure_us=EXPOSURE_RANGE_US, gain=GAIN)
FAKE_STAGE = DeviceKind("fake", "stage", "fakes.devices:fake_stage", "fakes.devices:FAKE_STAGE_OPTIONS",
                        summary="the simulated stage (moves the simulated camera's wall)", simulated=True)
