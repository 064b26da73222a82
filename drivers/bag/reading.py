"""Opening a bag with rosbags and reading its messages: the reader, the messages of some connections, the first
message of one, a CameraInfo's fields, a header's stamp."""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Iterator

from ..errors import FolderImportError
from .ros1 import Ros1Bag


def open_bag(path: Path):
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


def messages(r: Any, connections: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
    """The messages of these connections in time order; none for none (rosbags reads every topic for [])."""
    if connections:
        yield from r.messages(connections=connections)


def first(r: Any, connection: Any) -> Any:
    """The connection's first message, deserialized (None if it has none)."""
    for c, _t, raw in messages(r, [connection]):
        return r.deserialize(raw, c.msgtype)
    return None


def field(msg: Any, name: str) -> Any:
    """A field of a ROS 1 (`K`, `P`) or ROS 2 (`k`, `p`) CameraInfo."""
    return getattr(msg, name.lower(), None) if hasattr(msg, name.lower()) else getattr(msg, name.upper())


def stamp_ms(msg: Any) -> float:
    """The message header's stamp, in ms."""
    s = msg.header.stamp
    return (int(s.sec) + int(s.nanosec) * 1e-9) * 1e3
