"""Rail geometry shared by the serial stages, and the device-string options both take.

Both map the camera-to-wall distance to the rail the same way:
rail_mm = direction * (position_m - offset_m) * 1000, where offset_m is the distance when the
carriage is at rail zero (the home switch) and direction is +1 if moving away from home moves
the camera away from the wall, -1 otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import StageError
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


def direction_option(spec: DeviceSpec) -> int:
    direction = spec.int("direction", 1)
    if direction not in (1, -1):
        raise StageError(f"device {spec.text!r}: direction must be 1 or -1, not {direction}")
    return direction


def positive_option(spec: DeviceSpec, key: str, default: float) -> float:
    value = spec.float(key, default)
    if not value > 0:
        raise StageError(f"device {spec.text!r}: {key} must be positive, not {value}")
    return value
