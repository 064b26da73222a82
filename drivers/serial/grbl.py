"""A linear stage on the X axis of a GRBL 1.1 controller (G-code over USB serial). Stage kind `grbl`.

    grbl:///dev/ttyUSB0?baud=115200&offset_m=0.3&direction=1&feed=3000&settle=0.2&tolerance_mm=1

Every failure raises `StageError` with one line, "grbl <port>: <problem>; <what to do>";
docs/stages.md lists them all with causes and fixes.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field
from typing import Any

from ..errors import StageError
from ..registry import DeviceSpec
from ..stage import Stage
from .grbl_codes import GRBL_ALARMS, GRBL_ERRORS
from .grbl_machine import REQUIRED, move_time_s, parse_settings, rail_geometry, soft_limit_window, travel_note
from .grbl_status import parse_status
from .line import CABLE, GarbledReply, SerialLine
from .rail import GRBL_OPTIONS, Rail, require_port

_BANNER = re.compile(r"^Grbl (\S+) \[.*\]$")
#: `$$` lines as GRBL prints them (report.c): anything else in its reply is a garbled line
_SETTING_LINE = re.compile(r"\$\d+=-?\d+(?:\.\d+)?")
#: how many times a status report is asked for before the link counts as bad
STATUS_TRIES = 3
#: how many times a line is sent when its reply came garbled or cut off
_COMMAND_TRIES = 2
#: reports to wait for a WCO field with $10 bit 0 clear (report.c: one in every 10 idle, 30 busy)
_WCO_WAITS = 32


@dataclass(frozen=True)
class GrblStatus:
    """One real-time status report: the machine state ("Idle", "Run", "Hold:0", "Hold:1", ...), the X
    machine position in mm, and the current feed in mm/min."""

    state: str
    x_mm: float
    feed_mm_min: float = 0.0

    @property
    def kind(self) -> str:
        """The state without its sub-state ("Hold", "Door", ...)."""
        return self.state.split(":")[0]


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
    - $13=1 (report in inches): positions are converted; $10 bit 0 clear (WPos in reports): MPos is
      WPos plus the last WCO, which GRBL sends in the first report after a reset and every 10-30 reports
    - the feed is capped at $110, a move's time comes from $110, $120 and the distance, and a move
      is stuck when its position stops changing, not when a fixed budget runs out
    - soft limits ($20=1) that the rail cannot respect are refused before anything moves (`setup_problems`)

    The link is not trusted to be clean (a USB-serial cable next to stepper drivers garbles a byte now and
    then): a garbled, cut-off or late status report is asked for again, and a line whose reply came garbled
    is sent again (every line sent is idempotent); only a link that stays bad ends the run.

    Stopping keeps the position: on any error during motion the driver sends a feed hold (`!`) and waits
    for `Hold:0` (the hold complete; `Hold:1` is still decelerating, and a reset then gives ALARM:3 and
    loses the position) before a soft reset; if the hold is not seen to complete it does not reset.
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
        self._wco_x: float | None = None  # the work offset of X from the last report with WCO, controller units

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
            self._reset_when_still(self._status_or_none(tries=1))
            self._read_settings()
            self._status()
        except StageError:
            self.link.close()
            raise

    def close(self) -> None:
        self.link.close()

    def home(self) -> None:
        """Reset out of any alarm or hold (never while the carriage moves), run the homing cycle ($H) or
        just unlock ($X), set G90 G21."""
        self.link.discard_input()
        status = self._status_or_none()  # None: silent, as GRBL is after ALARM:1/2 until a reset
        if status is None or status.kind in ("Alarm", "Door", "Sleep", "Hold", "Run", "Jog"):
            self._reset_when_still(status)
            status = self._status_or_none()
        if self.homing:
            self._command("$H", self.home_timeout_s, during="homing ($H)")
        else:
            if status is not None and status.kind == "Alarm" and not int(self.settings.get(22, 0)):
                raise self._position_lost()
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

    def setup_problems(self) -> list[str]:
        """Soft limits ($20=1) that the rail cannot respect: every move would end in ALARM:2."""
        if self.rail is None or not int(self.settings.get(20, 0)):
            return []
        low, high = soft_limit_window(self.settings, self.options)
        ends = sorted(self.home_mm + self.away * mm for mm in (self.rail.min_mm, self.rail.max_mm))
        if low - 1e-6 <= ends[0] and ends[1] <= high + 1e-6:
            return []
        return [f"{self.name}: soft limits are on ($20=1) and allow machine X only within {low:g}..{high:g} mm, "
                f"but {self._rail_words()} runs over machine X {ends[0]:g}..{ends[1]:g} mm, so the first move beyond "
                f"them would end in ALARM:2; {self._soft_limit_fix()}"]

    def travel_note(self) -> str:
        if self.rail is None or self.travel_mm is not None or self.rail_min_mm is not None:
            return ""
        return (f"raise the controller's $130 (X max travel, now {self.settings.get(130, 0):g} mm), from which "
                "the stage's travel comes, to the length of the rail")

    def _rail_words(self) -> str:
        if self.travel_mm is not None and self.rail_min_mm is not None:
            return "the rail given by rail_min_mm and travel_mm"
        if not self.homing:
            return "without homing (homing=0) the rail, from MPos 0 (where the carriage was at power-up) towards +X,"
        return "the rail"

    def _soft_limit_fix(self) -> str:
        if not self.homing:
            return ("turn soft limits off ($20=0; they need homing to mean anything), or home the stage (home "
                    "switches, $22=1 and homing=1 in the device string), or put the rail within them with "
                    f"rail_min_mm=-{self.settings.get(130, 0):g}&travel_mm={self.settings.get(130, 0):g} (check direction)")
        return "make rail_min_mm and travel_mm lie within them, or leave both out to use the controller's travel"

    # --- reading the controller -------------------------------------------------------------------

    def _read_settings(self) -> None:
        """`$$` and `$I`: the settings the driver depends on, and the rail geometry they imply."""
        self.settings = parse_settings(self._query("$$", _SETTING_LINE))
        missing = [n for n in REQUIRED if n not in self.settings]
        if missing:
            raise self.link.error(
                f"'$$' did not list {', '.join(f'${n}' for n in missing)}",
                "check that the controller runs GRBL 1.1 (other firmware numbers its settings differently)",
            )
        self.options = next((t[5:-1] for t in self._query("$I") if t.startswith("[OPT:")), "")
        s = self.settings
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

    def _query(self, line: str, shape: re.Pattern[str] | None = None) -> list[str]:
        """Send a $ command; the lines before its 'ok'. A reply with a garbled or cut-off line (or a `$` line
        not of `shape`) is asked for once more, whole."""
        what = repr(line)
        trouble = _Trouble()
        for _ in range(_COMMAND_TRIES):
            self._drop_stale(what)
            self.link.write(line.encode("ascii") + b"\n", what)
            deadline = time.monotonic() + self.timeout_s
            out: list[str] = []
            clean = True
            while True:
                try:
                    text = self.link.read_line(deadline, what)
                except GarbledReply as e:
                    trouble.garbled.append(e.raw)
                    clean = False
                    continue
                if text is None:
                    if self.link.late:
                        trouble.late += 1
                    elif clean:
                        raise self.link.no_reply(what, self.timeout_s)
                    break
                if text == "ok":
                    if clean:
                        return out
                    break
                if text.startswith("$") and (shape is None or shape.fullmatch(text)) or text.startswith("["):
                    out.append(text)
                elif not text.startswith("<"):  # a status report answering an earlier '?' is passed over
                    try:
                        self._check_message(text, what)
                    except GarbledReply:
                        trouble.garbled.append(text)
                        clean = False
        raise self._link_trouble(what, trouble, _COMMAND_TRIES)

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
                    self._wco_x = None  # a reset clears G92, so the work offset may have changed
                    return
                if line:
                    seen.append(line)
        got = f" (got {seen[-1]!r})" if seen else " (got nothing)"
        raise self.link.error(
            f"no GRBL banner within {2 * self.timeout_s:.1f} s of a soft reset{got}",
            f"check that this port is the GRBL controller, that baud={self.link.baud} matches it, and {CABLE}",
        )

    def _reset_when_still(self, status: GrblStatus | None) -> None:
        """Soft reset, but never while the carriage moves: a reset during Run, Jog or Hold:1 (a hold still
        decelerating) aborts the motion with ALARM:3 and the position is lost (interface.md). A moving
        carriage is held first; if the hold is not seen to complete, nothing is reset."""
        if status is not None and (status.kind in ("Run", "Jog") or status.state == "Hold:1"):
            still = self._hold(status)
            if still is not None:
                raise self.link.error(
                    f"the carriage is moving and a feed hold ('!') was sent, but {still}; it was not reset, "
                    "since a reset while it moves loses the position",
                    f"wait until it stops, {CABLE}, then try again")
        self._soft_reset()

    def _command(self, line: str, timeout_s: float, *, during: str = "") -> None:
        """Send one line and wait for its 'ok'. If nothing, or a garbled or cut-off line, came where the 'ok'
        should be, the line is sent once more: every line this driver sends is idempotent (absolute moves in
        machine coordinates, $X, $H, modal G-codes), so a second copy of one already accepted changes nothing."""
        what = repr(line)
        trouble = _Trouble()
        for _ in range(_COMMAND_TRIES):
            self.link.write(line.encode("ascii") + b"\n", what)
            deadline = time.monotonic() + timeout_s
            while True:
                try:
                    text = self.link.read_line(deadline, what)
                except GarbledReply as e:
                    trouble.garbled.append(e.raw)
                    deadline = min(deadline, time.monotonic() + self.timeout_s)  # that may have been the 'ok'
                    continue
                if text is None:
                    if self.link.late:
                        trouble.late += 1
                    else:
                        trouble.silent += 1
                    break
                if text == "ok":
                    return
                if not text.startswith("<"):  # a status report answering an earlier '?' is passed over
                    try:
                        self._check_message(text, what, during)
                    except GarbledReply:
                        trouble.garbled.append(text)
                        deadline = min(deadline, time.monotonic() + self.timeout_s)
                if time.monotonic() > deadline:  # lines keep coming, none of them the 'ok'
                    trouble.silent += 1
                    break
        raise self._link_trouble(what, trouble, _COMMAND_TRIES, timeout_s)

    def _status_or_none(self, tries: int = STATUS_TRIES) -> GrblStatus | None:
        """A status report, or None if none comes (silent after ALARM:1/2, booting, or not a GRBL port)."""
        try:
            return self._status(tries=tries)
        except GarbledReply:
            return None
        except StageError:
            if not self.link.is_open:
                raise
            return None

    def _status(self, during: str = "", *, tries: int = STATUS_TRIES) -> GrblStatus:
        """Ask for a real-time status report ('?') and parse it; `during` names the command being waited on,
        for messages about alarms that arrive meanwhile.

        A garbled, cut-off or late report is asked for again, `tries` times in all, each within timeout_s:
        a USB-serial link next to stepper drivers garbles a byte now and then, and a '?' costs nothing.
        Alarms and errors that arrive meanwhile raise at once; only a link that stays bad ends the run."""
        trouble = _Trouble()
        asked = wco_waits = 0
        while asked < tries:
            self._drop_stale("'?'", during)
            self.link.write(b"?", "'?'")
            asked += 1
            deadline = time.monotonic() + self.timeout_s
            while True:
                try:
                    text = self.link.read_line(deadline, "'?'")
                except GarbledReply as e:
                    trouble.garbled.append(e.raw)
                    break
                if text is None:
                    if self.link.late:
                        trouble.late += 1
                    else:
                        trouble.silent += 1
                    break
                if text.startswith("<"):
                    status = self._parse_status(text)
                    if status is None:
                        trouble.garbled.append(text)
                        break
                    if math.isnan(status.x_mm) and wco_waits < _WCO_WAITS:
                        asked, wco_waits = asked - 1, wco_waits + 1  # WPos before any WCO: one comes within 30 reports
                        time.sleep(self.poll_s)
                        break
                    if math.isnan(status.x_mm):
                        raise self.link.error(
                            f"the controller reports work positions ($10={int(self.settings.get(10, 0))}) and sent no "
                            f"work offset (WCO) in {_WCO_WAITS} reports", "set $10=1 so reports give MPos")
                    return status
                if text != "ok":
                    try:
                        self._check_message(text, "'?'", during)
                    except GarbledReply:
                        trouble.garbled.append(text)
                        break
                if time.monotonic() > deadline:  # lines keep coming, none of them a status report
                    trouble.silent += 1
                    break
        raise self._link_trouble("'?'", trouble, tries)

    def _drop_stale(self, what: str, during: str = "") -> None:
        """Read what arrived unasked since the last reply: old status reports (late answers to an earlier '?')
        and stray 'ok's are dropped, alarms and errors among them raised."""
        while self.link.waiting:
            try:
                text = self.link.read_line(time.monotonic(), what)
            except GarbledReply:
                continue
            if text is None:
                return  # only the start of a line so far
            if text and not text.startswith("<") and text != "ok":
                try:
                    self._check_message(text, what, during)
                except GarbledReply:
                    pass

    def _parse_status(self, text: str) -> GrblStatus | None:
        """The report as a GrblStatus in mm (x NaN for WPos before any WCO), or None if it is garbled."""
        report = parse_status(text)
        if report is None:
            return None
        scale = 25.4 if int(self.settings.get(13, 0)) == 1 else 1.0  # $13=1: GRBL reports inches
        if report.wco is not None:
            self._wco_x = report.wco[0]
        x = report.position[0]
        if not report.machine:  # $10 bit 0 clear: WPos = MPos - WCO
            x = x + self._wco_x if self._wco_x is not None else math.nan
        x_mm = x * scale
        if abs(x_mm) > 1e6:
            return None  # no rail is a kilometre long
        if not math.isnan(x_mm):
            self._last_x_mm = x_mm
        return GrblStatus(report.state, x_mm, (report.feed or 0.0) * scale)

    def _link_trouble(self, what: str, trouble: "_Trouble", tries: int, timeout_s: float | None = None) -> StageError:
        """The error for a reply that never came clean: what was seen, and the fix that fits it."""
        if not trouble.garbled and not trouble.late:
            if self._alarm:
                return self.link.error(
                    f"controller silent after {self._alarm}: GRBL answers nothing, not even '?', until a reset",
                    "resume the run: homing sends the reset (Ctrl-X) first",
                )
            wait = self.timeout_s if timeout_s is None else timeout_s
            return self.link.error(f"no reply to {what} in {tries} tries of {wait:.1f} s", CABLE)
        seen = []
        if trouble.garbled:
            seen.append(f"{len(trouble.garbled)} garbled, the last {trouble.garbled[-1]!r}")
        if trouble.late:
            seen.append(f"{trouble.late} cut off or late")
        if trouble.silent:
            seen.append(f"{trouble.silent} unanswered")
        if trouble.garbled:
            fix = (f"the link corrupts bytes: check that baud={self.link.baud} matches the controller and that the "
                   "USB cable is short, shielded and away from the motor wiring")
        else:
            fix = ("replies come late: the controller or this computer is too busy; close other programs using the "
                   "port, or raise timeout_s in the device string")
        return self.link.error(f"no clean reply to {what} in {tries} tries ({'; '.join(seen)})", fix)

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
                fix = self._soft_limit_fix()
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

    def _position_lost(self) -> StageError:
        """The controller is in alarm when rig connects, with homing off on both sides: nothing can find
        rail zero again (GRBL powers up Idle with $22=0, so the alarm is from a reset while moving, a
        limit switch, or sleep, after which GRBL no longer vouches for MPos)."""
        return self.link.error(
            "the controller is in alarm from before (a reset while moving, a limit switch or sleep), so its "
            "machine position may be lost, and without homing (homing=0) rail zero cannot be found again",
            "put the carriage at rail zero by hand and switch the controller off and on (MPos restarts at 0 "
            "there), then resume; or fit home switches and use homing=1",
        )

    def _wait_idle(self, what: str, expected_s: float) -> GrblStatus:
        """Poll '?' until the motion has ended; stop the carriage before raising."""
        try:
            return self._poll_until_idle(what, expected_s)
        except StageError as e:
            if not self.link.is_open or self._alarm:
                raise
            raise StageError(f"{e}{self._stop_motion()}") from None

    def _hold(self, status: GrblStatus | None = None) -> str | None:
        """Feed hold ('!') and wait until the carriage is still: Hold:0 (the hold is complete), or a state
        without motion. The deadline is three times the deceleration from the current feed at $120, plus
        two reply times. None when still; else what was seen (and nothing more is sent)."""
        feed = status.feed_mm_min if status is not None and status.feed_mm_min > 0 else self.feed_mm_min
        accel = self.settings.get(120, 0.0) or 10.0
        deadline = time.monotonic() + 3.0 * (feed / 60.0) / accel + 2.0 * self.timeout_s + 1.0
        seen = "no status report came"
        while True:
            self.link.write(b"!", "a feed hold ('!')")  # again each time: a real-time byte can be lost too
            try:
                status = self._status("a feed hold ('!')")
            except GarbledReply as e:
                seen = f"its state could not be read ({e})"
            except StageError as e:
                if not self.link.is_open:
                    raise
                if "ALARM:" in str(e):
                    return None  # an alarm has stopped the motors
                seen = f"its state could not be read ({e})"
            else:
                if status.state == "Hold:0" or status.kind in ("Idle", "Alarm", "Check", "Sleep") \
                        or status.state in ("Door:0", "Door:1"):
                    return None
                seen = f"it still reported {status.state} at X {status.x_mm:.3f} mm"
            if time.monotonic() > deadline:
                return seen
            time.sleep(self.poll_s)

    def _stop_motion(self) -> str:
        """After an error during a move: a feed hold, then, once the hold is complete (Hold:0), a soft reset,
        which flushes the rest of the move and keeps the position (interface.md). Never a reset while the
        carriage may still move. Returns what was done, for the error message."""
        try:
            still = self._hold()
        except StageError:
            return "; the carriage could not be held (the port is gone)"
        if still is not None:
            return (f"; a feed hold was sent but {still}, so the controller was not reset (a reset while the "
                    "carriage moves loses the position); resuming stops it safely first")
        try:
            self._soft_reset()
        except StageError:
            return "; the carriage was held (feed hold) but no banner followed the reset after it"
        return "; the carriage was stopped (a feed hold, then a reset once the hold was complete: position kept)"

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
            kind = status.kind
            if kind == "Idle":
                idle_reports += 1
                if moved or idle_reports >= 2:
                    return status
            elif kind in ("Run", "Home", "Jog"):
                moved, idle_reports = True, 0
            elif kind == "Hold":
                if now - last_change > self.stall_s:
                    raise self.link.error(f"feed hold during {what} (X {status.x_mm:.3f} mm)",
                                          "someone pressed hold on the controller; resume the run to go on")
            elif kind == "Alarm":
                self._homed = False
                raise self.link.error(
                    f"controller in Alarm during {what}", f"check the rail and limit switches"
                )
            elif kind == "Door":
                raise self.link.error(f"safety door open during {what}", f"close it")
            elif kind in ("Check", "Sleep"):
                raise self.link.error(
                    f"controller in {kind} mode during {what}, nothing moves",
                    "leave it ($C toggles check mode; a reset wakes it from sleep)",
                )
            if kind == "Run" and now - last_change > self.stall_s:
                raise self.link.error(
                    f"stuck during {what}: X has stayed at {status.x_mm:.3f} mm for {now - last_change:.1f} s "
                    f"in state Run", "check the rail for obstruction and the motor wiring",
                )
            if now > deadline:
                raise self.link.error(
                    f"still moving {now - start:.1f} s after {what} (state {status.state}, X {status.x_mm:.3f} mm), "
                    f"though {expected_s:.1f} s should do at F{self.feed_mm_min:.0f} ($110={self.settings.get(110, 0):g}, "
                    f"$120={self.settings.get(120, 0):g})", "check the rail for obstruction and the controller's overrides",
                )
            time.sleep(self.poll_s)


@dataclass
class _Trouble:
    """What came instead of a clean reply, over the tries of one request."""

    garbled: list[bytes | str] = field(default_factory=list)
    late: int = 0
    silent: int = 0


def _grbl_error_fix(code: int) -> str:
    if code in (5, 10):
        return "enable homing on the controller ($22=1) or add homing=0 to the device string"
    if code == 9:
        return f"the controller is in alarm; re-home the stage"
    if code == 15:
        return "a jog beyond the soft limits ($20=1, $130); keep targets within the controller's travel"
    if code == 22:
        return "give a positive feed= in the device string"
    return "check the controller's settings ($$) and firmware (GRBL 1.1 expected)"


def open_grbl(spec: DeviceSpec, context: dict[str, Any]) -> Stage:
    """Factory for `grbl://PORT?...` (see drivers.registry)."""
    return GrblStage.from_spec(spec)
