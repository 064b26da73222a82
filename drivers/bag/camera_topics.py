"""Which of a ROS bag's topics are a camera's depth stream, and which belong to the same camera.

A depth image topic is `<camera>/<stream>/<image>`, and the camera's other topics lie under `<camera>/`:

| driver | depth image | its camera_info | the baseline's source |
|---|---|---|---|
| realsense-ros 2.x (ROS 1) | `/camera/depth/image_rect_raw` | `/camera/depth/camera_info` | `/camera/infra2/camera_info` P[3]; `/camera/extrinsics/depth_to_infra2` |
| realsense-ros 4.x (ROS 2) | `/camera/camera/depth/image_rect_raw` | `/camera/camera/depth/camera_info` | `/camera/camera/infra2/camera_info` P[3]; `.../extrinsics/depth_to_infra2` |
| depthai-ros | `/oak/stereo/image_raw` | `/oak/stereo/camera_info` | `/oak/left/camera_info` or `/oak/right/camera_info` P[3] |

(realsense-ros at 1cbd81be, realsense2_camera/src/base_realsense_node.cpp line 811: the right imager's
P[3] = -fx * translation[0]; rs_node_setup.cpp lines 263-264 and 314: `aligned_depth_to_<stream>/image_raw` and
`extrinsics/<depth>_to_<stream>`. depthai-ros at 9132443, depthai_bridge/src/ImageConverter.cpp lines 492-505: the
first of the stereo pair, left unless the order is reversed, gets P[3] = fx * T[0] of the first-to-second extrinsics,
negative.) A topic sent through image_transport adds `/compressedDepth` (or `/compressed`, `/zstd`) to the image topic.

Two cameras in one bag (`/cam_a/...`, `/cam_b/...`) are told apart by these namespaces: a topic under another
depth stream's camera namespace nested inside this one's belongs to that camera.
"""

from __future__ import annotations

#: suffixes image_transport adds to an image topic
TRANSPORT_SUFFIXES = ("/compressedDepth", "/compressed", "/zstd")
#: realsense-ros's topic of the stereo pair's second imager relative to the depth imager
EXTRINSICS_TO_RIGHT = "/extrinsics/depth_to_infra2"


def image_topic(topic: str) -> str:
    """The image topic a transport topic carries (`/camera/depth/image_rect_raw/compressedDepth` -> without the suffix)."""
    for suffix in TRANSPORT_SUFFIXES:
        if topic.endswith(suffix):
            return topic[: -len(suffix)]
    return topic


def stream_namespace(topic: str) -> str:
    """`/camera/depth` for `/camera/depth/image_rect_raw` (and its compressedDepth)."""
    return image_topic(topic).rsplit("/", 1)[0]


def camera_namespace(topic: str) -> str:
    """`/camera` for `/camera/depth/image_rect_raw`; '' (the root) for `/depth/image_raw`."""
    return stream_namespace(topic).rsplit("/", 1)[0]


def is_depth_like(topic: str) -> bool:
    """A topic that by its name may carry depth: `depth` in it (not a colour stream's), or a depthai `stereo` stream."""
    t = image_topic(topic).lower()
    if aligned_reason(topic, ""):
        return True
    segments = t.split("/")
    return ("depth" in t or "stereo" in segments) and "color" not in t and "rgb" not in t


def aligned_reason(topic: str, frame_id: str) -> str:
    """Why this depth is aligned to another camera (resampled into its pixels), or '' when it is the sensor's own:
    realsense-ros's `aligned_depth_to_<stream>`, openni's `depth_registered/` namespace, or a header frame of a
    colour camera (depthai-ros aligns its stereo depth to the RGB camera on the device: `oak_rgb_camera_optical_frame`)."""
    t = image_topic(topic)
    if "aligned_depth_to_" in t:
        return f"the topic {t} is aligned depth"
    if "depth_registered" in t.split("/")[:-1]:
        return f"the topic {t} is registered (aligned) depth"
    f = frame_id.lower()
    if "color" in f or "rgb" in f:
        return f"its frame {frame_id} is a colour camera's"
    return ""


def belongs(topic: str, camera: str, other_cameras: set[str]) -> bool:
    """`topic` lies under the camera namespace `camera`, and not under another camera's namespace nested inside it."""
    if not topic.startswith(camera + "/"):
        return False
    return not any(len(o) > len(camera) and topic.startswith(o + "/") for o in other_cameras)
