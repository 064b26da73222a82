"""A simulated GRBL 1.1h controller driving one linear axis (X), on a pseudo-terminal.

What it follows of the firmware, feature by feature (gnea/grbl wiki: interface.md, commands.md,
settings.md; source files named where the wiki is silent):
- start-up and soft reset (Ctrl-X): the banner `Grbl 1.1h ['$' for help]`, then each stored startup
  line run and echoed as `>G20:ok` (`$N0=...`, `$N1=...`; protocol.c), then `[MSG:'$H'|'$X' to unlock]`
  when homing is enabled and the machine is not homed (main.c: homing on means Alarm at power-up)
- settings (`fakes/grbl_settings.py`): `$$`, `$N=value`, stock defaults (`GrblSim.stock()`)
- machine space as stock GRBL makes it (limits.c, limits_go_home): homing ($H, needs $22=1) seeks the
  switch at $25 mm/min towards +X unless $23 bit 0 is set, pulls off $27 mm, and sets MPos to -$27
  (homing to +X) or -$130+$27 (to -X), so the travel is -$130..0; with the compile option
  HOMING_FORCE_SET_ORIGIN (`force_origin=True`, reported as `Z` in `$I`'s OPT) MPos is 0 there and the
  travel 0..$130 (to -X) or -$130..0 (to +X). No `?` is answered during homing (the cycle blocks
  the protocol loop). A failed homing gives ALARM:9, and the reset that follows prints the banner again.
- motion: feed capped at $110 mm/min (G0 moves at $110), acceleration $120 mm/s^2 (trapezoidal);
  `G53`, `G90`/`G91`, `G20`/`G21`, `G4 P<s>`; `$J=` jogging (soft limits give error:15, not an alarm);
  a planner of 15 blocks and a 128-byte receive buffer (bytes past it are lost, as an overrun UART loses
  them); a line over 80 characters gives error:11
- soft limits ($20=1): a target outside the travel gives ALARM:2; hard limits ($21=1): reaching the end
  of the rail gives ALARM:1; both are critical events: `[MSG:Reset to continue]`, then nothing is
  answered, not even `?`, until Ctrl-X (protocol.c: the critical-event loop blocks everything). With
  hard limits off ($21=0, stock) a move past the end of the rail stalls the motor there: MPos goes on
  to the target and the steps are lost
- real-time commands: `?` status, `!` feed hold, `~` resume, 0x85 jog cancel, feed and rapid overrides
  (0x90-0x97). A feed hold decelerates at $120: `Hold:1` while it brakes, `Hold:0` once it is still
  (report.c: `Hold:0` is SUSPEND_HOLD_COMPLETE, "ready to resume"); `!` while Idle gives `Hold:0` at once;
  `~` is ignored during `Hold:1` and resumes the move from `Hold:0` (or goes Idle if none is left). A reset
  during Run, Jog or Hold:1 aborts the motion with ALARM:3 and loses the position (motion_control.c,
  mc_reset: steppers killed while the motion or the hold's deceleration runs); a reset in Hold:0 keeps it
  (interface.md: a reset after the hold is complete does not throw an alarm)
- a soft reset resets the parser state (`$G`: G0 ... F0, gcode.c gc_init); a line that raised ALARM:2 gets
  its `ok` only after the reset, before the banner; `$SLP` answers `ok` and `[MSG:Sleeping]`, reports
  `Sleep`, reads no more lines, and the reset that wakes it leaves Alarm (protocol.c: sleep is re-entered
  as an alarm, since the position cannot be guaranteed); `$SLP` outside Idle and Alarm is error:8
- status reports per $10 (bit 0: MPos, else WPos; bit 1: Bf) with `FS`, `Pn:X` while a limit switch is
  pressed, `WCO` in the first report after a reset and then every 10th (idle) or 30th (busy), `Ov` in the
  report after a WCO one and then every 10th or 20th, and at once after an override changes (report.c's
  counters); positions in inches when $13=1 (report.c)
- `$G` (`[GC:...]`), `$#`, `$I`, `$N`, `$C` (check mode: no motion; leaving it resets), `$X`, `$H`

Faults for tests, via `inject()`: drop_reply, noise, unplug, position_error (mm=...), hard_limit (the
next move trips a limit switch half-way) and homing_fail; `power_cycle()` restarts the controller.
"""

from __future__ import annotations

import time

from .grbl_commands import PLANNER_BLOCKS, RX_BUFFER, GrblSystemCommands
from .grbl_gcode import GrblGcode
from .grbl_settings import STOCK
from .pty_controller import COMMON_FAULTS, Carriage, PtyController

BANNER = "Grbl 1.1h ['$' for help]"
_REALTIME = {ord("?"), 0x18, ord("!"), ord("~"), 0x85, *range(0x90, 0x98)}
LINE_BUFFER = 80


class GrblSim(GrblGcode, GrblSystemCommands, PtyController):
    """A GRBL 1.1h controller with one axis (X) on a rail of `travel_mm` ($130)."""

    kind = "grbl"
    faults = COMMON_FAULTS + ("hard_limit", "homing_fail")

    def __init__(
        self,
        *,
        travel_mm: float = 3000.0,
        speed_mm_s: float = 2000.0,
        start_mm: float | None = None,
        soft_limits: bool | None = None,
        homing: bool = True,
        accel_mm_s2: float = 1e5,
        settings: dict[int, float] | None = None,
        force_origin: bool = False,
        startup_lines: tuple[str, str] = ("", ""),
        seed: int = 0,
    ):
        """Fast by default (speed_mm_s sets $110 and the homing rates, accel_mm_s2 $120); `settings` override
        any setting; `GrblSim.stock()` is a freshly flashed controller. start_mm: where the carriage sits on
        the rail at power-up, mm from its -X end. Soft limits are on when homing is, by default; soft limits
        without homing are refused, as the firmware refuses `$20=1` with `$22=0` (error:10)."""
        super().__init__(seed=seed)
        soft_limits = homing if soft_limits is None else soft_limits
        self.settings = dict(STOCK)
        self.settings.update({20: int(soft_limits), 22: int(homing), 110: speed_mm_s * 60.0, 24: speed_mm_s * 60.0,
                              25: speed_mm_s * 60.0, 120: accel_mm_s2, 130: travel_mm})
        self.settings.update(settings or {})
        if self.settings[20] and not self.settings[22]:
            raise ValueError("soft limits ($20=1) need homing ($22=1): GRBL refuses $20=1 with $22=0 (error:10)")
        self.force_origin = force_origin
        self.startup_lines = list(startup_lines)
        rail = self.settings[130]
        self.carriage = Carriage(rail, self.settings[110] / 60.0, 0.4 * rail if start_mm is None else start_mm,
                                 self.settings[120])
        #: machine position = carriage position - origin_mm; power-up zero until homed
        self.origin_mm = self.carriage.position_mm(time.monotonic())
        self.homed = False
        self.state = "Alarm" if self.settings[22] else "Idle"
        #: True after ALARM:1/ALARM:2: nothing at all is served until a reset
        self.critical = False
        self.feed_mm_min = 0.0
        self.motion = 0
        self.absolute = True
        self.mm_per_unit = 1.0
        self.feed_override = self.rapid_override = 100
        self.reports = 0
        #: report.c's counters: reports until the next WCO and Ov fields (0: in the next report)
        self.wco_counter = self.ovr_counter = 0
        #: the line that raised ALARM:2 gets its `ok` after the reset (protocol.c returns to it only then)
        self._owed_ok = False
        self._rx = bytearray()
        self._queue: list[tuple[str, float, float]] = []  # ("move" | "jog", machine mm, mm/min) or ("dwell", s, 0)
        self._dwell_until: float | None = None
        self._target: tuple[float, float] | None = None  # the current move's (machine mm, mm/min), for resume
        self._commanded_mm: float | None = None  # where MPos ends if the motor stalls at the end of the rail
        self._muted = False
        self._jog_cancelled = False

    @classmethod
    def stock(cls, **options) -> "GrblSim":
        """A freshly flashed GRBL 1.1h: every setting at its default ($110=500, $120=10, $130=200, soft limits,
        hard limits and homing off), on a rail of $130 mm; `settings` override single ones."""
        overrides = dict(STOCK)
        overrides.update(options.pop("settings", {}))
        return cls(travel_mm=overrides[130], soft_limits=bool(overrides[20]), homing=bool(overrides[22]),
                   settings=overrides, **options)

    @property
    def travel_mm(self) -> float:
        return self.carriage.travel_mm

    @property
    def homes_positive(self) -> bool:
        return not int(self.settings[23]) & 1

    @property
    def pulloff_mm(self) -> float:
        return self.settings[27]

    def machine_mm(self, now_s: float) -> float:
        return self.carriage.position_mm(now_s) - self.origin_mm

    def from_home_mm(self, now_s: float) -> float:
        """How far the carriage is from where homing leaves it (the switch, less the pull-off), mm."""
        switch = self.travel_mm if self.homes_positive else 0.0
        homed = switch - self.pulloff_mm if self.homes_positive else switch + self.pulloff_mm
        return abs(self.carriage.position_mm(now_s) - homed)

    def machine_limits_mm(self) -> tuple[float, float]:
        """The soft-limit travel in machine coordinates (limits.c, system_check_travel_limits)."""
        travel = self.settings[130]
        if self.force_origin and not self.homes_positive:
            return 0.0, travel
        return -travel, 0.0

    # --- bytes in ---------------------------------------------------------------------------

    def handle_bytes(self, data: bytes, now_s: float) -> None:
        for byte in data:
            if byte in _REALTIME:
                self._realtime(byte, now_s)
            elif len(self._rx) < RX_BUFFER:
                self._rx.append(byte)  # past 128 bytes an overrun UART loses them
                if byte in (0x0A, 0x0D):
                    self._drain(now_s)  # GRBL reads a line as soon as it is whole, while the planner has room

    def _drain(self, now_s: float) -> None:
        """Execute complete lines while the planner has room (GRBL stops reading when it is full)."""
        while not self.critical:
            if sum(1 for q in self._queue if q[0] != "dwell") >= PLANNER_BLOCKS or self.state in ("Home", "Sleep"):
                return  # a full planner, the homing cycle and sleep read no more lines
            if self._dwell_until is not None or any(q[0] == "dwell" for q in self._queue):
                return  # G4 holds the parser: mc_dwell syncs the buffer, then sleeps; lines wait in the RX buffer
            ends = [i for i in (self._rx.find(b"\n"), self._rx.find(b"\r")) if i >= 0]
            if not ends:
                return
            end = min(ends)
            raw, self._rx = self._rx[:end], self._rx[end + 1:]
            self._execute_line(raw.decode("ascii", "replace"), now_s)

    def _realtime(self, byte: int, now_s: float) -> None:
        if byte == 0x18:
            self.commands.append("^X")
            self._soft_reset(now_s)
            return
        if self.critical or self.state == "Home":
            return  # the critical-event loop and the homing cycle answer nothing
        if byte == ord("?"):
            if not self.drop_command("?"):
                self.send_line(self._status(now_s))
        elif byte == ord("!") and self.state in ("Run", "Jog", "Idle"):
            self.commands.append("!")
            if self.state == "Idle":
                self.state = "Hold:0"  # protocol.c: a hold from Idle is complete at once
                return
            if self.state == "Jog":
                self._jog_cancel(now_s)
                return
            self.carriage.brake(now_s)
            self.state = "Hold:1" if self.carriage.moving() else "Hold:0"
        elif byte == ord("~") and self.state == "Hold:0":  # ignored while the hold still brakes (Hold:1)
            self.commands.append("~")
            if self._target is None and not self._queue:
                self.state = "Idle"
                return
            self.state = "Run"
            if self._target is not None:
                self._start_move(*self._target, now_s)
        elif byte == 0x85 and self.state == "Jog":
            self._jog_cancel(now_s)
        elif 0x90 <= byte <= 0x94:
            self.feed_override = {0x90: 100, 0x91: self.feed_override + 10, 0x92: self.feed_override - 10,
                                  0x93: self.feed_override + 1, 0x94: self.feed_override - 1}[byte]
            self.feed_override = min(200, max(10, self.feed_override))
            self.ovr_counter = 0  # protocol.c: a changed override is reported at once
        elif 0x95 <= byte <= 0x97:
            self.rapid_override = {0x95: 100, 0x96: 50, 0x97: 25}[byte]
            self.ovr_counter = 0

    def _execute_line(self, raw: str, now_s: float) -> None:
        line = "".join(raw.split()).upper()
        if self.drop_command(raw.strip()):
            return
        if len(raw) > LINE_BUFFER:
            self.send_line("error:11")
        elif not line:
            self.send_line("ok")
        elif line.startswith("$"):
            self._system_command(line, now_s)
        else:
            error = self._gcode(line, now_s)
            if error is not None:
                self.send_line(error)

    # --- time ----------------------------------------------------------------------------------

    def tick(self, now_s: float) -> None:
        outcome = self.carriage.update(now_s)
        if outcome is not None:
            self.rested(self.carriage.position_mm(now_s))
        if self.state == "Home":
            self._homing_tick(outcome, now_s)
            return
        if outcome in ("limit", "hard_limit"):
            if outcome == "hard_limit" or self.settings[21]:
                self._critical_alarm(1, now_s)
                return
            if self._commanded_mm is not None:  # hard limits off: the motor stalls at the end, steps lost
                self.origin_mm = self.carriage.position_mm(now_s) - self._commanded_mm
        if self.state == "Hold:1" and not self.carriage.moving():
            self.state = "Hold:0"  # the hold is complete: ready to resume, and a reset keeps the position
        if self.state == "Jog" and self._jog_cancelled and not self.carriage.moving():
            self._queue = [q for q in self._queue if q[0] != "jog"]
            self.state, self._target, self._jog_cancelled = "Idle", None, False
        if self._dwell_until is not None:
            if now_s < self._dwell_until:
                return
            self._dwell_until = None
            self.send_line("ok")
            self._drain(now_s)  # the parser reads on after the dwell
        if self.carriage.moving() or self.state in ("Alarm", "Hold:0", "Hold:1", "Sleep"):
            return
        if not self._queue:
            if self.state in ("Run", "Jog"):
                self.state, self._target = "Idle", None
            return
        kind, value, feed = self._queue.pop(0)
        if kind == "dwell":  # the parser stays held until the dwell is over (then its ok, then the next line)
            self._dwell_until = now_s + value
            return
        self._drain(now_s)  # a planner block is free: GRBL reads on
        self.state = "Jog" if kind == "jog" else "Run"
        self._start_move(value, feed, now_s)

    def _start_move(self, target_machine_mm: float, feed_mm_min: float, now_s: float) -> None:
        self._target = (target_machine_mm, feed_mm_min)
        override = self.rapid_override if feed_mm_min == self.settings[110] else self.feed_override
        speed = min(feed_mm_min * override / 100.0, self.settings[110]) / 60.0
        error = self.take_fault("position_error")
        trip = self.take_fault("hard_limit")
        start = self.carriage.position_mm(now_s)
        target = target_machine_mm + self.origin_mm
        self._commanded_mm = target_machine_mm
        self.carriage.start(
            target, now_s, speed_mm_s=speed,
            stop_at_mm=(start + target) / 2 if trip else None, stop_outcome="hard_limit",
            error_mm=float(error.get("mm", 5.0)) if error else 0.0,
        )

    def _homing_tick(self, outcome: str | None, now_s: float) -> None:
        if outcome == "homing_fail":
            self.send_line("ALARM:9")
            self.state = "Alarm"
            self._soft_reset(now_s, alarm_kept=True)  # limits.c: mc_reset() after a homing alarm
        elif outcome is not None:
            pulloff = self.pulloff_mm if self.homes_positive else -self.pulloff_mm
            homed_at = self.carriage.position_mm(now_s) - pulloff
            self.carriage.place(homed_at)  # the pull-off move (short; its time is not simulated)
            if self.force_origin:
                machine = 0.0
            else:
                machine = -self.pulloff_mm if self.homes_positive else -self.settings[130] + self.pulloff_mm
            self.origin_mm = homed_at - machine
            self.homed = True
            self.state = "Idle"
            self.send_line("ok")
            self._drain(now_s)

    # --- state changes ---------------------------------------------------------------------------

    def power_cycle(self) -> None:
        """Lose power and come back: motion stops, MPos restarts at zero where the carriage is,
        the banner is sent unasked, and (with homing enabled) the controller is in Alarm."""
        with self._lock:
            now = time.monotonic()
            self.carriage.stop(now)
            self.origin_mm = self.carriage.position_mm(now)
            self.homed = False
            self.state = "Alarm" if self.settings[22] else "Idle"
            self._soft_reset(now, alarm_kept=True)

    def _jog_cancel(self, now_s: float) -> None:
        """Brake and drop the jog; the state stays Jog until the carriage is still, then Idle (protocol.c)."""
        self.carriage.brake(now_s)
        self._queue = [q for q in self._queue if q[0] != "jog"]
        self._jog_cancelled = True
        if not self.carriage.moving():
            self.state, self._target, self._jog_cancelled = "Idle", None, False

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

    def _soft_reset(self, now_s: float, *, alarm_kept: bool = False) -> None:
        if not alarm_kept:
            if self.state in ("Run", "Jog", "Hold:1"):  # mc_reset: the motion or the hold's braking is cut short
                self.carriage.stop(now_s)
                self.state = "Alarm"
                self.homed = False
                self.send_line("ALARM:3")
            elif self.state == "Home":
                self.carriage.stop(now_s)
                self.state = "Alarm"
                self.send_line("ALARM:6")
            elif self.state == "Sleep":
                self.state = "Alarm"  # protocol.c: sleep is re-entered as an alarm
            elif self.state in ("Hold:0", "Check"):
                self.state = "Idle"  # stopped in a complete feed hold: the position is kept
        if self._owed_ok:
            self.send_line("ok")  # the line that raised ALARM:2 is answered on the way out of the alarm
            self._owed_ok = False
        self._queue.clear()
        self._target = None
        self._dwell_until = None
        self._jog_cancelled = False
        self._rx.clear()
        self.critical = False
        self.absolute, self.mm_per_unit, self.motion, self.feed_mm_min = True, 1.0, 0, 0.0  # gc_init: G0 G90 G21 F0
        self.feed_override = self.rapid_override = 100
        self.wco_counter = self.ovr_counter = 0  # the system struct is cleared: both fields in the next reports
        self.write(b"\r\n")
        self.send_line(BANNER)
        if self.state == "Alarm":
            self.send_line("[MSG:'$H'|'$X' to unlock]")
            return
        for text in self.startup_lines:
            if text:
                self._muted = True  # GRBL prints a startup line's result as >line:ok, not as a bare ok
                try:
                    error = self._gcode("".join(text.split()).upper(), now_s)
                finally:
                    self._muted = False
                self.send_line(f">{text}:{error or 'ok'}")

    def send_line(self, text: str) -> None:
        if not (self._muted and text == "ok"):
            super().send_line(text)
