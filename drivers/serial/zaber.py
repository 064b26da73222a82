"""A Zaber linear stage (one axis of one device) speaking the Zaber ASCII protocol. Stage kind `zaber`.

    zaber:///dev/ttyUSB0?microstep_um=0.1905&offset_m=0.3&direction=1&settle=0.2&tolerance_mm=1

Every failure raises `StageError` with one line, "zaber <port>: <problem>; <what to do>";
docs/stages.md lists them all with causes and fixes.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import Any

from ..errors import StageError
from ..registry import DeviceSpec
from ..stage import Stage
from .line import CABLE, SerialLine
from .rail import Rail, direction_option, positive_option, require_port
from .zaber_codes import ZABER_FLAGS, ZABER_REJECTIONS

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
            require_port(spec),
            baud=spec.int("baud", 115200),
            device=spec.int("device", 1),
            axis=spec.int("axis", 1),
            microstep_um=positive_option(spec, "microstep_um", 0.1905),
            offset_m=spec.float("offset_m", 0.3),
            direction=direction_option(spec),
            settle_s=spec.float("settle", 0.2),
            tolerance_mm=positive_option(spec, "tolerance_mm", 1.0),
            travel_mm=travel_mm if travel_mm > 0 else None,
            timeout_s=positive_option(spec, "timeout_s", 2.0),
            home_timeout_s=positive_option(spec, "home_timeout_s", 120.0),
            move_timeout_s=positive_option(spec, "move_timeout_s", 60.0),
            poll_s=positive_option(spec, "poll_s", 0.05),
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
            if line is None or (time.monotonic() > deadline and (not line or line[0] in "#!")):
                raise self.link.error(
                    f"no reply to {what} within {self.timeout_s:.1f} s",
                    f"{CABLE}, that it speaks ASCII at baud={self.link.baud} and is device {self.device}",
                )
            if not line or line[0] in "#!":
                continue  # info and alert messages (until the deadline: a port that streams them must not hang us)
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


def open_zaber(spec: DeviceSpec, context: dict[str, Any]) -> Stage:
    """Factory for `zaber://PORT?...` (see drivers.registry)."""
    return ZaberStage.from_spec(spec)
