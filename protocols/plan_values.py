"""Checks of a plan's values, wherever they come from (TOML, the command line, Python): a wrong type,
a NaN or a value outside what any rig can do is a ValueError naming the parameter, the value and the range.

TOML has no integer-valued floats, so `frames = 1e3` reads as 1000.0: whole numbers given as floats
are accepted; 2.5 frames is not.
"""

from __future__ import annotations

import math
from typing import Any

#: frames in one capture: a variance needs at least two
FRAMES = (2, 1_000_000)
#: a camera-to-wall distance, m
DISTANCE_M = (0.05, 100.0)


def number(where: str, name: str, value: Any, lo: float, hi: float, unit: str = "") -> float:
    """A finite number in [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: {name} = {value!r} is not a number; give {name} in {unit or 'its units'} "
                         f"({lo:g} to {hi:g})")
    v = float(value)
    if not math.isfinite(v) or not lo <= v <= hi:
        raise ValueError(f"{where}: {name} = {value!r} is outside {lo:g} to {hi:g}{' ' + unit if unit else ''}")
    return v


def whole(where: str, name: str, value: Any, lo: int, hi: int, why: str = "") -> int:
    """A whole number in [lo, hi] (an integral float such as 1e3 is accepted); `why` explains the range."""
    try:
        v = number(where, name, value, lo, hi)
    except ValueError as e:
        raise ValueError(f"{e}{'; ' + why if why else ''}") from None
    if v != int(v):
        raise ValueError(f"{where}: {name} = {value!r} is not a whole number")
    return int(v)


def flag(where: str, name: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{where}: {name} = {value!r} must be true or false")
    return value


def frames(where: str, name: str, value: Any) -> int:
    """A number of frames to capture for one variance (FRAMES)."""
    return whole(where, name, value, *FRAMES, "at least 2 frames are needed for a variance")


def distance_m(where: str, name: str, value: Any) -> float:
    """A camera-to-wall distance in m (DISTANCE_M)."""
    return number(where, name, value, *DISTANCE_M, "m")
