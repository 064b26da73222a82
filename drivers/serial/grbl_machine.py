"""What a GRBL 1.1 controller's settings (`$$`) and build options (`$I`) imply for a linear stage on X.

Machine space follows the firmware (grbl/limits.c, limits_go_home and system_check_travel_limits; gnea/grbl
wiki, settings.md): homing seeks the switch towards +X unless $23 bit 0 is set, pulls off $27 mm, and leaves
MPos at 0 when built with HOMING_FORCE_SET_ORIGIN (`Z` among `$I`'s OPT letters), else at -$27 (homing to
+X) or -$130+$27 (to -X); soft limits allow -$130..0, or 0..$130 with HOMING_FORCE_SET_ORIGIN homing to -X.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

#: the settings the driver reads: $10 status mask, $13 inches, $20 soft limits, $22 homing, $23 homing
#: direction, $27 pull-off, $110 X max rate, $120 X acceleration, $130 X max travel
REQUIRED = (10, 13, 20, 22, 23, 27, 110, 120, 130)


@dataclass(frozen=True)
class RailGeometry:
    """Machine X of rail zero (where homing leaves the carriage, or MPos 0 without homing), the sign of
    machine X moving away from it, and how far the rail goes that way, mm."""

    home_mm: float
    away: int
    travel_mm: float


def parse_settings(lines: list[str]) -> dict[int, float]:
    """`$N=value` lines -> {N: value}."""
    out: dict[int, float] = {}
    for text in lines:
        match = re.fullmatch(r"\$(\d+)=([-\d.]+)", text)
        if match:
            out[int(match.group(1))] = float(match.group(2))
    return out


def force_origin(options: str) -> bool:
    """True if the firmware was built with HOMING_FORCE_SET_ORIGIN (`Z` in the OPT letters)."""
    return "Z" in options.split(",")[0]


def soft_limit_window(settings: dict[int, float], options: str) -> tuple[float, float]:
    """The machine X that soft limits ($20=1) allow, mm (limits.c, system_check_travel_limits): -$130..0,
    or 0..$130 with HOMING_FORCE_SET_ORIGIN and homing towards -X ($23 bit 0 set)."""
    travel = settings[130]
    towards_plus = not int(settings.get(23, 0)) & 1
    return (0.0, travel) if force_origin(options) and not towards_plus else (-travel, 0.0)


def rail_geometry(settings: dict[int, float], options: str, *, homing: bool) -> RailGeometry:
    travel = settings[130]
    if not homing:
        return RailGeometry(0.0, 1, travel)
    towards_plus = not int(settings[23]) & 1
    if force_origin(options):
        home = 0.0
    else:
        home = -settings[27] if towards_plus else -travel + settings[27]
    low, high = soft_limit_window(settings, options)
    away = -1 if towards_plus else 1
    return RailGeometry(home, away, (home - low) if away < 0 else (high - home))


def travel_note(settings: dict[int, float], options: str) -> str:
    """Why a target can be beyond the soft limits: the travel the controller allows, in words."""
    if 130 not in settings:
        return ""
    towards = "+X" if not int(settings.get(23, 0)) & 1 else "-X"
    built = "with" if force_origin(options) else "without"
    low, high = soft_limit_window(settings, options)
    return (f"; the controller allows machine X only within {low:g}..{high:g} mm ($130={settings[130]:g}, homing "
            f"towards {towards} {built} HOMING_FORCE_SET_ORIGIN)")


def move_time_s(distance_mm: float, feed_mm_min: float, accel_mm_s2: float) -> float:
    """How long a move should take at feed_mm_min with a trapezoidal ramp at accel_mm_s2, s."""
    v = feed_mm_min / 60.0
    return distance_mm / v + (v / accel_mm_s2 if accel_mm_s2 > 0 else 0.0)
