"""What a recorded bag holds for rig: its depth frames and what the recording says about them.

Reads, with rosbags (pure Python, no ROS installed), RealSense `.bag` files (librealsense's recorder
writes a ROS 1 bag: `/device_0/sensor_N/Depth_0/image/data`, `.../info/camera_info`, the sensor's
options at record time on `/device_0/sensor_N/option/<Name>/value`, per-frame metadata on
`.../image/metadata`, the device's name, serial and firmware on `/device_0/info`) and ROS 1 / ROS 2
bags (`.bag`, `.db3`, `.mcap`, or a ROS 2 bag folder) from realsense-ros or depthai-ros
(`/camera/depth/image_rect_raw` with `/camera/depth/camera_info`). Depth must be integer counts
(`16UC1` or `mono16`); in a ROS bag their unit is the millimetre (REP 118), in a RealSense bag the
recorded `Depth Units` option. See docs/import.md.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..errors import FolderImportError
from .ros1 import Ros1Bag

BAG_SUFFIXES = (".bag", ".db3", ".mcap")
IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
KEY_VALUE = "diagnostic_msgs/msg/KeyValue"
FLOAT32 = "std_msgs/msg/Float32"
#: integer depth encodings rig reads; REP 118: 16UC1 depth images are in millimetres
DEPTH_ENCODINGS = ("16UC1", "mono16")
ROS_DEPTH_UNIT_M = 1e-3


def is_bag(path: Path) -> bool:
    """A bag file, or a ROS 2 bag folder (it holds metadata.yaml)."""
    return (path.is_file() and path.suffix.lower() in BAG_SUFFIXES) or (path.is_dir() and (path / "metadata.yaml").is_file())


@dataclass
class BagFacts:
    """What one bag says about its depth stream (NaN or None: the bag does not say)."""

    path: Path
    topic: str
    kind: str  # "realsense" (librealsense's recorder) or "ros"
    n_frames: int
    width: int
    height: int
    encoding: str
    fx: float = math.nan
    fy: float = math.nan
    cx: float = math.nan
    cy: float = math.nan
    baseline_m: float = math.nan
    depth_unit_m: float = math.nan
    projector_on: bool | None = None
    exposure_us: float = math.nan
    gain: float = math.nan
    auto_exposure: bool | None = None
    camera_model: str = ""
    camera_serial: str = ""
    camera_firmware: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    #: each depth frame's header stamp, in ms, in bag order
    stamps_ms: list[float] = field(default_factory=list)

    def known(self) -> dict[str, Any]:
        """The import keys this bag gives (the manifest's names: fx, ..., projector_on, exposure_us, gain)."""
        out: dict[str, Any] = {}
        for key in ("fx", "fy", "cx", "cy", "baseline_m", "depth_unit_m", "exposure_us", "gain"):
            v = getattr(self, key)
            if math.isfinite(v):
                out[key] = v
        if self.projector_on is not None:
            out["projector_on"] = self.projector_on
        for key in ("camera_model", "camera_serial"):
            if getattr(self, key):
                out[key] = getattr(self, key)
        return out


def _reader(path: Path):
    """The bag opened for reading (a context manager): a ROS 1 bag with its message definitions parsed once per
    process (drivers/bag/ros1.py), a ROS 2 bag with rosbags' AnyReader."""
    ros1 = Path(path).suffix == ".bag"
    try:
        if ros1:  # rosbags' ROS 1 reader alone: its high-level reader's imports (the ROS 2 storages) are 0.05 s more
            importlib.import_module("rosbags.rosbag1")
        else:
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore
    except ImportError:  # pragma: no cover - a dependency of rig
        raise FolderImportError("reading bags needs rosbags; pip install rosbags") from None
    # a ROS 1 bag carries its messages' definitions, and they are read from it; the ROS 2 Humble store (0.45 s of
    # imports: each distro's store builds on the one before) is only for a rosbag2 that has none (rosbags' AnyReader)
    if ros1:
        return Ros1Bag(path)
    return AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))


def _field(msg: Any, name: str) -> Any:
    """A field of a ROS 1 (`K`, `P`) or ROS 2 (`k`, `p`) CameraInfo."""
    return getattr(msg, name.lower(), None) if hasattr(msg, name.lower()) else getattr(msg, name.upper())


def _stamp_ms(msg: Any) -> float:
    s = msg.header.stamp
    return (int(s.sec) + int(s.nanosec) * 1e-9) * 1e3


def read_facts(path: Path, topic: str | None = None) -> BagFacts:
    """Open the bag, find its depth topic (or check `topic`), and read what it says; FolderImportError if it cannot."""
    try:
        with _reader(path) as r:
            return _facts(r, path, topic)
    except FolderImportError:
        raise
    except Exception as e:  # rosbags raises its own errors for a damaged or foreign file
        raise FolderImportError(f"{path}: not a readable bag ({type(e).__name__}: {' '.join(str(e).split())}); "
                                "give a RealSense .bag or a ROS 1/ROS 2 bag (.bag, .db3, .mcap)") from None


def _depth_topic(r: Any, path: Path, topic: str | None) -> Any:
    images = [c for c in r.connections if c.msgtype == IMAGE]
    if topic is not None:
        chosen = [c for c in images if c.topic == topic]
        if not chosen:
            raise FolderImportError(f"{path}: no image topic {topic!r}; its image topics are {sorted({c.topic for c in images})}")
        return chosen[0]
    depth = [c for c in images if "depth" in c.topic.lower() and "color" not in c.topic.lower()]
    if not depth:
        raise FolderImportError(f"{path}: no depth image topic (image topics: {sorted({c.topic for c in images}) or 'none'}); "
                                "pass --topic")
    if len({c.topic for c in depth}) > 1:
        raw = [c for c in depth if c.topic.endswith(("image_rect_raw", "Depth_0/image/data"))]
        if len({c.topic for c in raw}) != 1:
            raise FolderImportError(f"{path}: several depth topics {sorted({c.topic for c in depth})}; choose one with --topic")
        depth = raw
    return depth[0]


def _facts(r: Any, path: Path, topic: str | None) -> BagFacts:
    depth = _depth_topic(r, path, topic)
    realsense = depth.topic.startswith("/device_") and depth.topic.endswith("/image/data")
    first = None
    n = 0
    stamps = []
    for c, _t, raw in _messages(r, [depth]):
        n += 1
        msg = r.deserialize(raw, c.msgtype)
        stamps.append(_stamp_ms(msg))
        if first is None:
            first = msg
    if first is None:
        raise FolderImportError(f"{path}: the topic {depth.topic} holds no frame")
    if first.encoding not in DEPTH_ENCODINGS or first.is_bigendian:
        raise FolderImportError(f"{path}: {depth.topic} is {first.encoding}{' big-endian' if first.is_bigendian else ''}; "
                                f"rig reads integer depth ({' or '.join(DEPTH_ENCODINGS)}, little-endian): record the raw depth topic")
    facts = BagFacts(path, depth.topic, "realsense" if realsense else "ros", n, int(first.width), int(first.height),
                     first.encoding, stamps_ms=stamps)
    stream = depth.topic[: -len("/image/data")] if realsense else depth.topic.rsplit("/", 1)[0]
    info_topic = f"{stream}/info/camera_info" if realsense else f"{stream}/camera_info"
    infos = {c.topic: c for c in r.connections if c.msgtype == CAMERA_INFO}
    if info_topic in infos:
        info = _first(r, infos[info_topic])
        k = [float(v) for v in _field(info, "K")]
        facts.fx, facts.fy, facts.cx, facts.cy = k[0], k[4], k[2], k[5]
        facts.extra["camera_info_topic"] = info_topic
        facts.extra["distortion"] = {"model": str(info.distortion_model), "coeffs": [float(v) for v in _field(info, "D")]}
    if realsense:
        _realsense(r, facts, stream)
    else:
        facts.depth_unit_m = ROS_DEPTH_UNIT_M
        facts.extra["depth_unit_source"] = "REP 118: 16UC1 depth is in millimetres"
        _ros_baseline(r, facts, infos)
    facts.extra["bag_format"] = "RealSense (librealsense recorder, ROS 1 bag)" if realsense else _ros_format(path)
    facts.extra["depth_topic"] = depth.topic
    return facts


def _messages(r: Any, connections: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
    """The messages of these connections in time order; none for none (rosbags reads every topic for [])."""
    if connections:
        yield from r.messages(connections=connections)


def _first(r: Any, connection: Any) -> Any:
    for c, _t, raw in _messages(r, [connection]):
        return r.deserialize(raw, c.msgtype)
    return None


def _ros_format(path: Path) -> str:
    if path.is_dir():
        return "ROS 2 bag folder"
    return {".bag": "ROS 1 bag", ".db3": "ROS 2 bag (sqlite3)", ".mcap": "ROS 2 bag (MCAP)"}[path.suffix.lower()]


def _ros_baseline(r: Any, facts: BagFacts, infos: dict[str, Any]) -> None:
    """realsense-ros and depthai-ros publish the right imager's camera_info with P[3] = -fx * baseline."""
    for topic, c in sorted(infos.items()):
        msg = _first(r, c)
        p = [float(v) for v in _field(msg, "P")]
        if p[0] > 0 and p[3] < 0:
            facts.baseline_m = -p[3] / p[0]
            facts.extra["baseline_source"] = f"{topic}: P[3] = -fx * baseline"
            return


#: RealSense options recorded (name in the bag -> key in the recording's extra)
RS_OPTIONS = ("Exposure", "Gain", "Enable Auto Exposure", "Laser Power", "Emitter Enabled", "Depth Units",
              "Stereo Baseline", "Asic Temperature", "Projector Temperature", "Visual Preset")


def _realsense(r: Any, facts: BagFacts, stream: str) -> None:
    sensor = stream.rsplit("/", 1)[0]  # /device_0/sensor_0
    device = sensor.rsplit("/", 1)[0]
    options: dict[str, float] = {}
    identity: dict[str, str] = {}
    for c, _t, raw in _messages(r, [c for c in r.connections if c.topic.startswith(f"{sensor}/option/")
                                              and c.topic.endswith("/value") and c.msgtype == FLOAT32]):
        # std_msgs/Float32: the shortest decimal that is the same float32 (0.001, not 0.0010000000474974513)
        options[c.topic.split("/")[-2]] = float(str(np.float32(r.deserialize(raw, c.msgtype).data)))
    for c, _t, raw in _messages(r, [c for c in r.connections if c.topic == f"{device}/info" and c.msgtype == KEY_VALUE]):
        kv = r.deserialize(raw, c.msgtype)
        identity[str(kv.key)] = str(kv.value)
    facts.camera_model = identity.get("Name", "")
    facts.camera_serial = identity.get("Serial Number", "")
    facts.camera_firmware = identity.get("Firmware Version", "")
    if "Depth Units" in options:
        facts.depth_unit_m = options["Depth Units"]
    if "Stereo Baseline" in options:  # librealsense reports it in mm
        facts.baseline_m = options["Stereo Baseline"] * 1e-3
        facts.extra["baseline_source"] = "the recorded Stereo Baseline option (mm)"
    if "Emitter Enabled" in options:
        facts.projector_on = bool(options["Emitter Enabled"]) and options.get("Laser Power", 1.0) > 0
    facts.exposure_us = options.get("Exposure", math.nan)
    facts.gain = options.get("Gain", math.nan)  # RealSense gain: 16 = x1, rig's unit
    if "Enable Auto Exposure" in options:
        facts.auto_exposure = bool(options["Enable Auto Exposure"])
    facts.extra["options"] = {k: v for k, v in options.items() if k in RS_OPTIONS}
    facts.extra["device_info"] = identity


@dataclass
class BagFrame:
    depth: np.ndarray  # uint16 (height, width), depth counts, 0 = no data
    frame_number: int
    timestamp_ms: float
    metadata: dict[str, str]  # the frame's own metadata (RealSense bags), else {}


def frames(facts: BagFacts, window_ms: tuple[float, float] | None = None) -> Iterator[BagFrame]:
    """The depth frames in recording order, one at a time, with their number, time and metadata; with `window_ms`,
    only those whose stamp lies in [start, end] ms."""
    with _reader(facts.path) as r:
        depth = [c for c in r.connections if c.topic == facts.topic and c.msgtype == IMAGE]
        meta_topic = facts.topic[: -len("/data")] + "/metadata" if facts.kind == "realsense" else None
        by_time: dict[int, dict[str, str]] = {}
        metas = [c for c in r.connections if c.topic == meta_topic and c.msgtype == KEY_VALUE]
        for c, t, raw in _messages(r, metas):
            kv = r.deserialize(raw, c.msgtype)
            by_time.setdefault(t, {})[str(kv.key)] = str(kv.value)
        for index, (c, t, raw) in enumerate(_messages(r, depth)):
            msg = r.deserialize(raw, c.msgtype)
            stamp_ms = _stamp_ms(msg)
            if window_ms is not None and not window_ms[0] <= stamp_ms <= window_ms[1]:
                continue
            if (msg.width, msg.height, msg.encoding) != (facts.width, facts.height, facts.encoding):
                raise FolderImportError(f"{facts.path}: frame {index + 1} is {msg.width}x{msg.height} {msg.encoding}, the first "
                                        f"{facts.width}x{facts.height} {facts.encoding}; one stream per import")
            rows = np.frombuffer(msg.data, np.uint8).reshape(msg.height, int(msg.step))
            image = rows[:, : 2 * msg.width].copy().view("<u2").astype(np.uint16, copy=False)
            meta = by_time.get(t, {})
            seq = getattr(msg.header, "seq", 0)
            number = int(float(meta["Frame Counter"])) if "Frame Counter" in meta else (int(seq) if seq else index)
            yield BagFrame(image, number, stamp_ms, meta)
