"""ROS 1 and ROS 2 bags written with rosbags (the library, not rig), as realsense-ros records them.

Topics and types as realsense-ros publishes them: `/camera/depth/image_rect_raw` (sensor_msgs/Image, 16UC1,
millimetres by REP 118), `/camera/depth/camera_info` (K of the depth imager) and `/camera/infra2/camera_info`
(the right imager: P[3] = -fx * baseline). Used by tests/test_bag_import.py. `write_cameras` writes one or more
cameras of any driver's layout (`Camera`), raw or as image_transport's compressedDepth; tests/test_bag_streams.py.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

DEPTH = "/camera/depth/image_rect_raw"
DEPTH_INFO = "/camera/depth/camera_info"
RIGHT_INFO = "/camera/infra2/camera_info"
PERIOD_NS = 33_333_333  # 30 fps


def open_writer(path: Path, fmt: str) -> tuple[Path, object]:
    """rosbags' own writer for `fmt`: 'ros1' (at `path`.bag), or 'db3' / 'mcap' (a ROS 2 bag folder at `path`,
    storage version 8); the bag's path and the writer, not yet opened."""
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer

        path = path.parent / f"{path.name}.bag"
        return path, Writer(path)
    from rosbags.rosbag2 import StoragePlugin, Writer

    return path, Writer(path, version=8, storage_plugin=StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3)


def write_bag(path: Path, frames: np.ndarray, *, fx: float, fy: float, cx: float, cy: float, baseline_m: float,
              fmt: str = "db3", encoding: str = "16UC1", extra_depth_topic: str | None = None,
              start_ns: int = 1_700_000_000 * 10**9, skip: frozenset[int] = frozenset(),
              times_ns: list[int] | None = None) -> Path:
    """Write `frames` (N, H, W) as a bag: fmt 'db3' or 'mcap' (a ROS 2 bag folder at `path`) or 'ros1' (`path`.bag).
    Frames whose index is in `skip` are left out (a recorder that lost them): their time stays a gap. times_ns:
    each frame's stamp after start_ns (default: 30 fps)."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = fmt == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    t = ts.types
    Image, Info = t["sensor_msgs/msg/Image"], t["sensor_msgs/msg/CameraInfo"]
    Header, Time = t["std_msgs/msg/Header"], t["builtin_interfaces/msg/Time"]
    Roi = t["sensor_msgs/msg/RegionOfInterest"]
    n, h, w = frames.shape

    def header(i: int, ns: int):
        stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
        if ros1:
            return Header(seq=i, stamp=stamp, frame_id="camera_depth_optical_frame")
        return Header(stamp=stamp, frame_id="camera_depth_optical_frame")

    def info(ns: int, tx: float):
        k = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], np.float64)
        p = np.array([fx, 0, cx, tx, 0, fy, cy, 0, 0, 0, 1, 0], np.float64)
        fields = dict(header=header(0, ns), height=h, width=w, distortion_model="plumb_bob", binning_x=0, binning_y=0,
                      roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
        names = ("D", "K", "R", "P") if ros1 else ("d", "k", "r", "p")
        arrays = (np.zeros(5), k, np.eye(3).ravel(), p)
        return Info(**fields, **dict(zip(names, arrays)))

    def serialize(msg, msgtype):
        return ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype)

    path, writer = open_writer(path, fmt)
    with writer as out:
        def add(topic, msgtype):
            return out.add_connection(topic, msgtype, typestore=ts) if not ros1 else out.add_connection(topic, msgtype, typestore=ts)

        depth_c = add(DEPTH, Image.__msgtype__)
        info_c, right_c = add(DEPTH_INFO, Info.__msgtype__), add(RIGHT_INFO, Info.__msgtype__)
        extra_c = add(extra_depth_topic, Image.__msgtype__) if extra_depth_topic else None
        out.write(info_c, start_ns, serialize(info(start_ns, 0.0), Info.__msgtype__))
        out.write(right_c, start_ns, serialize(info(start_ns, -fx * baseline_m), Info.__msgtype__))
        for i, frame in enumerate(frames):
            if i in skip:
                continue
            ns = start_ns + (times_ns[i] if times_ns is not None else (i + 1) * PERIOD_NS)
            dtype = {"32FC1": "<f4", "8UC1": "u1"}.get(encoding, "<u2")
            data = (frame.astype(dtype) * (1e-3 if encoding == "32FC1" else 1)).astype(dtype).view(np.uint8).ravel()
            step = w * np.dtype(dtype).itemsize
            msg = Image(header=header(i + 1, ns), height=h, width=w, encoding=encoding, is_bigendian=0, step=step, data=data)
            out.write(depth_c, ns, serialize(msg, Image.__msgtype__))
            if extra_c is not None:
                out.write(extra_c, ns, serialize(msg, Image.__msgtype__))
    return path


#: realsense-ros's extrinsics message (realsense2_camera_msgs/msg/Extrinsics.msg, ROS 2: no header)
EXTRINSICS_MSG = "float64[9] rotation  # column-major 3x3 rotation matrix\nfloat64[3] translation  # metres\n"
EXTRINSICS = "realsense2_camera_msgs/msg/Extrinsics"


@dataclass
class Camera:
    """One camera's depth stream as its driver publishes it: topics relative to the namespace `ns`.

    frames: (N, H, W) uint16 counts (16UC1) or float32 metres (32FC1). right_info: a camera_info with
    P[3] = -fx * baseline_m (None: none); extrinsics_m: the translation published on `extrinsics/depth_to_infra2`
    (None: none). compress: frame -> (format, data) of a sensor_msgs/CompressedImage sent on `depth` + "/" +
    `transport` instead of the raw Image; bigendian: a raw Image's bytes big-endian."""

    frames: np.ndarray
    ns: str = "/camera"
    depth: str = "depth/image_rect_raw"
    info: str = "depth/camera_info"
    right_info: str | None = "infra2/camera_info"
    fx: float = 60.0
    baseline_m: float = 0.05
    encoding: str = "16UC1"
    frame_id: str = "camera_depth_optical_frame"
    extrinsics_m: tuple[float, float, float] | None = None
    compress: Callable[[np.ndarray], tuple[str, bytes]] | None = None
    transport: str = "compressedDepth"
    bigendian: bool = False

    @property
    def depth_topic(self) -> str:
        return f"{self.ns}/{self.depth}" + (f"/{self.transport}" if self.compress else "")


def write_cameras(path: Path, cameras: list[Camera], fmt: str = "mcap", start_ns: int = 1_700_000_000 * 10**9) -> Path:
    """Write the cameras' streams into one bag with rosbags' own writer and typestore: fmt 'db3' or 'mcap' (a ROS 2
    bag folder at `path`) or 'ros1' (`path`.bag); each camera's infos first, then its frames at 30 fps."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ros1 = fmt == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if not ros1:
        ts.register(get_types_from_msg(EXTRINSICS_MSG, EXTRINSICS))
    t = ts.types
    Image, Compressed, Info = t["sensor_msgs/msg/Image"], t["sensor_msgs/msg/CompressedImage"], t["sensor_msgs/msg/CameraInfo"]
    Header, Time, Roi = t["std_msgs/msg/Header"], t["builtin_interfaces/msg/Time"], t["sensor_msgs/msg/RegionOfInterest"]

    def header(i: int, ns: int, frame_id: str):
        stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
        return Header(seq=i, stamp=stamp, frame_id=frame_id) if ros1 else Header(stamp=stamp, frame_id=frame_id)

    def info(cam: Camera, ns: int, tx: float):
        n, h, w = cam.frames.shape
        cx, cy = (w - 1) / 2, (h - 1) / 2
        k = np.array([cam.fx, 0, cx, 0, cam.fx, cy, 0, 0, 1], np.float64)
        p = np.array([cam.fx, 0, cx, tx, 0, cam.fx, cy, 0, 0, 0, 1, 0], np.float64)
        names = ("D", "K", "R", "P") if ros1 else ("d", "k", "r", "p")
        return Info(header=header(0, ns, cam.frame_id), height=h, width=w, distortion_model="plumb_bob", binning_x=0,
                    binning_y=0, roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
                    **dict(zip(names, (np.zeros(5), k, np.eye(3).ravel(), p))))

    def serialize(msg, msgtype):
        return ts.serialize_ros1(msg, msgtype) if ros1 else ts.serialize_cdr(msg, msgtype)

    path, writer = open_writer(path, fmt)
    with writer as out:
        for cam in cameras:
            c = out.add_connection(f"{cam.ns}/{cam.info}", Info.__msgtype__, typestore=ts)
            out.write(c, start_ns, serialize(info(cam, start_ns, 0.0), Info.__msgtype__))
            if cam.right_info:
                c = out.add_connection(f"{cam.ns}/{cam.right_info}", Info.__msgtype__, typestore=ts)
                out.write(c, start_ns, serialize(info(cam, start_ns, -cam.fx * cam.baseline_m), Info.__msgtype__))
            if cam.extrinsics_m is not None:
                Ex = t[EXTRINSICS]
                c = out.add_connection(f"{cam.ns}/extrinsics/depth_to_infra2", EXTRINSICS, typestore=ts)
                out.write(c, start_ns, serialize(Ex(rotation=np.eye(3).ravel(), translation=np.array(cam.extrinsics_m)), EXTRINSICS))
        for cam in cameras:
            msgtype = (Compressed if cam.compress else Image).__msgtype__
            c = out.add_connection(cam.depth_topic, msgtype, typestore=ts)
            n, h, w = cam.frames.shape
            for i, frame in enumerate(cam.frames):
                ns = start_ns + (i + 1) * PERIOD_NS
                if cam.compress:
                    form, data = cam.compress(frame)
                    msg = Compressed(header=header(i + 1, ns, cam.frame_id), format=form, data=np.frombuffer(data, np.uint8))
                else:
                    dtype = (">" if cam.bigendian else "<") + ("f4" if cam.encoding == "32FC1" else "u2")
                    data = np.ascontiguousarray(frame.astype(dtype)).view(np.uint8).ravel()
                    msg = Image(header=header(i + 1, ns, cam.frame_id), height=h, width=w, encoding=cam.encoding,
                                is_bigendian=int(cam.bigendian), step=w * np.dtype(dtype).itemsize, data=data)
                out.write(c, ns, serialize(msg, msgtype))
    return path
