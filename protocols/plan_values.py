"""A plan's values: each parameter described once (`ProtocolParam`), checked wherever it comes from (TOML, the
command line, the TUI's form, Python), and read from text by one parser (`ProtocolParam.parse`).

A wrong type, a NaN or a value outside what any rig can do is a ValueError naming the parameter, the value and
the range. TOML has no integer-valued floats, so `frames = 1e3` reads as 1000.0: whole numbers given as floats
are accepted; 2.5 frames is not.

Text (an option's value, a form field) is read by the parameter's type: a number, a whole number, on/off, or a
list of numbers written `0.5, 1.0, 1.5` or as an inclusive range `START:STOP:STEP` (`0.5:3.0:0.25`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

#: frames in one capture: a variance needs at least two
FRAMES = (2, 1_000_000)
#: a camera-to-wall distance, m
DISTANCE_M = (0.05, 100.0)
#: the most values a range START:STOP:STEP may give
MAX_RANGE_VALUES = 10_000

#: a parameter's check: (where, name, value) -> the value as the plan records it; raises ValueError
Check = Callable[[str, str, Any], Any]


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


def between(lo: float, hi: float, unit: str = "") -> Check:
    """The check of a number in [lo, hi] `unit`."""
    return lambda where, name, value: number(where, name, value, lo, hi, unit)


def whole_between(lo: int, hi: int, why: str = "") -> Check:
    """The check of a whole number in [lo, hi]."""
    return lambda where, name, value: whole(where, name, value, lo, hi, why)


def any_number(where: str, name: str, value: Any) -> float:
    return number(where, name, value, -math.inf, math.inf)


def any_whole(where: str, name: str, value: Any) -> int:
    return whole(where, name, value, -(2 ** 63), 2 ** 63 - 1)


def numbers(where: str, name: str, value: Any) -> list[float]:
    """A list of finite numbers (not a string)."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
        raise ValueError(f"{where}: {name} = {value!r} must be a list of numbers, e.g. [0.5, 0.75, 1.0]")
    return [any_number(where, name, v) for v in value]


#: the types a parameter may have, and the check of a parameter that gives none
TYPES: dict[type, Check] = {float: any_number, int: any_whole, bool: flag, list: numbers}


# -- text ---------------------------------------------------------------------------------------


def parse_numbers(text: str) -> list[float]:
    """'0.5, 1.0, 1.5' (commas or semicolons) or an inclusive range 'START:STOP:STEP' ('0.5:3:0.25');
    ValueError for anything else."""
    text = text.strip()
    try:
        if ":" not in text:
            return [float(x) for x in text.replace(";", ",").split(",") if x.strip()]
        parts = [float(x) for x in text.split(":")]
    except ValueError:
        raise ValueError("") from None  # not numbers: the caller says what to write
    if len(parts) != 3 or not all(math.isfinite(x) for x in parts):
        raise ValueError("a range is START:STOP:STEP")
    start, stop, step = parts
    if step <= 0 or stop < start:
        raise ValueError("a range needs STEP > 0 and STOP >= START")
    n = int(round((stop - start) / step))
    if n + 1 > MAX_RANGE_VALUES:
        raise ValueError(f"a range of more than {MAX_RANGE_VALUES} values")
    return [round(start + i * step, 6) for i in range(n + 1) if start + i * step <= stop + 1e-9]


def parse_flag(text: str) -> bool:
    words = {"on": True, "off": False, "true": True, "false": False, "yes": True, "no": False, "1": True, "0": False}
    try:
        return words[text.strip().lower()]
    except KeyError:
        raise ValueError from None


# -- one parameter --------------------------------------------------------------------------------


@dataclass(frozen=True)
class ProtocolParam:
    """One parameter of a protocol, described once: the command line, experiment files, the TUI's form and the
    checks of every plan are made from this.

    type: float, int, bool, or list (of numbers); default: the value when none is given; unit: its unit in words
    ("m", "us", "" for none); label: the form's label ("Stops [m]"); help: a few words for `rig run --help`;
    check: (where, name, value) -> the value checked (plan_values.between, frames, ...; None: the type's own);
    option: rig run's option ("" -> --name-with-dashes); old_names: names it had before, still read from
    experiment files and recordings; form: shown on the TUI's form (else a loaded file's value is kept as it is).
    """

    name: str
    type: type
    default: Any
    unit: str = ""
    label: str = ""
    help: str = ""
    check: Check | None = None
    option: str = ""
    old_names: tuple[str, ...] = ()
    form: bool = True

    @property
    def cli_option(self) -> str:
        return self.option or "--" + self.name.replace("_", "-")

    @property
    def form_label(self) -> str:
        return self.label or self.name

    def checked(self, where: str, value: Any) -> Any:
        """The value as the plan records it; ValueError naming `where`, the parameter and the range."""
        return (self.check or TYPES[self.type])(where, self.name, value)

    def takes(self) -> str:
        """What the parameter's text is, in words."""
        unit = f" in {self.unit}" if self.unit else ""
        if self.type is list:
            return f"{'distances' if self.unit == 'm' else 'numbers'}{unit}"
        return {float: f"a number{unit}", int: "a whole number", bool: "on or off"}[self.type]

    def parse(self, text: str) -> Any:
        """The value typed as text (an option, a form field), by the parameter's type; ValueError saying what to
        type instead (unchecked: `checked` says whether the value is in range)."""
        t = text.strip()
        try:
            if self.type is list:
                return parse_numbers(t)
            if self.type is bool:
                return parse_flag(t)
            return self.type(t)
        except ValueError as e:
            if self.type is list:
                why = f" ({e})" if str(e) else ""
                raise ValueError(f"{text!r}{why}: write {self.takes()} separated by commas (0.5, 1.0, 1.5) or a "
                                 "range START:STOP:STEP (0.5:3.0:0.25)") from None
            if not t:
                raise ValueError(f"give {self.takes()}") from None
            raise ValueError(f"{text!r} is not {self.takes()}") from None

    def text(self, value: Any) -> str:
        """The value as the form shows it (parse reads it back)."""
        if self.type is list:
            return ", ".join(f"{v:g}" for v in value)
        if self.type is bool:
            return "on" if value else "off"
        return f"{value:g}" if isinstance(value, float) else str(value)
