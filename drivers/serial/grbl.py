"""A linear stage on the X axis of a GRBL 1.1 controller (G-code over USB serial). Stage kind `grbl`.

    grbl:///dev/ttyUSB0?baud=115200&offset_m=0.3&direction=1&feed=3000&settle=0.2&tolerance_mm=1&travel_mm=3000

Every failure raises `StageError` with one line, "grbl <port>: <problem>; <what to do>";
docs/stages.md lists them all with causes and fixes.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass
from typing import Any

from ..errors import StageError
from ..registry import DeviceSpec
from ..stage import Stage
from .grbl_codes import GRBL_ALARMS, GRBL_ERRORS
from .line import CABLE, GarbledReply, SerialLine
from .rail import Rail, direction_option, positive_option, require_port

_BANNER = re.compile(r"^Grbl (\S+) \[.*\]$")
_STATUS = re.compile(r"^<([A-Za-z]+)(?::\d+)?\|(.*)>$")


@dataclass(frozen=True)
class GrblStatus:
    """One real-time status report: the machine state and the X machine position in mm."""

    state: str
    x_mm: float


class GrblStage(Stage):
    """A linear stage on the X axis of a GRBL 1.1 controller (G-code over USB serial).

    Moves are absolute, in machine coordinates (G53 G1), so work offsets on the controller
    do not matter; the rail spans rail_min_mm .. rail_min_mm + travel_mm of machine X.
    """

    def __init__(
        self,
        path: str,
        *,
        baud: int = 115200,
        offset_m: float = 0.3,
        direction: int = 1,
        feed_mm_min: float = 3000.0,
        settle_s: float = 0.2,
        tolerance_mm: float = 1.0,
        travel_mm: float = 3000.0,
        rail_min_mm: float = 0.0,
        homing: bool = True,
        timeout_s: float = 2.0,
        home_timeout_s: float = 120.0,
        poll_s: float = 0.05,
    ):
        self.link = SerialLine("grbl", path, baud, timeout_s)
        self.name = self.link.name
        self.rail = Rail(offset_m, direction, rail_min_mm, rail_min_mm + travel_mm)
        self.feed_mm_min = feed_mm_min
        self.settle_s = settle_s
        self.tolerance_m = tolerance_mm / 1000.0
        self.homing = homing
        self.timeout_s = timeout_s
        self.home_timeout_s = home_timeout_s
        self.poll_s = poll_s
        self.firmware = ""
        self._homed = False
        self._last_x_mm: float | None = None

    @classmethod
    def from_spec(cls, spec: DeviceSpec) -> "GrblStage":
        return cls(
            require_port(spec),
            baud=spec.int("baud", 115200),
            offset_m=spec.float("offset_m", 0.3),
            direction=direction_option(spec),
            feed_mm_min=positive_option(spec, "feed", 3000.0),
            settle_s=spec.float("settle", 0.2),
            tolerance_mm=positive_option(spec, "tolerance_mm", 1.0),
            travel_mm=positive_option(spec, "travel_mm", 3000.0),
            rail_min_mm=spec.float("rail_min_mm", 0.0),
            homing=bool(spec.int("homing", 1)),
            timeout_s=positive_option(spec, "timeout_s", 2.0),
            home_timeout_s=positive_option(spec, "home_timeout_s", 120.0),
            poll_s=positive_option(spec, "poll_s", 0.05),
        )

    # --- Stage ------------------------------------------------------------------------------------

    @property
    def limits_m(self) -> tuple[float, float]:
        return self.rail.limits_m

    def open(self) -> None:
        self.link.open()
        self._homed = False
        try:
            self._soft_reset()
            self._status()
        except StageError:
            self.link.close()
            raise

    def close(self) -> None:
        self.link.close()

    def home(self) -> None:
        """Reset out of any alarm, run the homing cycle ($H) or just unlock ($X), set G90 G21."""
        self.link.discard_input()
        if self._status().state in ("Alarm", "Door", "Sleep"):
            self._soft_reset()
        if self.homing:
            self._command("$H", self.home_timeout_s)
        else:
            self._command("$X", self.timeout_s)
        self._command("G90 G21", self.timeout_s)
        self._homed = True

    def move_to(self, position_m: float) -> float:
        if not self._homed:
            raise self.link.error("not homed", "home the stage (the plan's home step) before moving")
        self.check_limits(position_m)
        x_mm = self.rail.to_rail_mm(position_m)
        command = f"G53 G1 X{x_mm:.3f} F{self.feed_mm_min:.0f}"
        last = self._last_x_mm
        distance_mm = abs(x_mm - last) if last is not None else self.rail.max_mm - self.rail.min_mm
        self._command(command, self.timeout_s)
        self._wait_idle(repr(command), 2.0 * distance_mm / (self.feed_mm_min / 60.0) + 10.0)
        if self.settle_s > 0:
            time.sleep(self.settle_s)
        measured = self.position_m()
        self.check_arrived(position_m, measured)
        return measured

    def position_m(self) -> float:
        return self.rail.to_position_m(self._status().x_mm)

    def describe(self) -> dict[str, Any]:
        return {
            **super().describe(),
            "driver": "grbl", "port": self.link.path, "baud": self.link.baud, "firmware": self.firmware,
            "offset_m": self.rail.offset_m, "direction": self.rail.direction,
            "rail_mm": [self.rail.min_mm, self.rail.max_mm], "feed_mm_min": self.feed_mm_min,
            "settle_s": self.settle_s, "homing": self.homing,
        }

    # --- protocol ---------------------------------------------------------------------------------

    def _soft_reset(self) -> None:
        """Wake the controller, send Ctrl-X and wait for the 'Grbl 1.1h [...]' banner.
        Tries twice: a board that resets when the port opens ignores bytes while it boots."""
        self.link.write(b"\r\n\r\n", "the wake-up")
        seen: list[str] = []
        for _ in range(2):
            self.link.discard_input()
            self.link.write(b"\x18", "a soft reset (Ctrl-X)")
            deadline = time.monotonic() + self.timeout_s
            while True:
                try:
                    line = self.link.read_line(deadline, "a soft reset (Ctrl-X)")
                except GarbledReply:
                    seen.append("garbled bytes")
                    continue
                if line is None or time.monotonic() > deadline:
                    break  # silence, or a port that streams without ever sending the banner: the deadline holds
                match = _BANNER.match(line)
                if match:
                    self.firmware = match.group(1)
                    return
                if line:
                    seen.append(line)
        got = f" (got {seen[-1]!r})" if seen else " (got nothing)"
        raise self.link.error(
            f"no GRBL banner within {2 * self.timeout_s:.1f} s of a soft reset{got}",
            f"check that this port is the GRBL controller, that baud={self.link.baud} matches it, and {CABLE}",
        )

    def _command(self, line: str, timeout_s: float) -> None:
        """Send one line and wait for its 'ok'."""
        what = repr(line)
        self.link.write(line.encode("ascii") + b"\n", what)
        deadline = time.monotonic() + timeout_s
        while True:
            text = self.link.read_line(deadline, what)
            if text is None:
                raise self.link.no_reply(what, timeout_s)
            if text == "ok":
                return
            self._check_message(text, what)
            if time.monotonic() > deadline:  # lines keep coming, none of them the 'ok'
                raise self.link.no_reply(what, timeout_s)

    def _status(self, during: str = "") -> GrblStatus:
        """Ask for a real-time status report ('?') and parse it; `during` names the command
        being waited on, for messages about alarms that arrive meanwhile."""
        self.link.write(b"?", "'?'")
        deadline = time.monotonic() + self.timeout_s
        while True:
            text = self.link.read_line(deadline, "'?'")
            if text is None:
                raise self.link.no_reply("'?'", self.timeout_s)
            if text.startswith("<"):
                return self._parse_status(text)
            if text != "ok":
                self._check_message(text, "'?'", during)
            if time.monotonic() > deadline:  # lines keep coming, none of them a status report
                raise self.link.no_reply("'?'", self.timeout_s)

    def _parse_status(self, text: str) -> GrblStatus:
        match = _STATUS.match(text)
        if not match:
            raise self.link.garbled(text, "'?'")
        fields = dict(f.split(":", 1) for f in match.group(2).split("|") if ":" in f)
        if "MPos" not in fields:
            raise self.link.error(
                f"status report {text!r} has no machine position (MPos)",
                "set $10=1 on the controller so it reports MPos",
            )
        try:
            x_mm = float(fields["MPos"].split(",")[0])
        except ValueError:
            raise self.link.garbled(text, "'?'") from None
        if not math.isfinite(x_mm) or abs(x_mm) > 1e6:
            raise self.link.garbled(text, "'?'")  # no rail is a kilometre long
        self._last_x_mm = x_mm
        return GrblStatus(match.group(1), x_mm)

    def _check_message(self, text: str, what: str, during: str = "") -> None:
        """Pass over push messages; raise on errors, alarms, resets and anything unrecognised."""
        if not text or text.startswith("[") or re.match(r"^\$\d+=", text):
            return
        if text.startswith("error:") and text[6:].isdigit():
            code = int(text[6:])
            raise self.link.error(
                f"controller answered {text} ({GRBL_ERRORS.get(code, 'unknown error')}) to {what}",
                _grbl_error_fix(code),
            )
        if text.startswith("ALARM:") and text[6:].isdigit():
            code = int(text[6:])
            self._homed = False
            meaning, fix = GRBL_ALARMS.get(code, ("unknown alarm", "check the controller"))
            raise self.link.error(f"{text} during {during or what} ({meaning})", f"{fix}")
        if _BANNER.match(text):
            self._homed = False
            raise self.link.error(
                f"controller reset unexpectedly during {what} (banner {text!r}), position lost",
                f"check its power supply and the USB cable",
            )
        raise self.link.garbled(text, what)

    def _wait_idle(self, what: str, timeout_s: float) -> GrblStatus:
        """Poll '?' until the motion has ended. Idle counts once motion was seen, or when two
        reports in a row say Idle (a move may not have started when the first one is sent)."""
        deadline = time.monotonic() + timeout_s
        moved, idle_reports = False, 0
        while True:
            status = self._status(what)
            if status.state == "Idle":
                idle_reports += 1
                if moved or idle_reports >= 2:
                    return status
            elif status.state in ("Run", "Home", "Jog"):
                moved, idle_reports = True, 0
            elif status.state == "Alarm":
                self._homed = False
                raise self.link.error(
                    f"controller in Alarm during {what}", f"check the rail and limit switches"
                )
            elif status.state == "Door":
                raise self.link.error(f"safety door open during {what}", f"close it")
            elif status.state in ("Check", "Sleep"):
                raise self.link.error(
                    f"controller in {status.state} mode during {what}, nothing moves",
                    "leave it ($C toggles check mode; a reset wakes it from sleep)",
                )
            if time.monotonic() > deadline:
                raise self.link.error(
                    f"still moving {timeout_s:.1f} s after {what} (state {status.state}, X {status.x_mm:.3f} mm)",
                    "check the rail for obstruction, a feed hold and the feed rate "
                    f"(feed={self.feed_mm_min:.0f})",
                )
            time.sleep(self.poll_s)


def _grbl_error_fix(code: int) -> str:
    if code in (5, 10):
        return "enable homing on the controller ($22=1) or add homing=0 to the device string"
    if code == 9:
        return f"the controller is in alarm; re-home the stage"
    if code == 15:
        return "make travel_mm match the controller's $130 or change the plan's stops"
    if code == 22:
        return "give a positive feed= in the device string"
    return "check the controller's settings ($$) and firmware (GRBL 1.1 expected)"


def open_grbl(spec: DeviceSpec, context: dict[str, Any]) -> Stage:
    """Factory for `grbl://PORT?...` (see drivers.registry)."""
    return GrblStage.from_spec(spec)
