"""A simulated GRBL 1.1 controller driving one linear axis (X), on a pseudo-terminal.

It speaks enough of GRBL 1.1 for the rig: the start-up banner, soft reset (Ctrl-X), the `?`
status report, `$X`, `$H`, `$$`, `$I`, and G-code lines with G0/G1/G4/G20/G21/G53/G90/G91
and X/F/P words. Machine space runs from 0 (the home switch) to `travel_mm`, as on a machine
homed with its origin at the switch.

Behaviour that matters to a driver: moves take time (`speed_mm_s`, fast by default so tests
are quick) and `?` reports Run with a moving MPos until they end; with homing enabled the
controller starts in Alarm until `$H` or `$X`; a target outside the travel gives ALARM:2
(soft limits on) or runs into the end switch and gives ALARM:1 (soft limits off); both are
critical: nothing but `?` and Ctrl-X is answered until a reset, after which `$X` or `$H`
is needed. Faults for tests, via `inject()`: drop_reply, noise, unplug, position_error
(mm=...), hard_limit (the next move trips a limit switch half-way) and homing_fail;
`power_cycle()` restarts the controller.
"""

from __future__ import annotations

import re
import time

from .pty_controller import COMMON_FAULTS, Carriage, PtyController

BANNER = "Grbl 1.1h ['$' for help]"
_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
_REALTIME = {ord("?"), 0x18, ord("!"), ord("~")}


class GrblSim(PtyController):
    """A GRBL 1.1 controller with one axis on a rail from 0 to travel_mm."""

    kind = "grbl"
    faults = COMMON_FAULTS + ("hard_limit", "homing_fail")

    def __init__(
        self,
        *,
        travel_mm: float = 3000.0,
        speed_mm_s: float = 2000.0,
        start_mm: float = 1200.0,
        soft_limits: bool = True,
        homing: bool = True,
        seed: int = 0,
    ):
        super().__init__(seed=seed)
        self.carriage = Carriage(travel_mm, speed_mm_s, start_mm)
        self.soft_limits = soft_limits
        self.homing = homing
        #: machine position = carriage position - origin; unknown (power-up zero) until homed
        self.origin_mm = start_mm
        self.homed = False
        self.state = "Alarm" if homing else "Idle"
        #: True after ALARM:1/ALARM:2: only `?` and Ctrl-X are served until a reset
        self.critical = False
        self.feed_mm_min = 0.0
        self.absolute = True
        self.mm_per_unit = 1.0
        self._line = bytearray()
        self._queue: list[tuple[str, float]] = []  # ("move", machine mm) or ("dwell", s)
        self._dwell_until: float | None = None

    @property
    def travel_mm(self) -> float:
        return self.carriage.travel_mm

    def machine_mm(self, now_s: float) -> float:
        return self.carriage.position_mm(now_s) - self.origin_mm

    # --- bytes in ---------------------------------------------------------------------------

    def handle_bytes(self, data: bytes, now_s: float) -> None:
        for byte in data:
            if byte in _REALTIME:
                self._realtime(byte, now_s)
            elif byte in (0x0A, 0x0D):
                line, self._line = self._line.decode("ascii", "replace"), bytearray()
                self._execute_line(line, now_s)
            elif byte < 0x80:
                self._line.append(byte)

    def _realtime(self, byte: int, now_s: float) -> None:
        if byte == 0x18:
            self.commands.append("^X")
            self._soft_reset(now_s)
            return
        if byte == ord("?"):
            if self.drop_command("?"):
                return
            self.send_line(self._status(now_s))
        # feed hold (!) and cycle start (~) are accepted and ignored

    def _execute_line(self, raw: str, now_s: float) -> None:
        line = "".join(raw.split()).upper()
        if self.critical:
            return  # waiting for a reset: GRBL reads nothing else
        if self.drop_command(raw.strip()):
            return
        if not line:
            self.send_line("ok")
        elif line.startswith("$"):
            self._system_command(line, now_s)
        else:
            self._gcode(line, now_s)

    # --- commands ------------------------------------------------------------------------------

    def _system_command(self, line: str, now_s: float) -> None:
        if line == "$X":
            if self.state == "Alarm":
                self.state = "Idle"
                self.send_line("[MSG:Caution: Unlocked]")
            self.send_line("ok")
        elif line == "$H":
            if not self.homing:
                self.send_line("error:5")
            elif self.state not in ("Idle", "Alarm"):
                self.send_line("error:8")
            else:
                self.state = "Home"
                fail = self.take_fault("homing_fail")
                stop_at = self.carriage.position_mm(now_s) / 2 if fail else None
                self.carriage.start(0.0, now_s, stop_at_mm=stop_at, stop_outcome="homing_fail")
        elif line == "$$":
            for key, value in (("$20", int(self.soft_limits)), ("$21", 1), ("$22", int(self.homing)),
                               ("$110", 3000.0), ("$130", self.travel_mm)):
                self.send_line(f"{key}={value:.3f}" if isinstance(value, float) else f"{key}={value}")
            self.send_line("ok")
        elif line == "$I":
            self.send_line("[VER:1.1h.20190830:]")
            self.send_line("[OPT:V,15,128]")
            self.send_line("ok")
        elif line == "$":
            self.send_line("[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]")
            self.send_line("ok")
        else:
            self.send_line("error:3")

    def _gcode(self, line: str, now_s: float) -> None:
        if self.state == "Alarm":
            self.send_line("error:9")
            return
        words = _WORD.findall(line)
        if "".join(letter + value for letter, value in words) != line:
            self.send_line("error:1")
            return
        motion, machine, x, dwell_s = None, False, None, None
        absolute, mm_per_unit, feed = self.absolute, self.mm_per_unit, self.feed_mm_min
        for letter, value in words:
            number = float(value)
            if letter == "G":
                if number in (0, 1):
                    motion = int(number)
                elif number == 4:
                    motion = 4
                elif number == 53:
                    machine = True
                elif number in (90, 91):
                    absolute = number == 90
                elif number in (20, 21):
                    mm_per_unit = 25.4 if number == 20 else 1.0
                else:
                    self.send_line("error:20")
                    return
            elif letter == "X":
                x = number
            elif letter == "F":
                feed = number
            elif letter == "P":
                dwell_s = number
            elif letter in ("Y", "Z", "N"):
                pass
            else:
                self.send_line("error:20")
                return
        self.absolute, self.mm_per_unit = absolute, mm_per_unit
        if motion == 4:
            self._queue.append(("dwell", dwell_s or 0.0))
            return  # "ok" once the dwell is over
        if x is None:
            self.send_line("ok")
            return
        if motion == 1 and feed <= 0:
            self.send_line("error:22")
            return
        self.feed_mm_min = feed if motion == 1 else self.feed_mm_min
        x_mm = x * self.mm_per_unit
        last = self._queue[-1][1] if self._queue and self._queue[-1][0] == "move" else None
        current = last if last is not None else (
            self.carriage.move.end_mm - self.origin_mm if self.carriage.move else self.machine_mm(now_s))
        target = x_mm if (self.absolute or machine) else current + x_mm
        if self.soft_limits and not 0.0 <= target <= self.travel_mm:
            self._critical_alarm(2, now_s)
            return
        self._queue.append(("move", target))
        self.send_line("ok")

    # --- time ----------------------------------------------------------------------------------

    def tick(self, now_s: float) -> None:
        outcome = self.carriage.update(now_s)
        if outcome is not None:
            self.rested(self.carriage.position_mm(now_s))
        if self.state == "Home":
            if outcome == "homing_fail":
                self.state = "Alarm"
                self.send_line("ALARM:9")
            elif outcome is not None:
                self.origin_mm = self.carriage.position_mm(now_s)
                self.homed = True
                self.state = "Idle"
                self.send_line("ok")
            return
        if outcome in ("limit", "hard_limit"):
            self._critical_alarm(1, now_s)
            return
        if self._dwell_until is not None:
            if now_s < self._dwell_until:
                return
            self._dwell_until = None
            self.send_line("ok")
        if self.carriage.moving() or self.state == "Alarm":
            return
        if not self._queue:
            if self.state == "Run":
                self.state = "Idle"
            return
        kind, value = self._queue.pop(0)
        if kind == "dwell":
            self._dwell_until = now_s + value
            return
        self.state = "Run"
        error = self.take_fault("position_error")
        trip = self.take_fault("hard_limit")
        start = self.carriage.position_mm(now_s)
        target = value + self.origin_mm
        self.carriage.start(
            target, now_s,
            stop_at_mm=(start + target) / 2 if trip else None, stop_outcome="hard_limit",
            error_mm=float(error.get("mm", 5.0)) if error else 0.0,
        )

    # --- state changes ---------------------------------------------------------------------------

    def power_cycle(self) -> None:
        """Lose power and come back: motion stops, MPos restarts at zero where the carriage is,
        the banner is sent unasked, and (with homing enabled) the controller is in Alarm."""
        with self._lock:
            now = time.monotonic()
            self.carriage.stop(now)
            self.origin_mm = self.carriage.position_mm(now)
            self.homed = False
            self.critical = False
            self.state = "Alarm" if self.homing else "Idle"
            self._queue.clear()
            self._dwell_until = None
            self._line.clear()
            self.write(b"\r\n")
            self.send_line(BANNER)
            if self.state == "Alarm":
                self.send_line("[MSG:'$H'|'$X' to unlock]")

    def _critical_alarm(self, code: int, now_s: float) -> None:
        self.carriage.stop(now_s)
        self._queue.clear()
        self._dwell_until = None
        self.state = "Alarm"
        self.critical = True
        if code == 1:
            self.homed = False
        self.send_line(f"ALARM:{code}")
        self.send_line("[MSG:Reset to continue]")

    def _soft_reset(self, now_s: float) -> None:
        if self.state == "Run" and self.carriage.moving():
            self.carriage.stop(now_s)
            self.state = "Alarm"
            self.homed = False
            self.send_line("ALARM:3")
        elif self.state == "Home":
            self.carriage.stop(now_s)
            self.state = "Alarm"
            self.send_line("ALARM:6")
        self._queue.clear()
        self._dwell_until = None
        self._line.clear()
        self.critical = False
        self.absolute, self.mm_per_unit = True, 1.0
        self.write(b"\r\n")
        self.send_line(BANNER)
        if self.state == "Alarm":
            self.send_line("[MSG:'$H'|'$X' to unlock]")

    def _status(self, now_s: float) -> str:
        x = self.machine_mm(now_s)
        feed = self.feed_mm_min if self.state == "Run" else 0
        return f"<{self.state}|MPos:{x:.3f},0.000,0.000|FS:{feed:.0f},0>"
