"""ROS 1 and ROS 2 bags written with rosbags (the library, not rig), as realsense-ros records them.

Topics and types as realsense-ros publishes them: `/camera/depth/image_rect_raw` (sensor_msgs/Image, 16UC1,
millimetres by REP 118), `/camera/depth/camera_info` (K of the depth imager) and `/camera/infra2/camera_info`
(the right imager: P[3] = -fx * baseline). Used by tests/test_bag_import.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

DEPTH = "/camera/depth/image_rect_raw"
DEPTH_INFO = "/camera/depth/camera_info"
RIGHT_INFO = "/camera/infra2/camera_info"
PERIOD_NS = 33_333_333  # 30 fps


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

    if ros1:
        from rosbags.rosbag1 import Writer

        path = path.parent / f"{path.name}.bag"
        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=8, storage_plugin=StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3)
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
            data = frame.astype("<u2").view(np.uint8).ravel() if encoding != "32FC1" else \
                (frame.astype("<f4") * 1e-3).view(np.uint8).ravel()
            step = w * (2 if encoding != "32FC1" else 4)
            msg = Image(header=header(i + 1, ns), height=h, width=w, encoding=encoding, is_bigendian=0, step=step, data=data)
            out.write(depth_c, ns, serialize(msg, Image.__msgtype__))
            if extra_c is not None:
                out.write(extra_c, ns, serialize(msg, Image.__msgtype__))
    return path
