"""Linear stages on a serial port: a GRBL 1.1 controller (G-code) and a Zaber stage (ASCII).

Device strings:

    grbl:///dev/ttyUSB0?baud=115200&offset_m=0.3&direction=1&feed=3000&settle=0.2&tolerance_mm=1&travel_mm=3000
    zaber:///dev/ttyUSB0?microstep_um=0.1905&offset_m=0.3&direction=1&settle=0.2&tolerance_mm=1

Both map the camera-to-wall distance to the rail the same way:
rail_mm = direction * (position_m - offset_m) * 1000, where offset_m is the distance when the
carriage is at rail zero (the home switch) and direction is +1 if moving away from home moves
the camera away from the wall, -1 otherwise.

Every failure raises `StageError` with one line, "<kind> <port>: <problem>; <what to do>";
docs/stages.md lists them all with causes and fixes.
"""

from __future__ import annotations

import errno
import os
import re
import time
from dataclasses import dataclass
from typing import Any

import serial

from rig.devices import DeviceSpec, register_stage

from .errors import StageError
from .stage import Stage

CABLE = "check the USB cable and that the controller is powered"

# --- GRBL 1.1 codes (gnea/grbl doc/csv) --------------------------------------------------------

GRBL_ERRORS = {
    1: "expected command letter",
    2: "bad number format",
    3: "invalid '$' statement",
    4: "negative value",
    5: "homing is not enabled ($22=0)",
    6: "step pulse shorter than 3 us",
    7: "EEPROM read failed, defaults restored",
    8: "'$' command only valid when idle",
    9: "G-code locked out during alarm or jog",
    10: "soft limits need homing enabled",
    11: "line too long",
    12: "step rate above 30 kHz",
    13: "safety door open",
    14: "line length exceeded",
    15: "jog target exceeds machine travel (soft limits)",
    16: "invalid jog command",
    17: "laser mode needs PWM output",
    20: "unsupported G-code command",
    21: "modal group violation",
    22: "feed rate undefined",
    23: "command needs an integer value",
    24: "more than one command needing axis words",
    25: "repeated G-code word",
    26: "no axis words for a command that needs them",
    27: "invalid line number",
    28: "missing value word",
    29: "G59.x work coordinates not supported",
    30: "G53 only allowed with G0 and G1",
    31: "axis words where none are used",
    32: "arc without in-plane axis words",
    33: "invalid motion target",
    34: "invalid arc radius",
    35: "arc without in-plane offset words",
    36: "unused value words",
    37: "G43.1 offset not on the tool-length axis",
    38: "tool number too large",
}

#: alarm code -> (meaning, what to do)
GRBL_ALARMS = {
    1: ("hard limit triggered, machine position lost",
        "free the carriage from the limit switch and clear the rail (the stage re-homes on resume)"),
    2: ("soft limit: target beyond the controller's travel ($130)",
        "make travel_mm match the controller's $130 or change the plan's stops"),
    3: ("reset while moving, machine position lost", "re-home the stage"),
    4: ("probe not in its expected initial state", "check the probe wiring"),
    5: ("probe did not make contact", "check the probe wiring"),
    6: ("homing failed: homing cycle was reset", "let homing finish before resetting"),
    7: ("homing failed: safety door opened", "close the door"),
    8: ("homing failed: pull-off did not clear the limit switch", "increase pull-off ($27) or check the switch wiring"),
    9: ("homing failed: limit switch not found within the search distance",
        "check the home switch wiring and $130 (max travel)"),
}

# --- Zaber ASCII codes -------------------------------------------------------------------------

ZABER_REJECTIONS = {
    "AGAIN": "device busy, try again",
    "BADAXIS": "no such axis",
    "BADCOMMAND": "command not understood or not supported by this device",
    "BADDATA": "value out of range or invalid (or the axis is not homed)",
    "BADMESSAGEID": "invalid message id",
    "BADSPLIT": "split command not understood",
    "DEVICEONLY": "command must go to the device, not an axis",
    "DRIVERDISABLED": "motor driver disabled",
    "FULL": "command buffer full",
    "INACTIVE": "axis or peripheral inactive",
    "LOCKSTEP": "axis is in lockstep",
    "NOACCESS": "access level too low",
    "NOTSUPPORTED": "not supported by this firmware",
    "PARKED": "axis is parked; unpark it",
    "REMOTE": "controlled remotely",
    "STATUSBUSY": "axis busy moving",
    "SYSTEMERROR": "system error, power-cycle the device",
}

ZABER_FLAGS = {
    "FF": "critical system error",
    "FV": "over- or under-voltage, driver disabled",
    "FD": "driver disabled",
    "FQ": "encoder error",
    "FT": "excessive twist",
    "FI": "index error",
    "FA": "analog encoder sync error",
    "FS": "stalled and stopped",
    "FB": "stream bounds error",
    "FP": "interpolated path deviation",
    "FE": "limit error",
    "FZ": "peripheral inactive (no stage connected to the controller?)",
    "FH": "hardware emergency stop",
    "FO": "driver disabled on startup or by command",
    "WL": "unexpected limit trigger",
    "WV": "voltage out of range",
    "WT": "controller temperature high",
    "WS": "stalled, recovered",
    "WM": "displaced when stationary",
    "WR": "no reference position (not homed)",
    "WH": "device not homed",
    "NC": "manual control",
    "NI": "movement interrupted",
    "ND": "stream discontinuity",
}


@dataclass(frozen=True)
class Rail:
    """How camera-to-wall distance maps to the controller's axis, in mm from rail zero."""

    offset_m: float
    direction: int
    min_mm: float
    max_mm: float

    def to_rail_mm(self, position_m: float) -> float:
        return self.direction * (position_m - self.offset_m) * 1000.0

    def to_position_m(self, rail_mm: float) -> float:
        return self.offset_m + self.direction * rail_mm / 1000.0

    @property
    def limits_m(self) -> tuple[float, float]:
        a, b = self.to_position_m(self.min_mm), self.to_position_m(self.max_mm)
        return (min(a, b), max(a, b))


class GarbledReply(StageError):
    """A reply that is not printable ASCII or not in the protocol (wrong baud, noise)."""


class SerialLine:
    """A serial port carrying lines of ASCII text; port failures become one-line StageErrors."""

    def __init__(self, kind: str, path: str, baud: int, timeout_s: float):
        self.kind, self.path, self.baud, self.timeout_s = kind, path, baud, timeout_s
        self.name = f"{kind} {path}"
        self._port: serial.Serial | None = None

    def error(self, problem: str, fix: str) -> StageError:
        return StageError(f"{self.name}: {problem}; {fix}")

    def open(self) -> None:
        try:
            exclusive = True if os.name == "posix" else None
            self._port = serial.Serial(self.path, self.baud, timeout=self.timeout_s, exclusive=exclusive)
        except (serial.SerialException, OSError) as e:
            raise self._open_error(e) from None

    def _open_error(self, e: Exception) -> StageError:
        code = getattr(e, "errno", None)
        if code in (errno.ENOENT, errno.ENXIO, errno.ENODEV):
            return self.error(
                "no such serial port",
                f"check the cable and `ls /dev/ttyUSB* /dev/ttyACM*`, or try without hardware: "
                f"run `rig stage-sim {self.kind}` and use the port it prints",
            )
        if code in (errno.EACCES, errno.EPERM):
            return self.error(
                "permission denied opening the port",
                "add yourself to the dialout group (`sudo usermod -aG dialout $USER`, then log in again)",
            )
        if code in (errno.EAGAIN, errno.EBUSY):
            return self.error(
                "port is in use by another program",
                "close it (G-code sender, Zaber Launcher, screen, minicom, another rig run) and retry",
            )
        return self.error(f"cannot open the port ({_one_line(e)})", "check the device path and the cable")

    def close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError):
                pass

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def _require(self) -> serial.Serial:
        if self._port is None:
            raise self.error("port is not open", "open the stage (use it as a context manager) before using it")
        return self._port

    def _disconnected(self, doing: str, e: Exception) -> StageError:
        self.close()
        return self.error(f"port disconnected while {doing} ({_one_line(e)})", f"{CABLE}")

    def write(self, data: bytes, what: str) -> None:
        port = self._require()
        try:
            port.write(data)
        except (serial.SerialException, OSError) as e:
            raise self._disconnected(f"sending {what}", e) from None

    def discard_input(self) -> None:
        port = self._require()
        try:
            port.reset_input_buffer()
        except (serial.SerialException, OSError) as e:
            raise self._disconnected("clearing the input", e) from None

    def read_line(self, deadline_s: float, what: str) -> str | None:
        """One line without its line end, or None if nothing arrived by deadline_s.
        Raises on a partial line or bytes that are not printable ASCII."""
        port = self._require()
        try:
            port.timeout = max(0.0, deadline_s - time.monotonic())
            raw = port.read_until(b"\n")
        except (serial.SerialException, OSError) as e:
            raise self._disconnected(f"waiting for the reply to {what}", e) from None
        if not raw:
            return None
        if not raw.endswith(b"\n"):
            raise self.garbled(raw, what)
        body = raw.rstrip(b"\r\n")
        if any(b < 0x20 or b > 0x7E for b in body):
            raise self.garbled(raw, what)
        return body.decode("ascii")

    def garbled(self, raw: bytes | str, what: str) -> StageError:
        shown = raw if isinstance(raw, str) else raw[:60]
        return GarbledReply(
            f"{self.name}: garbled reply {shown!r} to {what}; check that baud={self.baud} matches the controller "
            f"and that the cable is sound and away from motor wiring"
        )

    def no_reply(self, what: str, timeout_s: float) -> StageError:
        return self.error(f"no reply to {what} within {timeout_s:.1f} s", f"{CABLE}")


def _one_line(e: Exception) -> str:
    return " ".join(str(e).split())


def _require_port(spec: DeviceSpec) -> str:
    if not spec.path:
        raise StageError(
            f"device string {spec.text!r} names no serial port; write e.g. '{spec.kind}:///dev/ttyUSB0', "
            f"or run `rig stage-sim {spec.kind}` to get a simulated one"
        )
    return spec.path


def _direction(spec: DeviceSpec) -> int:
    direction = spec.int("direction", 1)
    if direction not in (1, -1):
        raise StageError(f"device {spec.text!r}: direction must be 1 or -1, not {direction}")
    return direction


def _positive(spec: DeviceSpec, key: str, default: float) -> float:
    value = spec.float(key, default)
    if not value > 0:
        raise StageError(f"device {spec.text!r}: {key} must be positive, not {value}")
    return value


# --- GRBL --------------------------------------------------------------------------------------------

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
            _require_port(spec),
            baud=spec.int("baud", 115200),
            offset_m=spec.float("offset_m", 0.3),
            direction=_direction(spec),
            feed_mm_min=_positive(spec, "feed", 3000.0),
            settle_s=spec.float("settle", 0.2),
            tolerance_mm=_positive(spec, "tolerance_mm", 1.0),
            travel_mm=_positive(spec, "travel_mm", 3000.0),
            rail_min_mm=spec.float("rail_min_mm", 0.0),
            homing=bool(spec.int("homing", 1)),
            timeout_s=_positive(spec, "timeout_s", 2.0),
            home_timeout_s=_positive(spec, "home_timeout_s", 120.0),
            poll_s=_positive(spec, "poll_s", 0.05),
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
                if line is None:
                    break
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


@register_stage("grbl")
def _grbl_stage(spec: DeviceSpec, world: Any) -> Stage:
    return GrblStage.from_spec(spec)


# --- Zaber -------------------------------------------------------------------------------------------

_ZABER_REPLY = re.compile(r"^@(\d+) (\d+) (?:(\d+) )?(OK|RJ) (IDLE|BUSY) (--|[A-Z]{2}) (\S.*)$")


@dataclass(frozen=True)
class ZaberReply:
    """One reply: accepted or not, BUSY/IDLE, the top warning flag ('--' for none), data."""

    rejected: bool
    busy: bool
    flag: str
    data: str


class ZaberStage(Stage):
    """A Zaber linear stage (one axis of one device) speaking the Zaber ASCII protocol.

    Positions on the device are microsteps of microstep_um from the home sensor; the travel
    is read from the device (limit.min, limit.max) when opened, and can be narrowed with
    travel_mm.
    """

    def __init__(
        self,
        path: str,
        *,
        baud: int = 115200,
        device: int = 1,
        axis: int = 1,
        microstep_um: float = 0.1905,
        offset_m: float = 0.3,
        direction: int = 1,
        settle_s: float = 0.2,
        tolerance_mm: float = 1.0,
        travel_mm: float | None = None,
        timeout_s: float = 2.0,
        home_timeout_s: float = 120.0,
        move_timeout_s: float = 60.0,
        poll_s: float = 0.05,
    ):
        self.link = SerialLine("zaber", path, baud, timeout_s)
        self.name = self.link.name
        self.device, self.axis = device, axis
        self.microstep_um = microstep_um
        self.offset_m, self.direction = offset_m, direction
        self.settle_s = settle_s
        self.tolerance_m = tolerance_mm / 1000.0
        self.travel_mm = travel_mm
        self.timeout_s = timeout_s
        self.home_timeout_s = home_timeout_s
        self.move_timeout_s = move_timeout_s
        self.poll_s = poll_s
        self.rail: Rail | None = Rail(offset_m, direction, 0.0, travel_mm) if travel_mm else None
        self._homed = False

    @classmethod
    def from_spec(cls, spec: DeviceSpec) -> "ZaberStage":
        travel_mm = spec.float("travel_mm", 0.0)
        return cls(
            _require_port(spec),
            baud=spec.int("baud", 115200),
            device=spec.int("device", 1),
            axis=spec.int("axis", 1),
            microstep_um=_positive(spec, "microstep_um", 0.1905),
            offset_m=spec.float("offset_m", 0.3),
            direction=_direction(spec),
            settle_s=spec.float("settle", 0.2),
            tolerance_mm=_positive(spec, "tolerance_mm", 1.0),
            travel_mm=travel_mm if travel_mm > 0 else None,
            timeout_s=_positive(spec, "timeout_s", 2.0),
            home_timeout_s=_positive(spec, "home_timeout_s", 120.0),
            move_timeout_s=_positive(spec, "move_timeout_s", 60.0),
            poll_s=_positive(spec, "poll_s", 0.05),
        )

    # --- Stage ------------------------------------------------------------------------------------

    @property
    def limits_m(self) -> tuple[float, float]:
        if self.rail is None:
            raise self.link.error(
                "travel limits are unknown until the stage is opened",
                "open it first, or add travel_mm= to the device string",
            )
        return self.rail.limits_m

    def open(self) -> None:
        self.link.open()
        self._homed = False
        try:
            self.link.discard_input()
            low = self._steps(self._request("get limit.min"), "get limit.min")
            high = self._steps(self._request("get limit.max"), "get limit.max")
        except StageError:
            self.link.close()
            raise
        min_mm, max_mm = low * self.microstep_um / 1000.0, high * self.microstep_um / 1000.0
        if self.travel_mm:
            max_mm = min(max_mm, self.travel_mm)
        self.rail = Rail(self.offset_m, self.direction, min_mm, max_mm)

    def close(self) -> None:
        self.link.close()

    def home(self) -> None:
        """Stop any motion left over, clear old warnings, home, and check the reference is set."""
        self.link.discard_input()
        self._request("stop")
        self._wait_idle("stop", self.move_timeout_s, homing=True, check_flags=False)
        self._request("warnings clear")
        self._request("home")
        reply = self._wait_idle("home", self.home_timeout_s, homing=True)
        if reply.flag in ("WR", "WH"):
            raise self.link.error(
                f"still no reference position after homing ({reply.flag})",
                "check the home sensor and cable, then home again",
            )
        self._homed = True

    def move_to(self, position_m: float) -> float:
        if not self._homed:
            raise self.link.error("not homed", "home the stage (the plan's home step) before moving")
        self.check_limits(position_m)
        steps = round(self._rail().to_rail_mm(position_m) * 1000.0 / self.microstep_um)
        command = f"move abs {steps}"
        self._request(command)
        self._wait_idle(command, self.move_timeout_s, homing=False)
        if self.settle_s > 0:
            time.sleep(self.settle_s)
        measured = self.position_m()
        self.check_arrived(position_m, measured)
        return measured

    def position_m(self) -> float:
        steps = self._steps(self._request("get pos"), "get pos")
        return self._rail().to_position_m(steps * self.microstep_um / 1000.0)

    def describe(self) -> dict[str, Any]:
        return {
            **super().describe(),
            "driver": "zaber", "port": self.link.path, "baud": self.link.baud,
            "device": self.device, "axis": self.axis, "microstep_um": self.microstep_um,
            "offset_m": self.offset_m, "direction": self.direction, "settle_s": self.settle_s,
        }

    # --- protocol ---------------------------------------------------------------------------------

    def _rail(self) -> Rail:
        if self.rail is None:
            raise self.link.error("port is not open", "open the stage before using it")
        return self.rail

    def _request(self, command: str) -> ZaberReply:
        """Send '/<device> <axis> <command>' and return its reply; raise if rejected."""
        text = f"/{self.device} {self.axis} {command}"
        what = repr(text)
        self.link.write(text.encode("ascii") + b"\n", what)
        deadline = time.monotonic() + self.timeout_s
        while True:
            line = self.link.read_line(deadline, what)
            if line is None:
                raise self.link.error(
                    f"no reply to {what} within {self.timeout_s:.1f} s",
                    f"{CABLE}, that it speaks ASCII at baud={self.link.baud} and is device {self.device}",
                )
            if not line or line[0] in "#!":
                continue  # info and alert messages
            match = _ZABER_REPLY.match(line)
            if not match or int(match.group(1)) != self.device or int(match.group(2)) != self.axis:
                raise self.link.garbled(line, what)
            reply = ZaberReply(match.group(4) == "RJ", match.group(5) == "BUSY", match.group(6), match.group(7))
            if reply.rejected:
                raise self._rejection(reply, what)
            return reply

    def _rejection(self, reply: ZaberReply, what: str) -> StageError:
        if reply.flag in ("WR", "WH"):
            self._homed = False
            return self.link.error(
                f"{what} rejected: no reference position ({reply.flag})", "home the stage "
            )
        meaning = ZABER_REJECTIONS.get(reply.data, "unknown reason")
        fix = ("check microstep_um and offset_m against the stage's travel (limit.max)"
               if reply.data == "BADDATA" else "check the device and axis numbers and the firmware")
        return self.link.error(f"{what} rejected: {reply.data} ({meaning})", fix)

    def _steps(self, reply: ZaberReply, command: str) -> int:
        try:
            return int(reply.data)
        except ValueError:
            raise self.link.garbled(reply.data, repr(command)) from None

    def _wait_idle(self, what: str, timeout_s: float, *, homing: bool, check_flags: bool = True) -> ZaberReply:
        """Poll 'get pos' until the axis is IDLE; raise on fault or interruption flags."""
        deadline = time.monotonic() + timeout_s
        while True:
            reply = self._request("get pos")
            if check_flags:
                self._check_flag(reply.flag, what, homing=homing)
            if not reply.busy:
                return reply
            if time.monotonic() > deadline:
                raise self.link.error(
                    f"still moving {timeout_s:.1f} s after {what!r}",
                    f"check the rail for obstruction and the stage's speed setting",
                )
            time.sleep(self.poll_s)

    def _check_flag(self, flag: str, what: str, *, homing: bool) -> None:
        meaning = ZABER_FLAGS.get(flag, "unknown flag")
        if flag.startswith("F"):
            self._homed = False
            raise self.link.error(
                f"stage fault {flag} ({meaning}) during {what!r}",
                f"clear the rail, check the load and power supply (homing clears the fault)",
            )
        if flag == "WL":
            raise self.link.error(
                f"unexpected limit trigger (WL) during {what!r}",
                f"check the limit sensor and that offset_m and travel fit the rail",
            )
        if flag == "NI":
            raise self.link.error(
                f"movement interrupted (NI) during {what!r}",
                f"make sure nothing else (knob, Zaber Launcher) commands the stage",
            )
        if flag in ("WR", "WH") and not homing:
            self._homed = False
            raise self.link.error(f"lost its reference position ({flag}) during {what!r}", "home the stage ")


@register_stage("zaber")
def _zaber_stage(spec: DeviceSpec, world: Any) -> Stage:
    return ZaberStage.from_spec(spec)
