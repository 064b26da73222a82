"""Dropped and duplicated frames of one stop, told from the frames' numbers and timestamps.

A camera numbers its frames as its sensor makes them (RealSense: the firmware's frame counter;
OAK-D: the sequence number), so frames lost on the way (a busy USB bus, a slow consumer) leave a
gap in the numbers, and a frame handed over twice repeats a number. Where the numbers run on
but the time between two frames is PERIOD_GAP or more frame periods (the period: the median of
the stop's first frame intervals), the frames between are counted as dropped too.

A duplicate carries no new sample: folding it in twice would halve its pixels' noise, so the
runner leaves it out (`check` returns False). Drops only mean fewer frames than asked for
within the capture's time; the runner asks for more until the stop has its frames.
"""

from __future__ import annotations

import math
import statistics

#: a frame interval this many periods long or longer means frames were dropped
PERIOD_GAP = 1.5
#: intervals of consecutively numbered frames that fix the stop's frame period
PERIOD_SAMPLES = 16


class FrameContinuity:
    """Counts dropped and duplicated frames of one stop, frame by frame."""

    def __init__(self) -> None:
        self.dropped = 0
        self.duplicated = 0
        self._number: int | None = None
        self._time_ms = math.nan
        self._intervals: list[float] = []
        self._period_ms = math.nan

    def check(self, frame_number: int, timestamp_ms: float) -> bool:
        """Note one frame as it arrives; False if it is a duplicate of the previous one (leave it out)."""
        last, last_t = self._number, self._time_ms
        if last is None:
            self._number, self._time_ms = frame_number, timestamp_ms
            return True
        if frame_number == last:
            self.duplicated += 1
            return False
        dt = timestamp_ms - last_t
        if frame_number > last + 1:
            self.dropped += frame_number - last - 1
        elif frame_number == last + 1 and math.isfinite(dt) and dt > 0:
            if math.isfinite(self._period_ms) and dt >= PERIOD_GAP * self._period_ms:
                self.dropped += round(dt / self._period_ms) - 1
            elif len(self._intervals) < PERIOD_SAMPLES:
                self._intervals.append(dt)
                if len(self._intervals) >= 3:
                    self._period_ms = statistics.median(self._intervals)
        # a number below the last: the camera restarted its counter; neither a drop nor a duplicate
        self._number, self._time_ms = frame_number, timestamp_ms
        return True
