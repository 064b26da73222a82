"""Progress lines for a run in a terminal, fed by the runner's `ProgressEvent`s."""

from __future__ import annotations

import sys
import time
from typing import TextIO

from protocols.runner import ProgressEvent


class TerminalProgress:
    """One updating bar per stop on a terminal; one line per stop elsewhere (logs, CI)."""

    def __init__(self, stream: TextIO | None = None, prefix: str = ""):
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.prefix = prefix
        self.t0 = time.monotonic()

    def __call__(self, e: ProgressEvent) -> None:
        head = f"{self.prefix}[{e.stop_index + 1:2d}/{e.n_stops}] {e.stop:>8}"
        if e.kind == "frame" and self.tty:
            width = 30
            filled = int(width * e.frame / max(e.n_frames, 1))
            self.stream.write(f"\r{head} {'#' * filled}{'.' * (width - filled)} {e.frame}/{e.n_frames} frames")
            self.stream.flush()
        elif e.kind == "stop_done":
            s = e.summary
            line = (f"{head} done: fill {100 * s['fill_rate']:5.1f}%, centre {s['center_mean_m']:.3f} m, "
                    f"sigma {1000 * s['center_sigma_m']:7.3f} mm  ({time.monotonic() - self.t0:5.1f} s)")
            self.stream.write(("\r" if self.tty else "") + line + (" " * 10 if self.tty else "") + "\n")
        elif e.kind == "stop_skipped":
            self.stream.write(f"{head} already recorded, skipped\n")
        elif e.kind == "message":
            self.stream.write(f"{self.prefix}{e.text}\n")
        self.stream.flush()
