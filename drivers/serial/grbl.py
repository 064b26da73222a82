"""A linear stage on the X axis of a GRBL 1.1 controller (G-code over USB serial). Stage kind `grbl`.

    grbl:///dev/ttyUSB0?baud=115200&offset_m=0.3&direction=1&feed=3000&settle=0.2&tolerance_mm=1

Every failure raises `StageError` with one line, "grbl <port>: <problem>; <what to do>";
docs/stages.md lists them all with causes and fixes.
"""

from __future__ import annotations

from typing import Any, Callable

from ..errors import StageError
from ..registry import DeviceSpec
from ..stage import Stage
from .grbl_link import SETTING_LINE, ControllerAlarm, GrblLink, GrblStatus, Refused
from .grbl_machine import REQUIRED, move_time_s, parse_settings, rail_geometry, soft_limit_window
from .line import CABLE, GarbledReply
from .rail import GRBL_OPTIONS, Rail, require_port

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
        self.link = GrblLink(path, baud, timeout_s, poll_s)
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
        #: machine X of rail zero, and the sign of machine X moving away from it
        self.home_mm, self.away = 0.0, 1
        self.rail: Rail | None = None
        if travel_mm is not None and rail_min_mm is not None:  # the device string fixes the rail in machine X
            self.rail = Rail(offset_m, direction, rail_min_mm, rail_min_mm + travel_mm)
        self._homed = False

    @property
    def firmware(self) -> str:
        return self.link.firmware

    @property
    def settings(self) -> dict[int, float]:
        """The controller's `$$`, read at open."""
        return self.link.settings

    @property
    def options(self) -> str:
        """The build options of `$I` ([OPT:...]), read at open."""
        return self.link.options

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
            self._reset_when_still(self.link.status_or_none(tries=1))
            self._read_settings()
            self.link.status()
        except StageError:
            self.link.close()
            raise

    def close(self) -> None:
        self.link.close()

    def home(self) -> None:
        """Reset out of any alarm or hold (never while the carriage moves), run the homing cycle ($H) or
        just unlock ($X), set G90 G21."""
        self.link.discard_input()
        status = self.link.status_or_none()  # None: silent, as GRBL is after ALARM:1/2 until a reset
        if status is None or status.kind in ("Alarm", "Door", "Sleep", "Hold", "Run", "Jog"):
            self._reset_when_still(status)
            status = self.link.status_or_none()
        if self.homing:
            self.link.command("$H", self.home_timeout_s, during="homing ($H)")
        else:
            if status is not None and status.kind == "Alarm" and not int(self.settings.get(22, 0)):
                raise self._position_lost()
            self.link.command("$X", self.timeout_s)
        self.link.command("G90 G21", self.timeout_s)
        self._homed, self.link.position_lost = True, False

    def move_to(self, position_m: float) -> float:
        if not self._homed or self.link.position_lost:
            raise self.link.error("not homed", "home the stage (the plan's home step) before moving")
        self.check_limits(position_m)
        x_mm = self.home_mm + self.away * self._rail().to_rail_mm(position_m)
        command = f"G21 G53 G1 X{x_mm:.3f} F{self.feed_mm_min:.0f}"
        last = self.link.last_x_mm
        distance_mm = abs(x_mm - last) if last is not None else self._rail().max_mm - self._rail().min_mm
        self._stopping_on_error(lambda: (self.link.command(command, self.timeout_s),
                                         self._poll_until_idle(repr(command), self._move_time_s(distance_mm))))
        if self.settle_s > 0:
            self.link.clock.sleep(self.settle_s)
        measured = self.position_m()
        self.check_arrived(position_m, measured)
        return measured

    def position_m(self) -> float:
        return self._rail().to_position_m((self.link.status().x_mm - self.home_mm) * self.away)

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
        self.link.settings = parse_settings(self.link.query("$$", SETTING_LINE))
        missing = [n for n in REQUIRED if n not in self.settings]
        if missing:
            raise self.link.error(
                f"'$$' did not list {', '.join(f'${n}' for n in missing)}",
                "check that the controller runs GRBL 1.1 (other firmware numbers its settings differently)",
            )
        self.link.options = next((t[5:-1] for t in self.link.query("$I") if t.startswith("[OPT:")), "")
        s = self.settings
        if self.homing and not s[22]:
            raise self.link.error(
                "homing is disabled on the controller ($22=0)",
                "enable it ($22=1, with home switches fitted) or add homing=0 to the device string",
            )
        self.feed_mm_min = min(self.requested_feed_mm_min, s[110])
        self.link.soft_limit_fix = self._soft_limit_fix()
        if self.rail is not None:
            return  # rail_min_mm and travel_mm given: the device string wins
        geometry = rail_geometry(s, self.options, homing=self.homing)
        self.home_mm, self.away = geometry.home_mm, geometry.away
        travel = min(self.travel_mm or geometry.travel_mm, geometry.travel_mm)
        low = self.rail_min_mm or 0.0
        self.rail = Rail(self.offset_m, self.direction, low, low + travel)

    def _move_time_s(self, distance_mm: float) -> float:
        return move_time_s(distance_mm, self.feed_mm_min, self.settings.get(120, 0.0))

    # --- protocol ---------------------------------------------------------------------------------

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
        self.link.soft_reset()

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

    def _stopping_on_error(self, move: Callable[[], object]) -> None:
        """Send a move and wait for it; on any error (a move never acknowledged may still have started),
        stop the carriage before raising."""
        try:
            move()
        except (Refused, ControllerAlarm):
            raise  # a refused line moves nothing; an alarm has stopped the motors itself
        except StageError as e:
            if not self.link.is_open or self.link.alarm:
                raise
            raise StageError(f"{e}{self._stop_motion()}") from None

    def _hold(self, status: GrblStatus | None = None) -> str | None:
        """Feed hold ('!') and wait until the carriage is still: Hold:0 (the hold is complete), or a state
        without motion. The deadline is three times the deceleration from the current feed at $120, plus
        two reply times. None when still; else what was seen (and nothing more is sent)."""
        feed = status.feed_mm_min if status is not None and status.feed_mm_min > 0 else self.feed_mm_min
        accel = self.settings.get(120, 0.0) or 10.0
        deadline = self.link.clock.monotonic() + 3.0 * (feed / 60.0) / accel + 2.0 * self.timeout_s + 1.0
        seen = "no status report came"
        while True:
            self.link.write(b"!", "a feed hold ('!')")  # again each time: a real-time byte can be lost too
            try:
                status = self.link.status("a feed hold ('!')")
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
            if self.link.clock.monotonic() > deadline:
                return seen
            self.link.clock.sleep(self.poll_s)

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
            self.link.soft_reset()
        except StageError:
            return "; the carriage was held (feed hold) but no banner followed the reset after it"
        return "; the carriage was stopped (a feed hold, then a reset once the hold was complete: position kept)"

    def _poll_until_idle(self, what: str, expected_s: float) -> GrblStatus:
        """Idle counts once motion was seen, or when two reports in a row say Idle (a move may not have
        started when the first one is sent). Stuck: the position has not changed for stall_s while not
        Idle, or the move takes far longer than the settings allow."""
        start = self.link.clock.monotonic()
        deadline = start + 2.0 * expected_s + 10.0
        moved, idle_reports = False, 0
        last_x, last_change = None, start
        while True:
            status = self.link.status(what)
            now = self.link.clock.monotonic()
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
            self.link.clock.sleep(self.poll_s)


def open_grbl(spec: DeviceSpec, context: dict[str, Any]) -> Stage:
    """Factory for `grbl://PORT?...` (see drivers.registry)."""
    return GrblStage.from_spec(spec)
