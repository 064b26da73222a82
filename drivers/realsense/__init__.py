"""Intel RealSense D4xx depth cameras through librealsense (pyrealsense2). Camera kind `realsense`.

`camera` is the driver; `sdk` imports pyrealsense2 on demand and lists cameras; `identity`
reads calibration and identity at open; `frame_buffer` copies frames out of the SDK's thread;
`metadata` reads each frame's exposure, gain and projector state. Importing this package
never imports pyrealsense2.
"""

from .camera import RealSenseCamera, open_realsense
from .metadata import projector_state
from .sdk import import_problem, list_realsense, sdk

__all__ = ["RealSenseCamera", "open_realsense", "projector_state", "import_problem", "list_realsense", "sdk"]
