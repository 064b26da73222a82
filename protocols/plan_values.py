"""Checks of a plan's values, wherever they come from (TOML, the command line, Python): a wrong type,
a NaN or a value outside what any rig can do is a ValueError naming the parameter, the value and the range.

TOML has no integer-valued floats, so `frames = 1e3` reads as 1000.0: whole numbers given as floats
are accepted; 2.5 frames is not.
"""

from __future__ import annotations

import math
from typing import Any


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
