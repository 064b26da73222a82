"""A simulated Zaber stage speaking the Zaber ASCII protocol, on a pseudo-terminal.

One device (number `device`, default 1) with one axis. Commands look like
`/1 1 move abs 5249344` and every command gets one reply such as `@01 1 OK BUSY -- 0`,
`@01 1 OK IDLE WR 15748031` or `@01 1 RJ IDLE -- BADDATA`: device, axis, OK/RJ, BUSY/IDLE,
the highest-priority warning flag (`--` for none), then data. Understood: the empty command
(status), home, move abs, move rel, stop, get pos, get limit.min, get limit.max,
get maxspeed, warnings, warnings clear. Positions are in microsteps of `microstep_um`.

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
        seed: int = 0,
    ):
        super().__init__(seed=seed)
        self.carriage = Carriage(travel_mm, speed_mm_s, start_mm)
        self.microstep_um = microstep_um
        self.device = device
        #: device position = carriage position - origin; arbitrary until homed
        self.origin_mm = start_mm
        self.homed = False
        self.homing = False
        self.flags: set[str] = {"WR"}
        self._buffer = bytearray()

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
        tokens = line[1:].split()
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
        elif words == "get pos":
            reply.send(str(self.position_steps(now_s)))
        elif words == "get limit.min":
            reply.send("0")
        elif words == "get limit.max":
            reply.send(str(self.limit_max_steps))
        elif words == "get maxspeed":
            reply.send(str(round(self.carriage.speed_mm_s * 1000.0 / self.microstep_um / 1.6384)))
        elif words in ("warnings", "warnings clear"):
            active = self._ordered_flags()
            reply.send(" ".join([f"{len(active):02d}", *active]))
            if words == "warnings clear":
                self.flags &= {"WR"} if not self.homed else set()
        else:
            reply.send("BADCOMMAND", rejected=True)

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
        head = f"@{sim.device:02d} {self.axis}" + (f" {self.message_id}" if self.message_id is not None else "")
        flag = "RJ" if rejected else "OK"
        sim.send_line(f"{head} {flag} {sim.status()} {sim.top_flag()} {data}")
