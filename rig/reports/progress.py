"""Progress lines for a run in a terminal, fed by the runner's `ProgressEvent`s: stops, frames, the time left, and
the warm-up's wait (in place on a terminal; a line a minute elsewhere)."""

from __future__ import annotations

import sys
import time
from typing import TextIO

from protocols.runner import ProgressEvent

from .work_progress import clock


class TerminalProgress:
    """One updating bar per stop on a terminal; one line per stop elsewhere (logs, CI)."""

    def __init__(self, stream: TextIO | None = None, prefix: str = ""):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.prefix = prefix
        self.t0 = time.monotonic()
        self.first: tuple[int, float] | None = None  # (stop index, time) of the first frame this run captured
        self.warm_up_minutes = -1  # the warm-up's minutes already reported (not a terminal)
        self.line_open = False  # a warm-up line waits to be overwritten (a terminal)

    def time_left(self, e: ProgressEvent) -> str:
        """", about 1:05 left": the time per frame so far (moves and settling included) times the frames to come."""
        now = time.monotonic()
        if self.first is None:
            self.first = (e.stop_index, now)
        first, t_first = self.first
        done = (e.stop_index - first) + (e.frame / max(e.n_frames, 1) if e.kind == "frame" else 1.0)
        if done <= 0 or now <= t_first or e.n_stops - first - done <= 0:
            return ""
        return f", about {clock((now - t_first) / done * (e.n_stops - first - done))} left"

    def __call__(self, e: ProgressEvent) -> None:
        head = f"{self.prefix}[{e.stop_index + 1:2d}/{e.n_stops}] {e.stop:>8}"
        if e.kind == "stop_start" and self.first is None:
            self.first = (e.stop_index, time.monotonic())
        if e.kind == "frame" and self.tty:
            width = 30
            filled = int(width * e.frame / max(e.n_frames, 1))
            self.stream.write(f"\r{head} {'#' * filled}{'.' * (width - filled)} {e.frame}/{e.n_frames} frames"
                              f"{self.time_left(e)}\x1b[K")
            self.stream.flush()
        elif e.kind == "stop_done":
            s = e.summary
            line = (f"{head} done: fill {100 * s['fill_rate']:5.1f}%, centre {s['center_mean_m']:.3f} m, "
                    f"sigma {1000 * s['center_sigma_m']:7.3f} mm  ({time.monotonic() - self.t0:5.1f} s"
                    f"{self.time_left(e)})")
            self.stream.write(("\r" if self.tty else "") + line + (" " * 10 if self.tty else "") + "\n")
        elif e.kind == "stop_skipped":
            self.stream.write(f"{head} already recorded, skipped\n")
        elif e.kind == "warm_up":
            if self.tty:
                self.stream.write(f"\r{self.prefix}{e.text}\x1b[K")
                self.line_open = True
            elif int(e.summary["waited_s"] // 60) > self.warm_up_minutes:
                self.warm_up_minutes = int(e.summary["waited_s"] // 60)
                self.stream.write(f"{self.prefix}{e.text}\n")
        elif e.kind == "message":
            self.stream.write(("\r\x1b[K" if self.line_open else "") + f"{self.prefix}{e.text}\n")
            self.line_open = False
        self.stream.flush()
