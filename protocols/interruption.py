"""A request to stop (Ctrl-C, SIGTERM) that outlives a KeyboardInterrupt Python swallowed.

A signal handler that raises runs at whatever Python is executing when the signal arrives; if that is a weakref
callback, a finaliser or a `__del__`, the KeyboardInterrupt is printed as "Exception ignored in ..." and lost, and
the run went on to its end (seen once in the suite: SIGTERM during a weakref callback, exit 0 instead of 130). The
command's handler therefore also `request()`s the stop, and the runner `check()`s at every step and frame, raising
the KeyboardInterrupt again where it is handled: completed stops saved, the resume hint, exit 130.
"""

from __future__ import annotations

import threading

REQUESTED = threading.Event()


def request() -> None:
    """Ask the running work to stop at its next check (safe from a signal handler or another thread)."""
    REQUESTED.set()


def forget() -> None:
    """Drop a request already acted on (a command starts with none)."""
    REQUESTED.clear()


def check() -> None:
    """Raise KeyboardInterrupt if a stop was requested (once: the request is then gone)."""
    if REQUESTED.is_set():
        REQUESTED.clear()
        raise KeyboardInterrupt
