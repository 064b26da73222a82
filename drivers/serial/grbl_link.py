"""The GRBL 1.1 protocol on a serial line, for a driver that does not trust the line to be clean.

A USB-serial cable next to stepper drivers garbles a byte now and then, and a busy computer or controller
sends a line end late. So a garbled, cut-off or late status report is asked for again (STATUS_TRIES in all),
and a line whose reply came garbled or not at all is sent once more (every line the stage driver sends is
idempotent); a late line end is joined to the start that came in time (`SerialLine`). Only a link that stays
bad is an error, and its message says what came instead and the fix for that.

`GrblLink` also keeps what the controller told it that a driver must not forget: the firmware version, the
settings (`$$`) and build options (`$I`), the work offset (WCO, for $10 without MPos), the last alarm (GRBL is
silent after ALARM:1/2 until a reset) and whether an alarm or a reset has made the position untrustworthy.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from ..errors import StageError
from .grbl_codes import GRBL_ALARMS, GRBL_ERRORS
from .grbl_machine import travel_note
from .grbl_status import parse_status
from .line import CABLE, Clock, GarbledReply, SerialLine

_BANNER = re.compile(r"^Grbl (\S+) \[.*\]$")
#: `$$` lines as GRBL prints them (report.c): anything else in its reply is a garbled line
SETTING_LINE = re.compile(r"\$\d+=-?\d+(?:\.\d+)?")
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



class GrblLink:
    """One GRBL 1.1 controller on a serial port: lines and real-time bytes out, checked replies in."""

    def __init__(self, path: str, baud: int, timeout_s: float, poll_s: float):
        self.line = SerialLine("grbl", path, baud, timeout_s)
        self.name = self.line.name
        self.timeout_s, self.poll_s = timeout_s, poll_s
        self.firmware = ""
        self.settings: dict[int, float] = {}
        self.options = ""
        #: the last alarm seen: GRBL is silent after ALARM:1/2, and resets itself after a homing alarm ("reset")
        self.alarm = ""
        #: an alarm or an unexpected reset has made the machine position untrustworthy (until homed again)
        self.position_lost = False
        #: what to do about a soft-limit alarm (the stage knows its rail)
        self.soft_limit_fix = "keep the targets within the controller's travel ($130)"
        #: the last X machine position read, mm
        self.last_x_mm: float | None = None
        self._wco_x: float | None = None  # the work offset of X from the last report with WCO, controller units

    # --- the port ---------------------------------------------------------------------------------------

    @property
    def path(self) -> str:
        return self.line.path

    @property
    def clock(self) -> Clock:
        """The line's clock (`SerialLine.clock`): every deadline and wait of the driver reads it."""
        return self.line.clock

    @property
    def baud(self) -> int:
        return self.line.baud

    @property
    def is_open(self) -> bool:
        return self.line.is_open

    def open(self) -> None:
        self.line.open()

    def close(self) -> None:
        self.line.close()

    def error(self, problem: str, fix: str) -> StageError:
        return self.line.error(problem, fix)

    def write(self, data: bytes, what: str) -> None:
        self.line.write(data, what)

    def discard_input(self) -> None:
        self.line.discard_input()

    # --- the protocol -----------------------------------------------------------------------------------

    def query(self, line: str, shape: re.Pattern[str] | None = None) -> list[str]:
        """Send a $ command; the lines before its 'ok'. A reply with a garbled or cut-off line (or a `$` line
        not of `shape`) is asked for once more, whole."""
        what = repr(line)
        trouble = _Trouble()
        for _ in range(_COMMAND_TRIES):
            self.drop_stale(what)
            self.line.write(line.encode("ascii") + b"\n", what)
            deadline = self.clock.monotonic() + self.timeout_s
            out: list[str] = []
            clean = True
            while True:
                try:
                    text = self.line.read_line(deadline, what)
                except GarbledReply as e:
                    trouble.garbled.append(e.raw)
                    clean = False
                    continue
                if text is None:
                    if self.line.late:
                        trouble.late += 1
                    elif clean:
                        raise self.line.no_reply(what, self.timeout_s)
                    break
                if text == "ok":
                    if clean:
                        return out
                    break
                if text.startswith("$") and (shape is None or shape.fullmatch(text)) or text.startswith("["):
                    out.append(text)
                elif not text.startswith("<"):  # a status report answering an earlier '?' is passed over
                    try:
                        self.check_message(text, what)
                    except GarbledReply:
                        trouble.garbled.append(text)
                        clean = False
        raise self.link_trouble(what, trouble, _COMMAND_TRIES)

    def soft_reset(self) -> None:
        """Wake the controller, send Ctrl-X and wait for the 'Grbl 1.1h [...]' banner.
        Tries twice: a board that resets when the port opens ignores bytes while it boots."""
        self.line.write(b"\r\n\r\n", "the wake-up")
        seen: list[str] = []
        for _ in range(2):
            self.line.discard_input()
            self.line.write(b"\x18", "a soft reset (Ctrl-X)")
            deadline = self.clock.monotonic() + self.timeout_s
            while True:
                try:
                    line = self.line.read_line(deadline, "a soft reset (Ctrl-X)")
                except GarbledReply:
                    seen.append("garbled bytes")
                    continue
                if line is None or self.clock.monotonic() > deadline:
                    break  # silence, or a port that streams without ever sending the banner: the deadline holds
                match = _BANNER.match(line)
                if match:
                    self.firmware = match.group(1)
                    self.alarm = ""
                    self._wco_x = None  # a reset clears G92, so the work offset may have changed
                    return
                if line:
                    seen.append(line)
        got = f" (got {seen[-1]!r})" if seen else " (got nothing)"
        raise self.line.error(
            f"no GRBL banner within {2 * self.timeout_s:.1f} s of a soft reset{got}",
            f"check that this port is the GRBL controller, that baud={self.line.baud} matches it, and {CABLE}",
        )

    def command(self, line: str, timeout_s: float, *, during: str = "") -> None:
        """Send one line and wait for its 'ok'. If nothing, or a garbled or cut-off line, came where the 'ok'
        should be, the line is sent once more: every line this driver sends is idempotent (absolute moves in
        machine coordinates, $X, $H, modal G-codes), so a second copy of one already accepted changes nothing."""
        what = repr(line)
        trouble = _Trouble()
        for _ in range(_COMMAND_TRIES):
            self.line.write(line.encode("ascii") + b"\n", what)
            deadline = self.clock.monotonic() + timeout_s
            while True:
                try:
                    text = self.line.read_line(deadline, what)
                except GarbledReply as e:
                    trouble.garbled.append(e.raw)
                    deadline = min(deadline, self.clock.monotonic() + self.timeout_s)  # that may have been the 'ok'
                    continue
                if text is None:
                    if self.line.late:
                        trouble.late += 1
                    else:
                        trouble.silent += 1
                    break
                if text == "ok":
                    return
                if not text.startswith("<"):  # a status report answering an earlier '?' is passed over
                    try:
                        self.check_message(text, what, during)
                    except GarbledReply:
                        trouble.garbled.append(text)
                        deadline = min(deadline, self.clock.monotonic() + self.timeout_s)
                if self.clock.monotonic() > deadline:  # lines keep coming, none of them the 'ok'
                    trouble.silent += 1
                    break
        raise self.link_trouble(what, trouble, _COMMAND_TRIES, timeout_s)

    def status_or_none(self, tries: int = STATUS_TRIES) -> GrblStatus | None:
        """A status report, or None if none comes (silent after ALARM:1/2, booting, or not a GRBL port)."""
        try:
            return self.status(tries=tries)
        except GarbledReply:
            return None
        except StageError:
            if not self.line.is_open:
                raise
            return None

    def status(self, during: str = "", *, tries: int = STATUS_TRIES) -> GrblStatus:
        """Ask for a real-time status report ('?') and parse it; `during` names the command being waited on,
        for messages about alarms that arrive meanwhile.

        A garbled, cut-off or late report is asked for again, `tries` times in all, each within timeout_s:
        a USB-serial link next to stepper drivers garbles a byte now and then, and a '?' costs nothing.
        Alarms and errors that arrive meanwhile raise at once; only a link that stays bad ends the run."""
        trouble = _Trouble()
        asked = wco_waits = 0
        while asked < tries:
            self.drop_stale("'?'", during)
            self.line.write(b"?", "'?'")
            asked += 1
            deadline = self.clock.monotonic() + self.timeout_s
            while True:
                try:
                    text = self.line.read_line(deadline, "'?'")
                except GarbledReply as e:
                    trouble.garbled.append(e.raw)
                    break
                if text is None:
                    if self.line.late:
                        trouble.late += 1
                    else:
                        trouble.silent += 1
                    break
                if text.startswith("<"):
                    status = self.parse_status(text)
                    if status is None:
                        trouble.garbled.append(text)
                        break
                    if math.isnan(status.x_mm) and wco_waits < _WCO_WAITS:
                        asked, wco_waits = asked - 1, wco_waits + 1  # WPos before any WCO: one comes within 30 reports
                        self.clock.sleep(self.poll_s)
                        break
                    if math.isnan(status.x_mm):
                        raise self.line.error(
                            f"the controller reports work positions ($10={int(self.settings.get(10, 0))}) and sent no "
                            f"work offset (WCO) in {_WCO_WAITS} reports", "set $10=1 so reports give MPos")
                    return status
                if text != "ok":
                    try:
                        self.check_message(text, "'?'", during)
                    except GarbledReply:
                        trouble.garbled.append(text)
                        break
                if self.clock.monotonic() > deadline:  # lines keep coming, none of them a status report
                    trouble.silent += 1
                    break
        raise self.link_trouble("'?'", trouble, tries)

    def drop_stale(self, what: str, during: str = "") -> None:
        """Read what arrived unasked since the last reply: old status reports (late answers to an earlier '?')
        and stray 'ok's are dropped, alarms and errors among them raised."""
        while self.line.waiting:
            try:
                text = self.line.read_line(self.clock.monotonic(), what)
            except GarbledReply:
                continue
            if text is None:
                return  # only the start of a line so far
            if text and not text.startswith("<") and text != "ok":
                try:
                    self.check_message(text, what, during)
                except GarbledReply:
                    pass

    def parse_status(self, text: str) -> GrblStatus | None:
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
            self.last_x_mm = x_mm
        return GrblStatus(report.state, x_mm, (report.feed or 0.0) * scale)

    def link_trouble(self, what: str, trouble: "_Trouble", tries: int, timeout_s: float | None = None) -> StageError:
        """The error for a reply that never came clean: what was seen, and the fix that fits it."""
        if not trouble.garbled and not trouble.late:
            if self.alarm:
                return self.line.error(
                    f"controller silent after {self.alarm}: GRBL answers nothing, not even '?', until a reset",
                    "resume the run: homing sends the reset (Ctrl-X) first",
                )
            wait = self.timeout_s if timeout_s is None else timeout_s
            return self.line.error(f"no reply to {what} in {tries} tries of {wait:.1f} s", CABLE)
        seen = []
        if trouble.garbled:
            seen.append(f"{len(trouble.garbled)} garbled, the last {trouble.garbled[-1]!r}")
        if trouble.late:
            seen.append(f"{trouble.late} cut off or late")
        if trouble.silent:
            seen.append(f"{trouble.silent} unanswered")
        if trouble.garbled:
            fix = (f"the link corrupts bytes: check that baud={self.line.baud} matches the controller and that the "
                   "USB cable is short, shielded and away from the motor wiring")
        else:
            fix = ("replies come late: the controller or this computer is too busy; close other programs using the "
                   "port, or raise timeout_s in the device string")
        return self.line.error(f"no clean reply to {what} in {tries} tries ({'; '.join(seen)})", fix)

    def check_message(self, text: str, what: str, during: str = "") -> None:
        """Pass over push messages; raise on errors, alarms, resets and anything unrecognised."""
        if not text or text.startswith("[") or re.match(r"^\$\d+=", text) or text.startswith(">"):
            return  # [MSG:...], [GC:...], settings, and startup lines run after a reset (>G20:ok)
        if text.startswith("error:") and text[6:].isdigit():
            code = int(text[6:])
            raise Refused(str(self.line.error(
                f"controller answered {text} ({GRBL_ERRORS.get(code, 'unknown error')}) to {what}",
                _grbl_error_fix(code),
            )))
        if text.startswith("ALARM:") and text[6:].isdigit():
            code = int(text[6:])
            self.position_lost = True
            self.alarm = text if code in (1, 2) else ""
            if code in (6, 7, 8, 9):
                self.alarm = "reset"  # a homing alarm resets the controller: its banner follows
            meaning, fix = GRBL_ALARMS.get(code, ("unknown alarm", "check the controller"))
            if code == 2:
                meaning += travel_note(self.settings, self.options)
                fix = self.soft_limit_fix
            raise ControllerAlarm(str(self.line.error(f"{text} during {during or what} ({meaning})", f"{fix}")))
        if _BANNER.match(text):
            if self.alarm == "reset":
                self.alarm = ""
                return  # the reset that follows a homing alarm, already reported
            self.position_lost = True
            raise self.line.error(
                f"controller reset unexpectedly during {what} (banner {text!r}), position lost",
                f"check its power supply and the USB cable",
            )
        raise self.line.garbled(text, what)


class Refused(StageError):
    """The controller answered a line with error:N: the line was not executed."""


class ControllerAlarm(StageError):
    """The controller raised ALARM:N (and stopped the motors itself)."""


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


