"""What a recorded bag holds for rig: its depth frames and what the recording says about them.

Reads, with rosbags (pure Python, no ROS installed), RealSense `.bag` files (librealsense's recorder
writes a ROS 1 bag: `/device_0/sensor_N/Depth_0/image/data`, `.../info/camera_info`, the sensor's
options at record time on `/device_0/sensor_N/option/<Name>/value`, per-frame metadata on
`.../image/metadata`, the device's name, serial and firmware on `/device_0/info`) and ROS 1 / ROS 2
bags (`.bag`, `.db3`, `.mcap`, or a ROS 2 bag folder) from realsense-ros, depthai-ros and the like
(`/camera/depth/image_rect_raw` with `/camera/depth/camera_info`; drivers/bag/camera_topics.py). Depth is integer
counts (`16UC1`, `mono16`; in a ROS bag millimetres by REP 118, in a RealSense bag the recorded `Depth Units`
option) or metres (`32FC1`, turned into counts by drivers/bag/metric_depth.py), as a raw Image or image_transport's
compressedDepth (drivers/bag/depth_messages.py). See docs/import.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..errors import FolderImportError
from .camera_topics import aligned_reason, camera_namespace, image_topic, is_depth_like, stream_namespace
from .depth_messages import (COMPRESSED_IMAGE, IMAGE, DepthFormat, DepthMessageError, decode, depth_format,
                             quantisation)
from .metric_depth import DepthRangeError, MetricDepthScan, to_counts
from .reading import field as info_field
from .reading import first, messages, open_bag, stamp_ms
from .stereo_baseline import CAMERA_INFO, find_baseline

BAG_SUFFIXES = (".bag", ".db3", ".mcap")
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
KEY_VALUE = "diagnostic_msgs/msg/KeyValue"
FLOAT32 = "std_msgs/msg/Float32"
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
    depth_format: DepthFormat = DepthFormat("16UC1")
    #: why the bag does not say the baseline although it has some for other cameras, or disagrees ('' if not so)
    baseline_problem: str = ""
    #: why this depth is aligned to another camera ('' when it is the sensor's own)
    aligned: str = ""
    #: depth in metres: what its frames hold (metric_depth), for the unit its counts get
    metric_scan: MetricDepthScan | None = None

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


def read_facts(path: Path, topic: str | None = None) -> BagFacts:
    """Open the bag, find its depth topic (or check `topic`), and read what it says; FolderImportError if it cannot."""
    try:
        with open_bag(path) as r:
            return _facts(r, path, topic)
    except FolderImportError:
        raise
    except Exception as e:  # rosbags raises its own errors for a damaged or foreign file
        raise FolderImportError(f"{path}: not a readable bag ({type(e).__name__}: {' '.join(str(e).split())}); "
                                "give a RealSense .bag or a ROS 1/ROS 2 bag (.bag, .db3, .mcap)") from None


def _depth_topic(r: Any, path: Path, topic: str | None) -> Any:
    images = [c for c in r.connections if c.msgtype in IMAGE_TYPES]
    if topic is not None:
        chosen = [c for c in images if c.topic == topic]
        if not chosen:
            raise FolderImportError(f"{path}: no image topic {topic!r}; its image topics are {sorted({c.topic for c in images})}")
        return chosen[0]
    depth = [c for c in images if is_depth_like(c.topic)]
    if not depth:
        raise FolderImportError(f"{path}: no depth image topic (image topics: {sorted({c.topic for c in images}) or 'none'}); "
                                "pass --topic")
    # one stream recorded raw and through image_transport: the raw Image, else its compressedDepth
    streams: dict[str, Any] = {}
    for c in sorted(depth, key=lambda c: (c.msgtype != IMAGE, not c.topic.endswith("/compressedDepth"), c.topic)):
        streams.setdefault(image_topic(c.topic), c)
    chosen = list(streams.values())
    own = [c for c in chosen if not aligned_reason(c.topic, "")]
    if len(chosen) > 1 and own:  # the sensor's own depth over depth aligned to another camera
        chosen = own
    if len(chosen) > 1:
        raw = [c for c in chosen if image_topic(c.topic).endswith(("image_rect_raw", "Depth_0/image/data"))]
        if len(raw) != 1:
            raise FolderImportError(f"{path}: several depth topics {sorted(c.topic for c in chosen)}; choose one with --topic")
        chosen = raw
    return chosen[0]


def _depth_image(path: Path, topic: str, msg: Any, fmt: DepthFormat, number: int) -> np.ndarray:
    """Frame `number` (from 1) of the topic decoded: uint16 counts or float32 metres; a one-line error if it cannot be."""
    try:
        return decode(msg, fmt)
    except DepthMessageError as e:
        raise FolderImportError(f"{path}: {topic} frame {number}: {e}") from None


def _facts(r: Any, path: Path, topic: str | None) -> BagFacts:
    depth = _depth_topic(r, path, topic)
    realsense = depth.topic.startswith("/device_") and depth.topic.endswith("/image/data")
    first_msg, fmt, scan = None, DepthFormat(""), None
    n, height, width = 0, 0, 0
    stamps = []
    for c, _t, raw in messages(r, [depth]):
        n += 1
        msg = r.deserialize(raw, c.msgtype)
        stamps.append(stamp_ms(msg))
        if first_msg is None:
            first_msg = msg
            try:
                fmt = depth_format(msg, c.msgtype, depth.topic)
            except DepthMessageError as e:
                raise FolderImportError(f"{path}: {e}") from None
            image = _depth_image(path, depth.topic, msg, fmt, n)
            height, width = image.shape
            scan = MetricDepthScan() if fmt.metres else None
        elif scan is not None:
            image = _depth_image(path, depth.topic, msg, fmt, n)
        if scan is not None:  # float metres: every frame, for the unit its counts will have (metric_depth)
            scan.add(image)
    if first_msg is None:
        raise FolderImportError(f"{path}: the topic {depth.topic} holds no frame")
    facts = BagFacts(path, depth.topic, "realsense" if realsense else "ros", n, width, height, str(fmt),
                     stamps_ms=stamps, depth_format=fmt)
    stream = depth.topic[: -len("/image/data")] if realsense else stream_namespace(depth.topic)
    info_topic = f"{stream}/info/camera_info" if realsense else f"{stream}/camera_info"
    infos = {c.topic: c for c in r.connections if c.msgtype == CAMERA_INFO}
    if info_topic in infos:
        info = first(r, infos[info_topic])
        k = [float(v) for v in info_field(info, "K")]
        facts.fx, facts.fy, facts.cx, facts.cy = k[0], k[4], k[2], k[5]
        facts.extra["camera_info_topic"] = info_topic
        facts.extra["distortion"] = {"model": str(info.distortion_model), "coeffs": [float(v) for v in info_field(info, "D")]}
    if fmt.compression:
        a, b = quantisation(first_msg)
        facts.extra["compressed_depth"] = {"format": str(fmt)}
        if fmt.metres:  # inverse depth in 16 bits: v = A / z + B, a step of z^2 / A m at z m
            facts.extra["compressed_depth"].update(depth_quant_a=a, depth_quant_b=b,
                                                   note=f"sent as inverse depth in 16 bits: a step of z^2 / {a:g} m at z m")
    if realsense:
        _realsense(r, facts, stream)
    else:
        _ros_depth_unit(facts, scan)
        camera = camera_namespace(depth.topic)
        others = {camera_namespace(c.topic) for c in r.connections
                  if c.msgtype in IMAGE_TYPES and is_depth_like(c.topic)} - {camera}
        found = find_baseline(r, depth.topic, camera, others)
        facts.baseline_m, facts.baseline_problem = found.baseline_m, found.problem
        if found.source:
            facts.extra["baseline_source"] = found.source
        why = aligned_reason(depth.topic, str(getattr(first_msg.header, "frame_id", "")))
        if why:
            facts.aligned = f"aligned depth ({why}): resampled into another camera's pixels, so its noise is not the sensor's own"
            facts.extra["aligned_depth"] = facts.aligned
    facts.extra["bag_format"] = "RealSense (librealsense recorder, ROS 1 bag)" if realsense else _ros_format(path)
    facts.extra["depth_topic"] = depth.topic
    facts.extra["depth_encoding"] = str(fmt)
    return facts


def _ros_depth_unit(facts: BagFacts, scan: MetricDepthScan | None) -> None:
    """Integer depth: 1 mm (REP 118). Metres: the unit metric_depth chooses from every frame, said in the metadata."""
    if scan is None:
        facts.depth_unit_m = ROS_DEPTH_UNIT_M
        facts.extra["depth_unit_source"] = "REP 118: 16UC1 depth is in millimetres"
    else:
        facts.metric_scan = scan
        _metric_unit(facts, scan)


def agree_metric_unit(facts: list[BagFacts]) -> None:
    """Bags of depth in metres imported together: one unit, chosen from all their frames (metric_depth)."""
    scans = [f.metric_scan for f in facts if f.metric_scan is not None]
    if len(scans) > 1:
        merged = MetricDepthScan.merged(scans)
        for f in facts:
            _metric_unit(f, merged)


def _metric_unit(facts: BagFacts, scan: MetricDepthScan) -> None:
    try:
        unit_m, exact = scan.unit()
    except DepthRangeError as e:
        facts.depth_unit_m = math.nan
        facts.extra["depth_unit_source"] = f"{facts.depth_format} metres: {e}"
        return
    facts.depth_unit_m = unit_m
    facts.extra["metric_depth"] = {"unit_m": unit_m, "exact": exact, "max_depth_m": scan.max_m}
    if exact:
        facts.extra["depth_unit_source"] = (f"{facts.depth_format} metres (REP 118), every value on a grid of {unit_m * 1e3:g} mm: "
                                            "counts of it hold them exactly")
    else:
        facts.extra["depth_unit_source"] = (f"{facts.depth_format} metres (REP 118) rounded to counts of {unit_m * 1e3:g} mm, "
                                            f"the finest 1-2-5 step that holds the farthest depth ({scan.max_m:.4g} m) in 16 bits; "
                                            "the rounding adds q^2/12 of variance, as for any depth unit")


def _ros_format(path: Path) -> str:
    if path.is_dir():
        return "ROS 2 bag folder"
    return {".bag": "ROS 1 bag", ".db3": "ROS 2 bag (sqlite3)", ".mcap": "ROS 2 bag (MCAP)"}[path.suffix.lower()]


#: RealSense options recorded (name in the bag -> key in the recording's extra)
RS_OPTIONS = ("Exposure", "Gain", "Enable Auto Exposure", "Laser Power", "Emitter Enabled", "Depth Units",
              "Stereo Baseline", "Asic Temperature", "Projector Temperature", "Visual Preset")


def _realsense(r: Any, facts: BagFacts, stream: str) -> None:
    sensor = stream.rsplit("/", 1)[0]  # /device_0/sensor_0
    device = sensor.rsplit("/", 1)[0]
    options: dict[str, float] = {}
    identity: dict[str, str] = {}
    for c, _t, raw in messages(r, [c for c in r.connections if c.topic.startswith(f"{sensor}/option/")
                                              and c.topic.endswith("/value") and c.msgtype == FLOAT32]):
        # std_msgs/Float32: the shortest decimal that is the same float32 (0.001, not 0.0010000000474974513)
        options[c.topic.split("/")[-2]] = float(str(np.float32(r.deserialize(raw, c.msgtype).data)))
    for c, _t, raw in messages(r, [c for c in r.connections if c.topic == f"{device}/info" and c.msgtype == KEY_VALUE]):
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


def _same_stream(facts: BagFacts, msg: Any, msgtype: str, number: int) -> np.ndarray:
    """Frame `number` (from 1) decoded, if it is of the first frame's format and size; else a one-line error."""
    try:
        fmt = depth_format(msg, msgtype, facts.topic)
    except DepthMessageError as e:
        raise FolderImportError(f"{facts.path}: frame {number}: {e}; the first frame is {facts.encoding}") from None
    image = _depth_image(facts.path, facts.topic, msg, fmt, number) if fmt == facts.depth_format else None
    if image is None or image.shape != (facts.height, facts.width):
        what = f"{image.shape[1]}x{image.shape[0]} {fmt}" if image is not None else str(fmt)
        raise FolderImportError(f"{facts.path}: frame {number} is {what}, the first {facts.width}x{facts.height} "
                                f"{facts.encoding}; one stream per import")
    return image


@dataclass
class BagFrame:
    depth: np.ndarray  # uint16 (height, width), depth counts, 0 = no data
    frame_number: int
    timestamp_ms: float
    metadata: dict[str, str]  # the frame's own metadata (RealSense bags), else {}


def frames(facts: BagFacts, window_ms: tuple[float, float] | None = None,
           depth_unit_m: float | None = None) -> Iterator[BagFrame]:
    """The depth frames in recording order, one at a time, with their number, time and metadata; with `window_ms`,
    only those whose stamp lies in [start, end] ms. Depth in metres becomes counts of `depth_unit_m` (default: the
    unit the bag's frames gave, `facts.depth_unit_m`)."""
    unit_m = facts.depth_unit_m if depth_unit_m is None else depth_unit_m
    with open_bag(facts.path) as r:
        depth = [c for c in r.connections if c.topic == facts.topic and c.msgtype in IMAGE_TYPES]
        meta_topic = facts.topic[: -len("/data")] + "/metadata" if facts.kind == "realsense" else None
        by_time: dict[int, dict[str, str]] = {}
        metas = [c for c in r.connections if c.topic == meta_topic and c.msgtype == KEY_VALUE]
        for c, t, raw in messages(r, metas):
            kv = r.deserialize(raw, c.msgtype)
            by_time.setdefault(t, {})[str(kv.key)] = str(kv.value)
        for index, (c, t, raw) in enumerate(messages(r, depth)):
            msg = r.deserialize(raw, c.msgtype)
            stamp = stamp_ms(msg)
            if window_ms is not None and not window_ms[0] <= stamp <= window_ms[1]:
                continue
            image = _same_stream(facts, msg, c.msgtype, index + 1)
            if facts.depth_format.metres:
                try:
                    image = to_counts(image, unit_m)
                except DepthRangeError as e:
                    raise FolderImportError(f"{facts.path}: {facts.topic} frame {index + 1}: {e}") from None
            meta = by_time.get(t, {})
            seq = getattr(msg.header, "seq", 0)
            number = int(float(meta["Frame Counter"])) if "Frame Counter" in meta else (int(seq) if seq else index)
            yield BagFrame(image, number, stamp, meta)
