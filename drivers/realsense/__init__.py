"""Intel RealSense D4xx depth cameras through librealsense (pyrealsense2). Camera kind `realsense`.

`camera` is the driver; `sdk` imports pyrealsense2 on demand and lists cameras; `identity`
reads calibration and identity at open; `frame_buffer` copies frames out of the SDK's thread;
`metadata` reads each frame's exposure, gain and projector state. Importing this package
never imports pyrealsense2.

`REALSENSE` is the kind's entry (drivers.registry), named by the entry point `rig.cameras` in pyproject.toml.
Its settings are the D4xx depth sensor's: exposure 1-165000 us, gain 16-248 (default and x1: 16), the scale
that is rig's own gain unit, so gain goes to the camera unchanged.
"""

from ..camera import GAIN_X1, GainScale
from ..registry import DeviceKind, Probe
from .camera import REALSENSE_OPTIONS, RealSenseCamera, open_realsense
from .metadata import projector_state
from .sdk import import_problem, list_realsense, sdk

REALSENSE = DeviceKind("realsense", "camera", open_realsense, REALSENSE_OPTIONS, Probe("realsense", list_realsense),
                       summary="Intel RealSense D4xx (librealsense)", exposure_us=(1.0, 165000.0),
                       gain=GainScale("gain", GAIN_X1, (GAIN_X1, 248.0)))

__all__ = ["REALSENSE", "RealSenseCamera", "open_realsense", "projector_state", "import_problem", "list_realsense", "sdk"]
