"""A simulated Zaber stage speaking the Zaber ASCII protocol, on a pseudo-terminal.

One device (number `device`, default 1) with one axis. Commands look like
`/1 1 move abs 5249344` and every command gets one reply such as `@01 1 OK BUSY -- 0`,
`@01 1 OK IDLE WR 15748031` or `@01 1 RJ IDLE -- BADDATA`: device, axis, OK/RJ, BUSY/IDLE,
the highest-priority warning flag (`--` for none), then data. Positions are in microsteps.

What it follows of the Zaber ASCII protocol manual (firmware 7), feature by feature:
- message format `/[device] [axis] [id] command[:CC]`: device 0 (or none) is every device, axis 0
  (or none) the device itself; an optional message id 0-99 is echoed in the reply
  (`@01 1 07 OK IDLE -- 0`); an optional checksum `:CC` (two hex digits, the two's complement of the
  byte sum of everything between `/` and `:`) is checked, and a message whose checksum is wrong is
  dropped without a reply (what a real device does with one could not be checked offline; dropping
  is the harder case for a driver, which then sees no reply); with `comm.checksum 1` the device appends
  a checksum to its own messages. The official zaber-motion library sends checksums by default.
- replies carry only the highest-priority warning flag; `warnings` lists them all (`04 FS NI WR ...`)
- `get <setting>` and `set <setting> <value>` for the settings in `_SETTINGS`: identity
  (`deviceid`, `system.serial`, `version`, `version.build`, `system.axiscount`, `peripheralid`),
  `resolution` (microsteps per full step; the microstep is `step_um / resolution`), `limit.min`,
  `limit.max`, `maxspeed`, `accel`, `comm.alert`, `comm.checksum`, `comm.packet.size.max`; read-only
  ones answer `BADCOMMAND` to `set`, out-of-range values `BADDATA`
- with `comm.alert 1`, an alert `!01 1 IDLE --` when an axis comes to rest
- until homed the axis carries WR (no reference position) and `move abs` is rejected

Until homed the axis carries the WR flag (no reference position) and absolute moves are
rejected. Faults for tests, via `inject()`: drop_reply, noise, unplug, position_error
(mm=...), and stall (the next move stops half-way with the FS fault flag); `power_cycle()`
restarts the device, which then has no reference position.
"""

from __future__ import annotations

import time

from .pty_controller import COMMON_FAULTS, Carriage, PtyController

#: warning flags in the order the device reports them: faults, then warnings, then notices
_FLAG_PRIORITY = ("FF", "FS", "FT", "FQ", "FD", "FZ", "FE", "WL", "WV", "WT", "WM", "WR", "WH", "NI", "NC", "ND")
#: settings `get` answers, and whether `set` may write them (the rest are computed in `_get`)
_SETTINGS = {
    "deviceid": False, "system.serial": False, "version": False, "version.build": False,
    "system.axiscount": False, "peripheralid": False, "comm.packet.size.max": False, "limit.min": True,
    "limit.max": True, "maxspeed": True, "accel": True, "resolution": True, "comm.alert": True,
    "comm.checksum": True, "pos": True, "system.access": True,
}
#: device-scope settings: one value, whatever the axis
_DEVICE_SCOPE = {"deviceid", "system.serial", "version", "version.build", "system.axiscount", "comm.packet.size.max",
                 "comm.alert", "comm.checksum", "system.access"}


def checksum(body: str) -> str:
    """The Zaber ASCII checksum of a message body (between the start character and the colon): two hex digits."""
    return f"{(-sum(body.encode('ascii'))) & 0xFF:02X}"


class ZaberSim(PtyController):
    """A Zaber linear stage (one axis) on a rail from 0 to travel_mm."""

    kind = "zaber"
    faults = COMMON_FAULTS + ("stall",)

    def __init__(
        self,
        *,
        travel_mm: float = 3000.0,
        microstep_um: float = 0.1905,
        speed_mm_s: float = 2000.0,
        start_mm: float = 1200.0,
        device: int = 1,
        resolution: int = 64,
        device_id: int = 50081,
        serial: int = 1234567,
        seed: int = 0,
    ):
        """microstep_um: the microstep at the default resolution 64 (as datasheets give it); with another
        `resolution` the device's microstep is microstep_um * 64 / resolution."""
        super().__init__(seed=seed)
        self.carriage = Carriage(travel_mm, speed_mm_s, start_mm)
        self.step_um = microstep_um * 64
        self.resolution = resolution
        self.device = device
        self.device_id, self.serial = device_id, serial
        self.alerts = False
        self.checksums = False
        self.accel = 205
        #: device position = carriage position - origin; arbitrary until homed
        self.origin_mm = start_mm
        self.homed = False
        self.homing = False
        self.flags: set[str] = {"WR"}
        self._buffer = bytearray()

    @property
    def microstep_um(self) -> float:
        return self.step_um / self.resolution

    @property
    def limit_max_steps(self) -> int:
        return int(self.carriage.travel_mm * 1000.0 / self.microstep_um)

    def position_steps(self, now_s: float) -> int:
        return round((self.carriage.position_mm(now_s) - self.origin_mm) * 1000.0 / self.microstep_um)

    # --- bytes in ---------------------------------------------------------------------------

    def handle_bytes(self, data: bytes, now_s: float) -> None:
        for byte in data:
            if byte in (0x0A, 0x0D):
                line, self._buffer = self._buffer.decode("ascii", "replace").strip(), bytearray()
                if line:
                    self._execute(line, now_s)
            else:
                self._buffer.append(byte)

    def _execute(self, line: str, now_s: float) -> None:
        if not line.startswith("/"):
            return  # devices ignore anything that is not a command
        if self.drop_command(line):
            return
        body = line[1:]
        if ":" in body:
            body, given = body.rsplit(":", 1)
            if given.strip().upper() != checksum(body):
                return  # a corrupted message: dropped
        tokens = body.split()
        device = axis = 0
        message_id = None
        if tokens and tokens[0].isdigit():
            device = int(tokens.pop(0))
            if tokens and tokens[0].isdigit():
                axis = int(tokens.pop(0))
                if tokens and tokens[0].isdigit():
                    message_id = int(tokens.pop(0))
        if device not in (0, self.device):
            return
        reply = _Reply(self, axis, message_id)
        if message_id is not None and not 0 <= message_id <= 99:
            reply.send("BADMESSAGEID", rejected=True)
            return
        if axis not in (0, 1):
            reply.send("BADAXIS", rejected=True)
            return
        self._command(tokens, reply, now_s)

    def _command(self, tokens: list[str], reply: "_Reply", now_s: float) -> None:
        words = " ".join(tokens)
        if not tokens:
            reply.send("0")
        elif words == "home":
            self._start(0.0, now_s, homing=True)
            reply.send("0")
        elif tokens[0] == "move" and len(tokens) == 3 and tokens[1] in ("abs", "rel"):
            self._move(tokens[1], tokens[2], reply, now_s)
        elif words == "stop":
            self.carriage.stop(now_s)
            self.homing = False
            reply.send("0")
        elif tokens[0] == "get" and len(tokens) == 2:
            value = self._get(tokens[1], reply.axis, now_s)
            reply.send(value if value is not None else "BADCOMMAND", rejected=value is None)
        elif tokens[0] == "set" and len(tokens) == 3:
            self._set(tokens[1], tokens[2], reply, now_s)
        elif words in ("warnings", "warnings clear"):
            active = self._ordered_flags()
            reply.send(" ".join([f"{len(active):02d}", *active]))
            if words == "warnings clear":
                self.flags &= {"WR"} if not self.homed else set()
        else:
            reply.send("BADCOMMAND", rejected=True)

    def _get(self, name: str, axis: int, now_s: float) -> str | None:
        """A setting's value as the device prints it; None if there is no such setting."""
        if name not in _SETTINGS:
            return None
        return str(self._device_value(name) if name in _DEVICE_SCOPE else self._axis_value(name, now_s))

    def _device_value(self, name: str) -> int | str:
        return {"deviceid": self.device_id, "system.serial": self.serial, "version": "7.38", "version.build": 17935,
                "system.axiscount": 1, "comm.packet.size.max": 80, "comm.alert": int(self.alerts),
                "comm.checksum": int(self.checksums), "system.access": 1}[name]

    def _axis_value(self, name: str, now_s: float) -> int:
        if name == "pos":
            return self.position_steps(now_s)
        if name == "maxspeed":  # microsteps per 1.6384 s (the firmware's speed unit)
            return round(self.carriage.speed_mm_s * 1000.0 / self.microstep_um * 1.6384)
        return {"limit.min": 0, "limit.max": self.limit_max_steps, "accel": self.accel,
                "resolution": self.resolution, "peripheralid": 0}[name]

    def _set(self, name: str, text: str, reply: "_Reply", now_s: float) -> None:
        if not _SETTINGS.get(name, False):
            reply.send("BADCOMMAND", rejected=True)
            return
        try:
            value = int(text)
        except ValueError:
            reply.send("BADDATA", rejected=True)
            return
        if name in ("comm.alert", "comm.checksum") and value in (0, 1):
            setattr(self, "alerts" if name == "comm.alert" else "checksums", bool(value))
        elif name == "resolution" and 1 <= value <= 256 and not self.carriage.moving():
            self.resolution = value  # the reference is lost: positions change meaning
            self.homed = False
            self.flags.add("WR")
        elif name == "maxspeed" and value > 0:
            self.carriage.speed_mm_s = value / 1.6384 * self.microstep_um / 1000.0
        elif name == "accel" and value >= 0:
            self.accel = value
        elif name == "system.access" and value in (1, 2):
            pass
        elif name == "limit.max" and 0 < value <= self.limit_max_steps:
            self.carriage.travel_mm = value * self.microstep_um / 1000.0
        elif name == "pos" and not self.carriage.moving():
            self.origin_mm = self.carriage.position_mm(now_s) - value * self.microstep_um / 1000.0
        else:
            reply.send("BADDATA", rejected=True)
            return
        reply.send("0")

    def _move(self, mode: str, value: str, reply: "_Reply", now_s: float) -> None:
        try:
            steps = int(value)
        except ValueError:
            reply.send("BADDATA", rejected=True)
            return
        if mode == "abs" and not self.homed:
            reply.send("BADDATA", rejected=True)
            return
        target = steps if mode == "abs" else self.position_steps(now_s) + steps
        if not 0 <= target <= self.limit_max_steps:
            reply.send("BADDATA", rejected=True)
            return
        if self.carriage.moving():
            self.flags.add("NI")
        self._start(self.origin_mm + target * self.microstep_um / 1000.0, now_s, homing=False)
        reply.send("0")

    def _start(self, carriage_mm: float, now_s: float, *, homing: bool) -> None:
        self.flags.discard("FS")
        self.homing = homing
        if homing:
            self.carriage.start(0.0, now_s)
            return
        error = self.take_fault("position_error")
        stall = self.take_fault("stall")
        start = self.carriage.position_mm(now_s)
        self.carriage.start(
            carriage_mm, now_s,
            stop_at_mm=(start + carriage_mm) / 2 if stall else None, stop_outcome="stall",
            error_mm=float(error.get("mm", 5.0)) if error else 0.0,
        )

    def power_cycle(self) -> None:
        """Lose power and come back: motion stops and the reference position is lost (WR)."""
        with self._lock:
            now = time.monotonic()
            self.carriage.stop(now)
            self.origin_mm = self.carriage.position_mm(now)
            self.homed = self.homing = False
            self.flags = {"WR"}
            self._buffer.clear()

    # --- time ----------------------------------------------------------------------------------

    def tick(self, now_s: float) -> None:
        outcome = self.carriage.update(now_s)
        if outcome is None:
            return
        if self.homing and outcome == "arrived":
            self.origin_mm = self.carriage.position_mm(now_s)
            self.homed = True
            self.flags.discard("WR")
        elif outcome == "stall":
            self.flags.add("FS")
        self.homing = False
        self.rested(self.carriage.position_mm(now_s))
        if self.alerts:
            self.send_message(f"!{self.device:02d} 1 {self.status()} {self.top_flag()}")

    def send_message(self, text: str) -> None:
        """Send a reply, info or alert line, with its checksum when comm.checksum is 1."""
        self.send_line(f"{text}:{checksum(text[1:])}" if self.checksums else text)

    def _ordered_flags(self) -> list[str]:
        return [f for f in _FLAG_PRIORITY if f in self.flags]

    def status(self) -> str:
        return "BUSY" if self.carriage.moving() else "IDLE"

    def top_flag(self) -> str:
        ordered = self._ordered_flags()
        return ordered[0] if ordered else "--"


class _Reply:
    """Formats the one reply a command gets."""

    def __init__(self, sim: ZaberSim, axis: int, message_id: int | None):
        self.sim, self.axis, self.message_id = sim, axis, message_id

    def send(self, data: str, *, rejected: bool = False) -> None:
        sim = self.sim
        head = f"@{sim.device:02d} {self.axis}" + (f" {self.message_id:02d}" if self.message_id is not None else "")
        flag = "RJ" if rejected else "OK"
        sim.send_message(f"{head} {flag} {sim.status()} {sim.top_flag()} {data}")
