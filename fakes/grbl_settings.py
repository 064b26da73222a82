"""GRBL 1.1h settings as the firmware stores and prints them (gnea/grbl wiki, settings.md; grbl/defaults.h,
DEFAULTS_GENERIC), and the reports built from them.

`$$` prints every setting as `$N=value`, integers bare and reals with three decimals (report.c,
report_grbl_settings); `$N=value` writes one (error:3 for no such setting, error:4 for a negative value,
error:10 for soft limits without homing).
"""

from __future__ import annotations

#: GRBL 1.1h's defaults (defaults.h, DEFAULTS_GENERIC): number -> value
STOCK: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0,
    20: 0, 21: 0, 22: 0, 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0, 32: 0,
    100: 250.0, 101: 250.0, 102: 250.0, 110: 500.0, 111: 500.0, 112: 500.0,
    120: 10.0, 121: 10.0, 122: 10.0, 130: 200.0, 131: 200.0, 132: 200.0,
}
#: the settings GRBL stores as integers (masks and flags); the rest are reals
INTEGER = {0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32}


def settings_lines(settings: dict[int, float]) -> list[str]:
    """The `$$` reply (without its closing ok)."""
    return [f"${n}={int(v)}" if n in INTEGER else f"${n}={v:.3f}" for n, v in sorted(settings.items())]


def write_setting(settings: dict[int, float], n: int, text: str) -> str | None:
    """Apply `$n=text`; None if accepted, else the error line GRBL prints."""
    if n not in settings:
        return "error:3"
    try:
        value = float(text)
    except ValueError:
        return "error:2"
    if value < 0:
        return "error:4"
    if n == 20 and value and not settings[22]:
        return "error:10"  # soft limits need homing (settings.c)
    settings[n] = int(value) if n in INTEGER else value
    return None


def rate_text(feed_mm_min: float, report_inches: bool) -> str:
    """A feed rate as report.c prints it (printFloat_RateValue): mm/min with no decimals, or with $13=1
    inches/min with one."""
    return f"{feed_mm_min / 25.4:.1f}" if report_inches else f"{feed_mm_min:.0f}"


def parser_state(*, motion: int, inches: bool, relative: bool, feed_mm_min: float, report_inches: bool) -> str:
    """The `$G` reply line: the active modal state (report.c, report_gcode_modes); the feed in the units
    $13 reports in."""
    return (f"[GC:G{motion} G54 G17 {'G20' if inches else 'G21'} {'G91' if relative else 'G90'} G94 M5 M9 T0 "
            f"F{rate_text(feed_mm_min, report_inches)} S0]")


def offsets_lines() -> list[str]:
    """The `$#` reply: coordinate offsets (all zero here), G28/G30 positions, G92, tool length, last probe."""
    zero = "0.000,0.000,0.000"
    return [*(f"[G{n}:{zero}]" for n in (54, 55, 56, 57, 58, 59, 28, 30, 92)), "[TLO:0.000]", f"[PRB:{zero}:0]"]
