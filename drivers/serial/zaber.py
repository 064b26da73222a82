"""A Zaber linear stage (one axis of one device) speaking the Zaber ASCII protocol. Stage kind `zaber`.

    zaber:///dev/ttyUSB0?microstep_um=0.1905&offset_m=0.3&direction=1&settle=0.2&tolerance_mm=1

`microstep_um` is the datasheet's "microstep size (default resolution)", i.e. at resolution 64; the
driver reads the device's `resolution` at open and scales it (a stage set to resolution 128 moves
half as far per microstep). The device's identity (`deviceid`, `system.serial`, `version`) is read at
open, recorded by `describe()`, and checked against `deviceid=` when the device string pins it.
Every command carries a message id and a checksum (Zaber ASCII protocol manual, "Message IDs" and
"Checksums"); a reply must echo the id, and a reply's checksum, when the device adds one
(`comm.checksum 1`), is verified. A reply shows only its most urgent warning flag, so when it shows
one the driver reads `warnings` to see them all.

Every failure raises `StageError` with one line, "zaber <port>: <problem>; <what to do>";
docs/stages.md lists them all with causes and fixes.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from ..errors import StageError
from ..registry import DeviceSpec
from ..stage import Stage
from .line import CABLE, SerialLine
from .rail import ZABER_OPTIONS, Rail, require_port
from .zaber_codes import ZABER_FLAGS, ZABER_REJECTIONS

_ZABER_REPLY = re.compile(r"^@(\d+) (\d+) (?:(\d+) )?(OK|RJ) (IDLE|BUSY) (--|[A-Z]{2}) (\S[^:]*?)(?::([0-9A-Fa-f]{2}))?$")
#: the resolution a datasheet's microstep size refers to
DEFAULT_RESOLUTION = 64


def checksum(body: str) -> str:
    """Zaber ASCII checksum of the text between the start character and the colon: the two's complement of the
    byte sum, two hex digits (Zaber ASCII protocol manual, "Checksums")."""
    return f"{(-sum(body.encode('ascii'))) & 0xFF:02X}"


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
        device_id: int | None = None,
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
        #: the datasheet's microstep at resolution 64; `microstep_um` is the device's, once its resolution is read
        self.datasheet_microstep_um = microstep_um
        self.microstep_um = microstep_um
        self.expected_device_id = device_id
        self.identity: dict[str, str] = {}
        self._message_id = 0
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
        o = spec.take(ZABER_OPTIONS)  # the options, their defaults and checks: drivers/serial/rail.py
        return cls(
            require_port(spec),
            baud=o["baud"],
            device=o["device"],
            axis=o["axis"],
            microstep_um=o["microstep_um"],
            device_id=o["deviceid"],
            offset_m=o["offset_m"],
            direction=o["direction"],
            settle_s=o["settle"],
            tolerance_mm=o["tolerance_mm"],
            travel_mm=o["travel_mm"],
            timeout_s=o["timeout_s"],
            home_timeout_s=o["home_timeout_s"],
            move_timeout_s=o["move_timeout_s"],
            poll_s=o["poll_s"],
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
            self._read_identity()
            low = self._steps(self._request("get limit.min"), "get limit.min")
            high = self._steps(self._request("get limit.max"), "get limit.max")
        except StageError:
            self.link.close()
            raise
        min_mm, max_mm = low * self.microstep_um / 1000.0, high * self.microstep_um / 1000.0
        if self.travel_mm:
            max_mm = min(max_mm, self.travel_mm)
        self.rail = Rail(self.offset_m, self.direction, min_mm, max_mm)

    def _read_identity(self) -> None:
        """Read who the device is and its resolution; set the microstep from the resolution; check deviceid=."""
        self.identity = {name: self._request(f"get {name}", axis=0).data
                         for name in ("deviceid", "system.serial", "version")}
        resolution = self._steps(self._request("get resolution"), "get resolution")
        if resolution <= 0:
            raise self.link.garbled(str(resolution), "'get resolution'")
        self.identity["resolution"] = str(resolution)
        self.microstep_um = self.datasheet_microstep_um * DEFAULT_RESOLUTION / resolution
        if self.expected_device_id is not None and self.identity["deviceid"] != str(self.expected_device_id):
            raise self.link.error(
                f"device {self.device} is deviceid {self.identity['deviceid']} (serial {self.identity['system.serial']}), "
                f"not deviceid {self.expected_device_id} as the device string says",
                "check which stage is on this port, or correct deviceid= (and microstep_um= with it)",
            )

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
            self.link.clock.sleep(self.settle_s)
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
            "datasheet_microstep_um": self.datasheet_microstep_um,
            **{f"device_{k.replace('.', '_')}": v for k, v in self.identity.items()},
            "offset_m": self.offset_m, "direction": self.direction, "settle_s": self.settle_s,
        }

    # --- protocol ---------------------------------------------------------------------------------

    def _rail(self) -> Rail:
        if self.rail is None:
            raise self.link.error("port is not open", "open the stage before using it")
        return self.rail

    def _request(self, command: str, *, axis: int | None = None) -> ZaberReply:
        """Send '/<device> <axis> <id> <command>:<checksum>' and return its reply; raise if rejected."""
        axis = self.axis if axis is None else axis
        self._message_id = (self._message_id + 1) % 100
        body = f"{self.device} {axis} {self._message_id:02d} {command}"
        what = repr(f"/{self.device} {axis} {command}")
        self.link.write(f"/{body}:{checksum(body)}\n".encode("ascii"), what)
        deadline = self.link.clock.monotonic() + self.timeout_s
        while True:
            line = self.link.read_line(deadline, what)
            if line is None or (self.link.clock.monotonic() > deadline and (not line or line[0] in "#!")):
                raise self.link.error(
                    f"no reply to {what} within {self.timeout_s:.1f} s",
                    f"{CABLE}, that it speaks ASCII at baud={self.link.baud} and is device {self.device}",
                )
            if not line or line[0] in "#!":
                continue  # info and alert messages (until the deadline: a port that streams them must not hang us)
            match = _ZABER_REPLY.match(line)
            if not match or int(match.group(1)) != self.device or int(match.group(2)) != axis:
                raise self.link.garbled(line, what)
            if match.group(8) is not None and match.group(8).upper() != checksum(line[1:line.rindex(":")]):
                raise self.link.garbled(line, what)
            if match.group(3) is not None and int(match.group(3)) != self._message_id:
                continue  # a late reply to an earlier command (it timed out): not this one's
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
        deadline = self.link.clock.monotonic() + timeout_s
        while True:
            reply = self._request("get pos")
            if check_flags and reply.flag != "--" and not (homing and reply.flag in ("WR", "WH")):
                for flag in self._all_flags(reply.flag):
                    self._check_flag(flag, what, homing=homing)
            if not reply.busy:
                return reply
            if self.link.clock.monotonic() > deadline:
                raise self.link.error(
                    f"still moving {timeout_s:.1f} s after {what!r}",
                    f"check the rail for obstruction and the stage's speed setting",
                )
            self.link.clock.sleep(self.poll_s)

    def _all_flags(self, top: str) -> list[str]:
        """Every warning flag now set (a reply shows only the most urgent), most urgent first."""
        words = self._request("warnings").data.split()
        flags = [w for w in words[1:] if len(w) == 2 and w.isalpha()]
        return flags if top in flags else [top, *flags]

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
