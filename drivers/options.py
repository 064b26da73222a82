"""The options a device string may carry, declared once per kind, and the one parser that reads them.

A driver lists its options as an `OptionTable` of `Option`s (name, type, default, accepted values,
unit, help) and reads a device string with `DeviceSpec.take(TABLE)` (drivers.registry), which
returns {name: value} for every option of the table: the value given, else the default. It refuses,
in one line naming the problem and the fix:

- a key the table does not have, with the nearest known key (`did you mean offset_m?`) and the list;
- a value of the wrong type (`baud='fast' is not a whole number`), an empty value, nan or inf;
- a value outside the option's range (`feed must be positive, not 0`);
- a path (`kind:///...`) for a kind whose table says it takes none.

The error is the table's `error` class (StageError for stages, CameraError for cameras). The same
table prints itself (`OptionTable.lines`, `rig devices --options KIND`), so names, defaults and
units are written in one place per driver.

    RAIL = OptionTable("grbl", "stage", (
        Option("offset_m", float, 0.3, AT_LEAST_0, "m", "camera-to-wall distance at rail zero"),
        Option("direction", int, 1, one_of(1, -1), "", "+1: away from home is away from the wall"),
    ), path="serial port", error=StageError)
    values = spec.take(RAIL)          # {"offset_m": 0.3, "direction": 1}
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping, Type

from .errors import DeviceError

#: the words a flag (type bool) accepts, lower case
TRUE_WORDS = ("1", "on", "true", "yes")
FALSE_WORDS = ("0", "off", "false", "no")


@dataclass(frozen=True)
class Check:
    """A condition on a parsed value, and how to say it ("positive", "1 or -1", "0 to 1")."""

    test: Callable[[Any], bool]
    text: str

    def __call__(self, value: Any) -> bool:
        return bool(self.test(value))


def at_least(low: float) -> Check:
    return Check(lambda v: v >= low, f"at least {low:g}")


def between(low: float, high: float) -> Check:
    return Check(lambda v: low <= v <= high, f"{low:g} to {high:g}")


def below(low: float, high: float) -> Check:
    """low <= value < high."""
    return Check(lambda v: low <= v < high, f"{low:g} to below {high:g}")


def one_of(*values: Any) -> Check:
    words = [repr(v) if isinstance(v, str) else f"{v:g}" for v in values]
    text = words[0] if len(words) == 1 else ", ".join(words[:-1]) + " or " + words[-1]
    return Check(lambda v: v in values, text)


POSITIVE = Check(lambda v: v > 0, "positive")
AT_LEAST_0 = at_least(0)

_TYPE_WORDS = {float: "a number", int: "a whole number", bool: "1 or 0", str: "text"}


@dataclass(frozen=True)
class Option:
    """One key of a device string.

    type: float, int, bool (a flag: 1/0, on/off, true/false, yes/no) or str.
    default: the value when the key is absent (None: the driver decides, as `absent` says).
    check: the values accepted besides the type (None: any value of the type).
    unit: of the value, for the help and the messages ("m", "mm/min", "s").
    example: a value to suggest in messages (default: the default).
    absent: what None as the default means, e.g. "read from the controller".
    """

    name: str
    type: Type[Any]
    default: Any
    check: Check | None = None
    unit: str = ""
    help: str = ""
    example: Any = None
    absent: str = ""

    def parse(self, raw: str, text: str, error: Type[DeviceError]) -> Any:
        """The value of `raw` for this option; a one-line `error` if it is not one."""
        value: Any = raw.strip()
        if not value:
            if self.type is str:  # `serial=` is no serial
                return self.default
            raise error(f"device {text!r}: {self.name} has no value; {self.fix()}")
        if self.type is bool:
            if value.lower() not in TRUE_WORDS + FALSE_WORDS:
                raise error(f"device {text!r}: {self.name}={raw!r} is not 1 or 0; write {self.name}=1 or "
                            f"{self.name}=0 (on/off, true/false and yes/no work too)")
            value = value.lower() in TRUE_WORDS
        elif self.type is not str:
            try:
                value = self.type(value)
            except ValueError:
                raise error(f"device {text!r}: {self.name}={raw!r} is not {_TYPE_WORDS[self.type]}; {self.fix()}") from None
            if isinstance(value, float) and not math.isfinite(value):
                raise error(f"device {text!r}: {self.name}={raw.strip()} is not a finite number; {self.fix()}")
        if self.check is not None and not self.check(value):
            shown = repr(value) if isinstance(value, str) else _show(value)
            raise error(f"device {text!r}: {self.name} must be {self.check.text}, not {shown}; {self.fix()}")
        return value

    def fix(self) -> str:
        """What to write instead: 'give e.g. feed=3000 (mm/min, the default)'."""
        example = self.default if self.example is None else self.example
        if self.type is bool and example is not None:
            example = int(example)
        unit = self.unit if self.unit != self.name else ""
        notes = [n for n in (unit, "the default" if example == self.default else "") if n]
        fix = f"give e.g. {self.name}={_show(example)}" + (f" ({', '.join(notes)})" if notes else "")
        if self.default is None and self.absent:
            fix += f", or leave it out ({self.absent})"
        return fix

    def default_text(self) -> str:
        if self.default is None:
            return f"({self.absent})" if self.absent else "-"
        shown = _show(int(self.default) if self.type is bool else self.default)
        return f"{shown} {self.unit}".strip() if shown != "" else "''"


@dataclass(frozen=True)
class OptionTable:
    """The options of one device kind, and what the `//path` part of its device string names ('' if none)."""

    kind: str
    what: str  # "camera" or "stage"
    options: tuple[Option, ...]
    path: str = ""
    error: type[DeviceError] = DeviceError
    by_name: dict[str, Option] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        by_name = {o.name: o for o in self.options}
        if len(by_name) != len(self.options):
            raise ValueError(f"{self.kind}: an option is declared twice")
        object.__setattr__(self, "by_name", by_name)

    def names(self) -> list[str]:
        return sorted(self.by_name)

    def defaults(self) -> dict[str, Any]:
        return {o.name: o.default for o in self.options}

    def take(self, options: Mapping[str, str], text: str = "", path: str = "") -> dict[str, Any]:
        """{name: value} for every option: the given ones parsed and checked, the others their defaults."""
        text = text or f"{self.kind}:" + ",".join(f"{k}={v}" for k, v in options.items())
        if path and not self.path:
            raise self.error(f"device {text!r}: the {self.kind} {self.what} takes no path ({path!r}); write "
                             f"{self.kind}:KEY=VALUE,... with {self.takes()}")
        unknown = [k for k in options if k not in self.by_name]
        if unknown:
            raise self.error(self.unknown_message(unknown, text))
        values = self.defaults()
        for key, raw in options.items():
            values[key] = self.by_name[key].parse(raw, text, self.error)
        return values

    def unknown_message(self, unknown: Iterable[str], text: str) -> str:
        unknown = list(unknown)
        names = ", ".join(repr(k) for k in unknown)
        message = f"unknown option{'s' if len(unknown) > 1 else ''} {names} in {text!r}"
        near = [(k, m[0]) for k in unknown if (m := difflib.get_close_matches(k, self.names(), n=1, cutoff=0.6))]
        if len(near) == 1 and len(unknown) == 1:
            message += f"; did you mean {near[0][1]}? It takes"
        elif near:
            message += "; did you mean " + ", ".join(f"{m} (for {k})" for k, m in near) + "? It takes"
        else:
            message += "; it takes"
        return message + (": " + ", ".join(self.names()) if self.options else " no options")

    def takes(self) -> str:
        return "options " + ", ".join(self.names()) if self.options else "no options"

    def lines(self) -> list[str]:
        """The table as text: one line per option (name, default, accepted values, meaning)."""
        form = (f"{self.kind}:///PATH?KEY=VALUE&... (PATH: {self.path}) or " if self.path else "") + f"{self.kind}:KEY=VALUE,..."
        out = [f"{self.kind} {self.what}: {form}"]
        if not self.options:
            return out + ["  (no options)"]
        rows = [(o.name, o.default_text(), _accepts(o), o.help) for o in self.options]
        widths = [max(len(r[i]) for r in rows) for i in range(3)]
        for r in rows:
            out.append("  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)) + "  " + r[3])
        return out


def _accepts(option: Option) -> str:
    word = {float: "number", int: "integer", bool: "1/0", str: "text"}[option.type]
    return f"{word}, {option.check.text}" if option.check is not None else word


def _show(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)
