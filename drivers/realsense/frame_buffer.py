"""Frames copied out of the SDK on its own thread into a bounded buffer the driver reads from."""

from __future__ import annotations

import collections
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from .metadata import METADATA_KEYS

#: frames the host-side queue holds (depth and IR count separately); older ones are dropped
QUEUE_FRAMES = 64


@dataclass
class Item:
    """One frame copied out of the SDK: which stream, its number, clock, metadata and pixels."""

    kind: str  # "depth" or "ir"
    number: int
    timestamp_ms: float
    domain: str
    metadata: dict[str, float]
    data: np.ndarray


class FrameBuffer:
    """The sensor's frame callback: copies each frame out at once (so the SDK's frame pool never
    runs dry) into a bounded buffer.

    Live, a full buffer drops its oldest frame, as the SDK's own queues do. Playing a recording
    back (not in real time) it is lossless: the SDK's thread waits in the callback until the
    reader has made room. (An `rs.frame_queue(keep_frames=True)` deadlocks there with
    pyrealsense2 2.59 as soon as the reader is slower than the file; docs/hardware.md.)
    """

    def __init__(self, rs: Any, *, lossless: bool, size: int = QUEUE_FRAMES):
        self.rs = rs
        self.lossless = lossless
        self.size = size
        self.items: collections.deque[Item] = collections.deque()
        self.cv = threading.Condition()
        self.closed = False
        self.error: BaseException | None = None
        md = rs.frame_metadata_value
        self._md = [(k, getattr(md, k)) for k in METADATA_KEYS if hasattr(md, k)]

    def __call__(self, f: Any) -> None:  # on the SDK's thread
        try:
            rs = self.rs
            p = f.get_profile()
            stype = p.stream_type()
            if stype == rs.stream.depth:
                kind = "depth"
            elif stype == rs.stream.infrared and p.stream_index() == 1:
                kind = "ir"
            else:
                return
            raw = {k: float(f.get_frame_metadata(v)) for k, v in self._md if f.supports_frame_metadata(v)} if kind == "depth" else {}
            item = Item(kind, int(f.get_frame_number()), float(f.get_timestamp()), timestamp_domain(f), raw,
                         np.array(np.asanyarray(f.get_data()), copy=True))
        except BaseException as e:  # reported to the reader
            self.error = e
            return
        with self.cv:
            if self.lossless:
                while len(self.items) >= self.size and not self.closed:
                    self.cv.wait(0.05)
            elif len(self.items) >= self.size:
                self.items.popleft()
            if not self.closed:
                self.items.append(item)
                self.cv.notify_all()

    def get(self, timeout_s: float) -> Item | None:
        with self.cv:
            if not self.items and timeout_s > 0:
                self.cv.wait_for(lambda: bool(self.items) or self.closed, timeout_s)
            if not self.items:
                return None
            item = self.items.popleft()
            self.cv.notify_all()
            return item

    def first(self, kind: str, timeout_s: float) -> Item | None:
        """The oldest buffered frame of `kind`, left in the buffer; waits up to timeout_s for one (None: none came)."""
        def found() -> Item | None:
            return next((i for i in self.items if i.kind == kind), None)

        with self.cv:
            self.cv.wait_for(lambda: found() is not None or self.closed or self.error is not None
                             or (self.lossless and len(self.items) >= self.size), timeout_s)
            return found()

    def drain(self) -> int:
        """Discard every buffered frame; return the highest frame number discarded (-1 if none)."""
        with self.cv:
            last = max((i.number for i in self.items), default=-1)
            self.items.clear()
            self.cv.notify_all()
            return last

    def close(self) -> None:
        with self.cv:
            self.closed = True
            self.cv.notify_all()


def timestamp_domain(f: Any) -> str:
    return str(f.get_frame_timestamp_domain()).split(".")[-1]
