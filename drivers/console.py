"""SDKs that talk on the process's standard output: their chatter goes to standard error instead.

depthai's logger writes to file descriptor 1 from C++ (`[depthai] [warning] USB protocol not available`
when it is imported without USB access), under Python's sys.stdout, where it would mix into output that
scripts read (`rig devices`). `sdk_chatter_to_stderr()` points descriptor 1 at descriptor 2 while an SDK is
imported, searches or opens a device; nested and concurrent uses (probes in threads) share one redirection,
undone when the last ends. Python's own buffered stdout is flushed first, so nothing of ours is moved.
"""

from __future__ import annotations

import os
import sys
import threading
from contextlib import contextmanager
from typing import Iterator

_lock = threading.Lock()
_depth = 0
_saved_fd: int | None = None


def _flush() -> None:
    for stream in (sys.stdout, sys.__stdout__):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):
            pass


@contextmanager
def sdk_chatter_to_stderr() -> Iterator[None]:
    """While inside, whatever is written to file descriptor 1 goes to descriptor 2."""
    global _depth, _saved_fd
    with _lock:
        if _depth == 0:
            _flush()
            try:
                _saved_fd = os.dup(1)
                os.dup2(2, 1)
            except OSError:  # no descriptor 1 or 2 (a daemon): nothing to move
                _saved_fd = None
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and _saved_fd is not None:
                try:
                    os.dup2(_saved_fd, 1)
                finally:
                    os.close(_saved_fd)
                    _saved_fd = None
