"""Progress of long analysis work (fits, diagnoses) on a terminal, fed by `rig.models.fitting.progress`.

    with WorkProgressLine("rig diagnose", verbosity) as progress:
        diagnose(data, progress=progress)

On a terminal, stderr shows one line that updates in place: what is being done, how far, the
time so far and an estimate of the time left, e.g.

    rig diagnose [######........] 6/14 0:21, about 0:25 left: fitting active+noise_floor

The line is redrawn twice a second, so the clock moves during a long step, and erased when the
work ends (or fails), before the result is printed. When stderr is not a terminal (a pipe, a log,
CI) nothing is written; `-q` (verbosity < 0) writes nothing either. `-v` (verbosity >= 1) adds a
line per finished step with its duration, and a last line with the total, on a terminal or not.

The time left is the time so far per finished step times the steps still expected; a step's
count may grow while the work goes on (a diagnosis adds effects as it finds them), so it is an
estimate, shown as "about".
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:  # only named here: `rig run` must not load the models (scipy, numba) to show its progress
    from ..models.fitting.progress import WorkProgress

BAR_WIDTH = 14
REDRAW_S = 0.5


def clock(seconds: float) -> str:
    """0:07, 1:05, 1:02:03."""
    s = int(round(max(seconds, 0.0)))
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class WorkProgressLine:
    """A `ProgressFn` that shows analysis progress on a terminal's stderr (see the module's docstring)."""

    def __init__(self, title: str, verbosity: int = 0, stream: TextIO | None = None, *, redraw_s: float = REDRAW_S):
        self.title = title
        self.stream = stream or sys.stderr
        self.verbosity = verbosity
        self.tty = _is_terminal(self.stream)
        self.live = self.tty and verbosity >= 0  # the updating line
        self.log = verbosity >= 1  # a line per finished step
        self.t0 = time.monotonic()
        self.current: WorkProgress | None = None
        self.step_t0 = self.t0
        self.shown = False  # the updating line is on the screen
        self.drawn = ""  # what it reads
        self.lock = threading.Lock()
        self.stopped = threading.Event()
        self.ticker: threading.Thread | None = None
        self.redraw_s = redraw_s

    # -- the ProgressFn ---------------------------------------------------------------------------
    def __call__(self, p: WorkProgress) -> None:
        now = time.monotonic()
        with self.lock:
            previous = self.current
            if self.log and previous is not None and not previous.finished:
                self._erase()
                self._write(f"{self.title}: {previous.task} ({now - self.step_t0:.1f} s)\n")
            self.current, self.step_t0 = p, now
            if p.finished:
                self._erase()
                if self.log:
                    self._write(f"{self.title}: {p.task} after {now - self.t0:.1f} s\n")
                return
            self._draw(now)
        if self.live and self.ticker is None:
            self.ticker = threading.Thread(target=self._tick, name="progress-line", daemon=True)
            self.ticker.start()

    def close(self) -> None:
        """Stop redrawing and erase the line (the work is over, or failed)."""
        self.stopped.set()
        if self.ticker is not None:
            self.ticker.join(timeout=2)
        with self.lock:
            self._erase()

    def __enter__(self) -> "WorkProgressLine":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def print_above(self, text: str, out: TextIO | None = None) -> None:
        """Print a line of results (to `out`, stdout by default) without mixing it into the progress line."""
        out = out or sys.stdout
        with self.lock:
            self._erase()
            print(text, file=out, flush=True)
            if self.current is not None and not self.current.finished:
                self._draw(time.monotonic())

    def above(self, out: TextIO | None = None) -> "LinesAbove":
        """A stream for code that prints its results line by line (to `out`) while this line shows progress."""
        return LinesAbove(self, out or sys.stdout)

    # -- drawing --------------------------------------------------------------------------------
    def line(self, now: float) -> str:
        """The progress line as it reads at `now` (monotonic seconds)."""
        p = self.current
        if p is None:
            return ""
        elapsed = now - self.t0
        filled = int(BAR_WIDTH * p.fraction)
        text = f"{self.title} [{'#' * filled}{'.' * (BAR_WIDTH - filled)}] {p.done}/{p.total} {clock(elapsed)}"
        if p.done > 0:
            per_step = (self.step_t0 - self.t0) / p.done
            left = max(per_step * (p.total - p.done) - (now - self.step_t0), 0.0)
            text += f", {'at least' if p.more_may_come else 'about'} {clock(left)} left"  # lower bound while steps may come
        return f"{text}: {p.task}"  # the task last: a narrow terminal cuts it, not the numbers

    def _draw(self, now: float) -> None:
        if not self.live:
            return
        width = _columns(self.stream)
        text = self.line(now)
        if len(text) > width - 1:  # a wrapped line could not be redrawn in place
            text = text[: max(width - 4, 0)] + "..."
        if self.shown and text == self.drawn:
            return
        self._write("\r" + text + "\x1b[K")
        self.shown, self.drawn = True, text

    def _erase(self) -> None:
        if self.shown:
            self._write("\r\x1b[K")
            self.shown = False

    def _write(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):  # the terminal went away: progress is not worth failing the work for
            self.live = self.log = False

    def _tick(self) -> None:
        while not self.stopped.wait(self.redraw_s):
            with self.lock:
                if self.current is not None and not self.current.finished and self.shown:
                    self._draw(time.monotonic())


def _is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError, OSError):
        return False


def _columns(stream: TextIO) -> int:
    try:
        return os.get_terminal_size(stream.fileno()).columns or 80
    except (AttributeError, ValueError, OSError):
        return 80


class LinesAbove:
    """A text stream whose every whole line goes out through `WorkProgressLine.print_above`."""

    def __init__(self, progress: WorkProgressLine, out: TextIO):
        self.progress, self.out, self.pending = progress, out, ""

    def write(self, text: str) -> int:
        self.pending += text
        *lines, self.pending = self.pending.split("\n")
        for line in lines:
            self.progress.print_above(line, self.out)
        return len(text)

    def flush(self) -> None:
        self.out.flush()
