"""A ROS 1 bag (a RealSense recording is one) opened with rosbags' own reader, its message definitions parsed once.

rosbags' AnyReader parses every connection's message definition each time it opens a bag: for the real D435 bag's
topics, 0.18 s of a `rig import`'s 1.9 s, and an import opens a bag once for what it says and again for each stop's
frames. Here the definitions are read from the bag exactly as AnyReader reads them (each connection's own `.msg`
text, rosbags' parser), checked against each connection's MD5 sum as AnyReader checks them, and kept for the process
by the file's path, size and modification time, so a file changed on disk is parsed again.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Iterator

#: parsed typestores, by (resolved path, size, mtime in ns)
_TYPESTORES: dict[tuple[str, int, int], Any] = {}


class BagDefinitionError(Exception):
    """The bag's message definitions cannot be used (none, or one that does not match its connection's MD5 sum)."""


def _typestore(path: Path, connections: list[Any]) -> Any:
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import Stores, get_typestore, get_types_from_msg

    st = os.stat(path)
    key = (str(Path(path).resolve()), st.st_size, st.st_mtime_ns)
    if key in _TYPESTORES:
        return _TYPESTORES[key]
    store = get_typestore(Stores.EMPTY)
    defined = [c for c in connections if c.msgdef.format == MessageDefinitionFormat.MSG]
    if connections and not defined:
        raise BagDefinitionError("the bag holds no message definitions")
    types: dict[str, Any] = {}
    for c in defined:
        types.update(get_types_from_msg(c.msgdef.data, c.msgtype))
    store.register(types)
    for c in defined:
        if c.digest and store.generate_msgdef(c.msgtype)[1] != c.digest:
            raise BagDefinitionError(f"message type {c.msgtype!r} does not match its MD5 sum {c.digest}")
    _TYPESTORES[key] = store
    return store


class Ros1Bag:
    """`with Ros1Bag(path) as bag:` its `connections`, `messages(connections)` (connection, time in ns, raw bytes; in
    time order) and `deserialize(raw, msgtype)`, as rosbags' AnyReader gives them for one ROS 1 bag."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._reader: Any = None
        self.connections: list[Any] = []
        self._store: Any = None

    def __enter__(self) -> "Ros1Bag":
        from rosbags.rosbag1 import Reader

        reader = Reader(self.path)
        reader.open()
        connections = list(reader.connections)
        try:
            self._store = _typestore(self.path, connections)
        except BaseException:
            reader.close()
            raise
        self._reader, self.connections = reader, connections
        return self

    def __exit__(self, *exc: object) -> bool:
        self._reader.close()
        return False

    def messages(self, connections: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
        return self._reader.messages(connections=connections)

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        return self._store.deserialize_ros1(raw, msgtype)
