"""A ROS bag's stereo baseline for one depth stream, from its own camera's topics only (drivers/bag/camera_topics.py).

Sources, under the depth topic's camera namespace: a camera_info whose projection has P[3] = -fx * baseline
(ROS CameraInfo: P[3] = -fx' B for the second camera of a rectified pair; realsense-ros's infra2, depthai-ros's
left or right), and realsense-ros's `extrinsics/depth_to_infra2` (realsense2_camera_msgs Extrinsics: the translation
from the depth imager to the second one, m; baseline = its length). They must agree; a bag whose only such topics
belong to other cameras, or whose camera's topics disagree, does not say the baseline (`--baseline-m` does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .camera_topics import EXTRINSICS_TO_RIGHT, belongs
from .reading import field, first

CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
#: two sources of one camera agree within this relative difference: P[3] is -fx * t computed in float32 (realsense-ros)
#: and divided by fx here, three roundings of 2^-24 at most, well inside 1e-6
AGREE_REL = 1e-6


@dataclass
class Baseline:
    """The baseline in m (NaN: not said), where it came from, and why it is not said when the bag has some."""

    baseline_m: float = math.nan
    source: str = ""
    problem: str = ""


def _from_info(r: Any, c: Any) -> float:
    msg = first(r, c)
    if msg is None:
        return math.nan
    p = [float(v) for v in field(msg, "P")]
    return -p[3] / p[0] if p[0] > 0 and p[3] < 0 else math.nan


def _from_extrinsics(r: Any, c: Any) -> float:
    try:
        msg = first(r, c)
    except Exception:  # a type the bag does not define, or a layout not realsense-ros's: not a source
        return math.nan
    t = np.asarray(getattr(msg, "translation", []), np.float64)
    return float(np.linalg.norm(t)) if t.shape == (3,) and np.linalg.norm(t) > 0 else math.nan


def find_baseline(r: Any, depth_topic: str, camera: str, other_cameras: set[str]) -> Baseline:
    """The baseline of the camera `camera` (the depth topic's namespace), read from its own topics."""
    ours: list[tuple[str, float]] = []
    theirs: list[str] = []
    for c in sorted(r.connections, key=lambda c: (c.msgtype != CAMERA_INFO, c.topic)):  # camera_info first
        if c.msgtype == CAMERA_INFO:
            b = _from_info(r, c)
            if math.isfinite(b):
                (ours.append((f"{c.topic}: P[3] = -fx * baseline", b)) if belongs(c.topic, camera, other_cameras)
                 else theirs.append(c.topic))
        elif c.topic == camera + EXTRINSICS_TO_RIGHT and c.msgtype.endswith("/Extrinsics"):
            b = _from_extrinsics(r, c)
            if math.isfinite(b):
                ours.append((f"{c.topic}: the translation's length", b))
    where = f"the camera {camera}/" if camera else "the bag's root namespace"
    if not ours:
        if theirs:
            return Baseline(problem=f"no topic of {where} ({depth_topic}'s camera) gives the stereo baseline; "
                                    f"{', '.join(theirs)} belong{'s' * (len(theirs) == 1)} to other cameras: pass --baseline-m")
        return Baseline()
    first_b = ours[0][1]
    if any(abs(b - first_b) > AGREE_REL * first_b for _, b in ours[1:]):
        said = ", ".join(f"{s.split(':')[0]} {b * 1e3:.6g} mm" for s, b in ours)
        return Baseline(problem=f"the topics of {where} ({depth_topic}'s camera) disagree on the stereo baseline "
                                f"({said}): pass --baseline-m")
    return Baseline(first_b, "; ".join(s for s, _ in ours))
