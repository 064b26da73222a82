"""The G-code the simulated GRBL 1.1h controller (`fakes/grbl_sim.py`) understands, parsed as the firmware
parses it where the driver and the tests go (grbl/gcode.c): G0, G1, G4, G20/G21, G53, G90/G91, F, X, and `$J=`
jogs; unknown G-codes are error:20, a line that is not words error:1, G1 without a feed error:22, a jog
without F error:22 (gcode.c checks the jog's F word first) and without an axis error:16. A target beyond soft
limits is ALARM:2 for a move (a critical event; the line's `ok` comes after the reset) and error:15 for a jog.
"""

from __future__ import annotations

import re
from typing import Any

_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")


class GrblGcode:
    """G-code lines into the simulated controller's planner queue."""

    # provided by GrblSim
    settings: dict[int, float]
    state: str
    absolute: bool
    mm_per_unit: float
    motion: int
    feed_mm_min: float
    _queue: list[tuple[str, float, float]]
    _target: Any
    _owed_ok: bool

    def _gcode(self, line: str, now_s: float, *, jog: bool = False) -> str | None:
        """Parse and queue one line; None once its `ok` is sent (or deferred), else the error line."""
        if self.state == "Alarm" or (jog and self.state not in ("Idle", "Jog")):
            return "error:9" if self.state == "Alarm" else "error:8"
        words = _WORD.findall(line)
        if "".join(letter + value for letter, value in words) != line:
            return "error:1"
        motion, machine, x, dwell_s = None, False, None, None
        absolute, mm_per_unit, feed = self.absolute, self.mm_per_unit, None
        for letter, value in words:
            number = float(value)
            if letter == "G":
                if number in (0, 1, 4):
                    motion = int(number)
                elif number == 53:
                    machine = True
                elif number in (90, 91):
                    absolute = number == 90
                elif number in (20, 21):
                    mm_per_unit = 25.4 if number == 20 else 1.0
                elif number not in (17, 54, 94):
                    return "error:20"
            elif letter == "X":
                x = number
            elif letter == "F":
                feed = number
            elif letter == "P":
                dwell_s = number
            elif letter not in ("Y", "Z", "N", "M", "S", "T"):
                return "error:20"
        if jog:
            if feed is None:
                return "error:22"  # gcode.c: a jog needs its F word (step 2), before anything else is checked
            if x is None:
                return "error:16"
            current = self._planned_end_mm(now_s)
            target = x * mm_per_unit if (absolute or machine) else current + x * mm_per_unit
            low, high = self.machine_limits_mm()
            if self.settings[20] and not low <= target <= high:
                return "error:15"
            self._queue.append(("jog", target, feed * mm_per_unit))
            self.send_line("ok")
            return None
        self.absolute, self.mm_per_unit = absolute, mm_per_unit
        if feed is not None:
            self.feed_mm_min = feed * mm_per_unit
        if motion == 4:
            self._queue.append(("dwell", dwell_s or 0.0, 0.0))
            return None  # "ok" once the dwell is over
        if motion in (0, 1):
            self.motion = motion
        if x is None:
            self.send_line("ok")
            return None
        if self.motion == 1 and self.feed_mm_min <= 0:
            return "error:22"
        current = self._planned_end_mm(now_s)
        target = x * mm_per_unit if (absolute or machine) else current + x * mm_per_unit
        low, high = self.machine_limits_mm()
        if self.settings[20] and not low <= target <= high:
            self._critical_alarm(2, now_s)
            self._owed_ok = True
            return None
        if self.state != "Check":
            self._queue.append(("move", target, self.feed_mm_min if self.motion == 1 else self.settings[110]))
        self.send_line("ok")
        return None

    def _planned_end_mm(self, now_s: float) -> float:
        moves = [q for q in self._queue if q[0] != "dwell"]
        if moves:
            return moves[-1][1]
        if self._target is not None and self.state != "Idle":
            return self._target[0]
        return self.machine_mm(now_s)
