"""A linear stage on the X axis of a GRBL 1.1 controller (G-code over USB serial). Stage kind `grbl`.

    grbl:///dev/ttyUSB0?baud=115200&offset_m=0.3&direction=1&feed=3000&settle=0.2&tolerance_mm=1

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
from .grbl_machine import REQUIRED, move_time_s, parse_settings, rail_geometry, travel_note
from .line import CABLE, GarbledReply, SerialLine
from .rail import GRBL_OPTIONS, Rail, require_port

_BANNER = re.compile(r"^Grbl (\S+) \[.*\]$")
_STATUS = re.compile(r"^<([A-Za-z]+)(?::\d+)?\|(.*)>$")


@dataclass(frozen=True)
class GrblStatus:
    """One real-time status report: the machine state and the X machine position in mm."""

    state: str
    x_mm: float


class GrblStage(Stage):
    """A linear stage on the X axis of a GRBL 1.1 controller (G-code over USB serial).

    Moves are absolute, in machine coordinates (G53 G1), so work offsets on the controller do not
    matter. The driver reads the controller at open (`$$`, `$I`) instead of assuming it:
    - the rail: with homing, rail zero is where homing leaves the carriage, and "away from home" is -X
      when the controller homes towards +X ($23 bit 0 clear, stock) and +X otherwise; where homing
      leaves MPos follows the firmware (limits.c): 0 with HOMING_FORCE_SET_ORIGIN (`Z` in `$I`'s OPT),
      else -$27 (homing to +X) or -$130+$27 (to -X); the travel is what soft limits allow, $130 long.
      Without homing, rail zero is MPos 0 (where the carriage was at power-up) and the travel +X, $130
      long. `rail_min_mm` and `travel_mm` in the device string override this (machine X, +X away).
    - $13=1 (report in inches): positions are converted; $10 must report MPos (bit 0)
    - the feed is capped at $110, a move's time comes from $110, $120 and the distance, and a move
      is stuck when its position stops changing, not when a fixed budget runs out
    - on any error during motion it stops the carriage (feed hold `!`, then a soft reset, which keeps
      the position once the hold is complete) before reporting
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
        travel_mm: float | None = None,
        rail_min_mm: float | None = None,
        homing: bool = True,
        timeout_s: float = 2.0,
        home_timeout_s: float = 120.0,
        poll_s: float = 0.05,
        stall_s: float = 3.0,
    ):
        self.link = SerialLine("grbl", path, baud, timeout_s)
        self.name = self.link.name
        self.offset_m, self.direction = offset_m, direction
        self.requested_feed_mm_min = self.feed_mm_min = feed_mm_min
        self.settle_s = settle_s
        self.tolerance_m = tolerance_mm / 1000.0
        self.travel_mm, self.rail_min_mm = travel_mm, rail_min_mm
        self.homing = homing
        self.timeout_s = timeout_s
        self.home_timeout_s = home_timeout_s
        self.poll_s = poll_s
        self.stall_s = stall_s
        self.firmware = ""
        self.settings: dict[int, float] = {}
        self.options = ""
        #: machine X of rail zero, and the sign of machine X moving away from it
        self.home_mm, self.away = 0.0, 1
        self.rail: Rail | None = None
        if travel_mm is not None and rail_min_mm is not None:  # the device string fixes the rail in machine X
            self.rail = Rail(offset_m, direction, rail_min_mm, rail_min_mm + travel_mm)
        self._homed = False
        self._last_x_mm: float | None = None
        self._alarm = ""  # the last alarm seen: GRBL is silent after ALARM:1/2 and resets after a homing alarm

    @classmethod
    def from_spec(cls, spec: DeviceSpec) -> "GrblStage":
        o = spec.take(GRBL_OPTIONS)  # the options, their defaults and checks: drivers/serial/rail.py
        return cls(
            require_port(spec),
            baud=o["baud"],
            offset_m=o["offset_m"],
            direction=o["direction"],
            feed_mm_min=o["feed"],
            settle_s=o["settle"],
            tolerance_mm=o["tolerance_mm"],
            travel_mm=o["travel_mm"],
            rail_min_mm=o["rail_min_mm"],
            homing=o["homing"],
            timeout_s=o["timeout_s"],
            home_timeout_s=o["home_timeout_s"],
            poll_s=o["poll_s"],
            stall_s=o["stall_s"],
        )

    # --- Stage ------------------------------------------------------------------------------------

    @property
    def limits_m(self) -> tuple[float, float]:
        return self._rail().limits_m

    def _rail(self) -> Rail:
        if self.rail is None:
            raise self.link.error(
                "travel limits are unknown until the stage is opened (they are read from the controller's $$)",
                "open it first, or give both rail_min_mm= and travel_mm= in the device string",
            )
        return self.rail

    def open(self) -> None:
        self.link.open()
        self._homed = False
        try:
            self._soft_reset()
            self._read_settings()
            self._status()
        except StageError:
            self.link.close()
            raise

    def close(self) -> None:
        self.link.close()

    def home(self) -> None:
        """Reset out of any alarm or hold, run the homing cycle ($H) or just unlock ($X), set G90 G21."""
        self.link.discard_input()
        try:
            state = self._status().state
        except StageError:
            state = "silent"  # after ALARM:1/2 GRBL answers nothing until a reset
        if state in ("silent", "Alarm", "Door", "Sleep") or state.startswith("Hold"):
            self._soft_reset()
        if self.homing:
            self._command("$H", self.home_timeout_s, during="homing ($H)")
        else:
            self._command("$X", self.timeout_s)
        self._command("G90 G21", self.timeout_s)
        self._homed = True

    def move_to(self, position_m: float) -> float:
        if not self._homed:
            raise self.link.error("not homed", "home the stage (the plan's home step) before moving")
        self.check_limits(position_m)
        x_mm = self.home_mm + self.away * self._rail().to_rail_mm(position_m)
        command = f"G21 G53 G1 X{x_mm:.3f} F{self.feed_mm_min:.0f}"
        last = self._last_x_mm
        distance_mm = abs(x_mm - last) if last is not None else self._rail().max_mm - self._rail().min_mm
        self._command(command, self.timeout_s)
        self._wait_idle(repr(command), self._move_time_s(distance_mm))
        if self.settle_s > 0:
            time.sleep(self.settle_s)
        measured = self.position_m()
        self.check_arrived(position_m, measured)
        return measured

    def position_m(self) -> float:
        return self._rail().to_position_m((self._status().x_mm - self.home_mm) * self.away)

    def describe(self) -> dict[str, Any]:
        rail = self.rail
        return {
            **super().describe(),
            "driver": "grbl", "port": self.link.path, "baud": self.link.baud, "firmware": self.firmware,
            "offset_m": self.offset_m, "direction": self.direction,
            "rail_mm": [rail.min_mm, rail.max_mm] if rail else None, "home_machine_x_mm": self.home_mm,
            "away_from_home": "+X" if self.away > 0 else "-X", "feed_mm_min": self.feed_mm_min,
            "settle_s": self.settle_s, "homing": self.homing, "build_options": self.options,
            "settings": {f"${n}": v for n, v in sorted(self.settings.items())},
        }

    # --- reading the controller -------------------------------------------------------------------

    def _read_settings(self) -> None:
        """`$$` and `$I`: the settings the driver depends on, and the rail geometry they imply."""
        self.settings = parse_settings(self._query("$$"))
        missing = [n for n in REQUIRED if n not in self.settings]
        if missing:
            raise self.link.error(
                f"'$$' did not list {', '.join(f'${n}' for n in missing)}",
                "check that the controller runs GRBL 1.1 (other firmware numbers its settings differently)",
            )
        self.options = next((t[5:-1] for t in self._query("$I") if t.startswith("[OPT:")), "")
        s = self.settings
        if not int(s[10]) & 1:
            raise self.link.error(
                f"the controller reports work positions ($10={int(s[10])})",
                "set $10=1 (or $10=3) so status reports give the machine position, MPos",
            )
        if self.homing and not s[22]:
            raise self.link.error(
                "homing is disabled on the controller ($22=0)",
                "enable it ($22=1, with home switches fitted) or add homing=0 to the device string",
            )
        self.feed_mm_min = min(self.requested_feed_mm_min, s[110])
        if self.rail is not None:
            return  # rail_min_mm and travel_mm given: the device string wins
        geometry = rail_geometry(s, self.options, homing=self.homing)
        self.home_mm, self.away = geometry.home_mm, geometry.away
        travel = min(self.travel_mm or geometry.travel_mm, geometry.travel_mm)
        low = self.rail_min_mm or 0.0
        self.rail = Rail(self.offset_m, self.direction, low, low + travel)

    def _query(self, line: str) -> list[str]:
        """Send a $ command; the lines before its 'ok'."""
        what = repr(line)
        self.link.write(line.encode("ascii") + b"\n", what)
        deadline = time.monotonic() + self.timeout_s
        out: list[str] = []
        while True:
            text = self.link.read_line(deadline, what)
            if text is None:
                raise self.link.no_reply(what, self.timeout_s)
            if text == "ok":
                return out
            if text.startswith("$") or text.startswith("["):
                out.append(text)
            else:
                self._check_message(text, what)

    def _move_time_s(self, distance_mm: float) -> float:
        return move_time_s(distance_mm, self.feed_mm_min, self.settings.get(120, 0.0))

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
                    self._alarm = ""
                    return
                if line:
                    seen.append(line)
        got = f" (got {seen[-1]!r})" if seen else " (got nothing)"
        raise self.link.error(
            f"no GRBL banner within {2 * self.timeout_s:.1f} s of a soft reset{got}",
            f"check that this port is the GRBL controller, that baud={self.link.baud} matches it, and {CABLE}",
        )

    def _command(self, line: str, timeout_s: float, *, during: str = "") -> None:
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
            self._check_message(text, what, during)
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
                if self._alarm:
                    raise self.link.error(
                        f"controller silent after {self._alarm}: GRBL answers nothing, not even '?', until a reset",
                        "resume the run: homing sends the reset (Ctrl-X) first",
                    )
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
            x = float(fields["MPos"].split(",")[0])
        except ValueError:
            raise self.link.garbled(text, "'?'") from None
        x_mm = x * 25.4 if int(self.settings.get(13, 0)) == 1 else x  # $13=1: GRBL reports inches
        if not math.isfinite(x_mm) or abs(x_mm) > 1e6:
            raise self.link.garbled(text, "'?'")  # no rail is a kilometre long
        self._last_x_mm = x_mm
        return GrblStatus(match.group(1).split(":")[0] if match.group(1).startswith("Hold") else match.group(1), x_mm)

    def _check_message(self, text: str, what: str, during: str = "") -> None:
        """Pass over push messages; raise on errors, alarms, resets and anything unrecognised."""
        if not text or text.startswith("[") or re.match(r"^\$\d+=", text) or text.startswith(">"):
            return  # [MSG:...], [GC:...], settings, and startup lines run after a reset (>G20:ok)
        if text.startswith("error:") and text[6:].isdigit():
            code = int(text[6:])
            raise self.link.error(
                f"controller answered {text} ({GRBL_ERRORS.get(code, 'unknown error')}) to {what}",
                _grbl_error_fix(code),
            )
        if text.startswith("ALARM:") and text[6:].isdigit():
            code = int(text[6:])
            self._homed = False
            self._alarm = text if code in (1, 2) else ""
            if code in (6, 7, 8, 9):
                self._alarm = "reset"  # a homing alarm resets the controller: its banner follows
            meaning, fix = GRBL_ALARMS.get(code, ("unknown alarm", "check the controller"))
            if code == 2:
                meaning += travel_note(self.settings, self.options)
            raise self.link.error(f"{text} during {during or what} ({meaning})", f"{fix}")
        if _BANNER.match(text):
            if self._alarm == "reset":
                self._alarm = ""
                return  # the reset that follows a homing alarm, already reported
            self._homed = False
            raise self.link.error(
                f"controller reset unexpectedly during {what} (banner {text!r}), position lost",
                f"check its power supply and the USB cable",
            )
        raise self.link.garbled(text, what)

    def _wait_idle(self, what: str, expected_s: float) -> GrblStatus:
        """Poll '?' until the motion has ended; stop the carriage (feed hold, reset) before raising."""
        try:
            return self._poll_until_idle(what, expected_s)
        except StageError:
            if self.link.is_open and not self._alarm:
                self._stop_motion()
            raise

    def _stop_motion(self) -> None:
        """Feed hold, wait for the hold to complete, then soft reset: the carriage stops and GRBL keeps
        its position (commands.md). Best effort: the error that led here is what gets reported."""
        try:
            self.link.write(b"!", "a feed hold ('!')")
            deadline = time.monotonic() + max(2.0, self._move_time_s(0.0) * 2)
            while time.monotonic() < deadline:
                if self._status().state in ("Hold", "Idle", "Alarm"):
                    break
                time.sleep(self.poll_s)
            self._soft_reset()
        except StageError:
            pass

    def _poll_until_idle(self, what: str, expected_s: float) -> GrblStatus:
        """Idle counts once motion was seen, or when two reports in a row say Idle (a move may not have
        started when the first one is sent). Stuck: the position has not changed for stall_s while not
        Idle, or the move takes far longer than the settings allow."""
        start = time.monotonic()
        deadline = start + 2.0 * expected_s + 10.0
        moved, idle_reports = False, 0
        last_x, last_change = None, start
        while True:
            status = self._status(what)
            now = time.monotonic()
            if last_x is None or abs(status.x_mm - last_x) > 1e-3:
                last_x, last_change = status.x_mm, now
            if status.state == "Idle":
                idle_reports += 1
                if moved or idle_reports >= 2:
                    return status
            elif status.state in ("Run", "Home", "Jog"):
                moved, idle_reports = True, 0
            elif status.state == "Hold":
                if now - last_change > self.stall_s:
                    raise self.link.error(f"feed hold during {what} (X {status.x_mm:.3f} mm)",
                                          "someone pressed hold on the controller; resume the run to go on")
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
            if status.state == "Run" and now - last_change > self.stall_s:
                raise self.link.error(
                    f"stuck during {what}: X has stayed at {status.x_mm:.3f} mm for {now - last_change:.1f} s "
                    f"in state Run", "check the rail for obstruction and the motor wiring; the carriage was stopped",
                )
            if now > deadline:
                raise self.link.error(
                    f"still moving {now - start:.1f} s after {what} (state {status.state}, X {status.x_mm:.3f} mm), "
                    f"though {expected_s:.1f} s should do at F{self.feed_mm_min:.0f} ($110={self.settings.get(110, 0):g}, "
                    f"$120={self.settings.get(120, 0):g})", "check the rail for obstruction and the controller's overrides",
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
