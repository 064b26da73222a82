"""Rail geometry shared by the serial stages, and the device-string options both take.

Both map the camera-to-wall distance to the rail the same way:
rail_mm = direction * (position_m - offset_m) * 1000, where offset_m is the distance when the
carriage is at rail zero (the home switch) and direction is +1 if moving away from home moves
the camera away from the wall, -1 otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..errors import StageError
from ..options import AT_LEAST_0, POSITIVE, Option, OptionTable, one_of
from ..registry import DeviceSpec


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


def require_port(spec: DeviceSpec) -> str:
    if not spec.path:
        raise StageError(
            f"device string {spec.text!r} names no serial port; write e.g. '{spec.kind}:///dev/ttyUSB0', "
            f"or run `rig stage-sim {spec.kind}` to get a simulated one"
        )
    return spec.path


# --- the device-string options (docs/stages.md has the tables) --------------------------------------

BAUD = Option("baud", int, 115200, POSITIVE, "baud", "serial speed")
OFFSET_M = Option("offset_m", float, 0.3, AT_LEAST_0, "m", "camera-to-wall distance with the carriage at rail zero")
DIRECTION = Option("direction", int, 1, one_of(1, -1), "",
                   "1: moving away from rail zero moves the camera away from the wall; -1: towards it")
SETTLE = Option("settle", float, 0.2, AT_LEAST_0, "s", "wait after a move before reading the position back")
TOLERANCE_MM = Option("tolerance_mm", float, 1.0, POSITIVE, "mm",
                      "largest accepted difference between commanded and measured position")
TRAVEL_MM = Option("travel_mm", float, None, POSITIVE, "mm", "narrow the travel", example=1000,
                   absent="what the controller allows")
TIMEOUT_S = Option("timeout_s", float, 2.0, POSITIVE, "s", "how long to wait for any reply")
HOME_TIMEOUT_S = Option("home_timeout_s", float, 120.0, POSITIVE, "s", "how long homing may take")
POLL_S = Option("poll_s", float, 0.05, POSITIVE, "s", "interval between position reads while moving")

GRBL_OPTIONS = OptionTable("grbl", "stage", (
    BAUD,
    OFFSET_M,
    DIRECTION,
    Option("feed", float, 3000.0, POSITIVE, "mm/min", "feed rate of moves, capped at the controller's $110"),
    SETTLE,
    TOLERANCE_MM,
    TRAVEL_MM,
    Option("rail_min_mm", float, None, None, "mm",
           "with travel_mm: the rail is machine X rail_min_mm .. rail_min_mm + travel_mm, +X away from rail zero",
           example=0, absent="read from the controller"),
    Option("homing", bool, True, None, "", "1: home with $H; 0: no home switch, only unlock with $X"),
    TIMEOUT_S,
    HOME_TIMEOUT_S,
    POLL_S,
    Option("stall_s", float, 3.0, POSITIVE, "s", "a move is stuck when X has not changed for this long while running"),
), path="serial port", error=StageError)

ZABER_OPTIONS = OptionTable("zaber", "stage", (
    BAUD,
    Option("device", int, 1, POSITIVE, "", "device number in the daisy chain"),
    Option("axis", int, 1, POSITIVE, "", "axis on the device"),
    Option("microstep_um", float, 0.1905, POSITIVE, "um",
           "the datasheet's microstep size (default resolution), scaled by the device's resolution"),
    Option("deviceid", int, None, POSITIVE, "", "the device id the stage must have (get deviceid)",
           example=50081, absent="any"),
    OFFSET_M,
    DIRECTION,
    SETTLE,
    TOLERANCE_MM,
    replace(TRAVEL_MM, absent="read from the device"),
    TIMEOUT_S,
    HOME_TIMEOUT_S,
    Option("move_timeout_s", float, 60.0, POSITIVE, "s", "how long a move may take"),
    POLL_S,
), path="serial port", error=StageError)
