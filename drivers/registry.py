"""Device strings and the kinds of camera and stage they name.

Device strings look like URLs: `fake:`, `fake:width=424,height=240`, `none:`,
`grbl:///dev/ttyUSB0?baud=115200`, `zaber:///dev/ttyUSB0`, `realsense:serial=123`.
The part before the first colon picks the kind; the rest is either `//path?key=value&...`
or `key=value,key=value`.

A kind maps to a factory named as a `"module:function"` string (imported only when that
kind is used), so a driver exists without importing anything above it. Built-in kinds are
listed here; an installed package adds kinds through the entry-point groups `rig.cameras`
and `rig.stages` (`[project.entry-points."rig.cameras"] mycam = "mypkg.camera:open_camera"`).

A factory is called as `factory(spec, context)`: `spec` is the parsed `DeviceSpec`,
`context` a dict shared by the camera and stage built together (the simulated devices keep
their common world in it).

Each kind declares its options once, as an `OptionTable` (drivers.options), and reads them with
`spec.take(TABLE)`, which refuses an unknown key (suggesting the nearest known one) or a bad value
in one line. `option_table(what, kind)` finds a kind's table (for `rig devices --options KIND`): the
built-in ones are named in CAMERA_OPTIONS and STAGE_OPTIONS, a plugin's factory may carry its own
as the attribute `options`.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Callable
from urllib.parse import unquote_plus, urlsplit

from .errors import DeviceError
from .options import OptionTable

#: built-in camera kinds: kind -> "module:factory"
CAMERA_KINDS = {
    "fake": "fakes.devices:fake_camera",
    "realsense": "drivers.realsense:open_realsense",
    "oak": "drivers.oak:open_oak",
}
#: built-in stage kinds: kind -> "module:factory"
STAGE_KINDS = {
    "fake": "fakes.devices:fake_stage",
    "none": "drivers.stage:no_stage",
    "grbl": "drivers.serial.grbl:open_grbl",
    "zaber": "drivers.serial.zaber:open_zaber",
}
ENTRY_POINT_GROUPS = {"camera": "rig.cameras", "stage": "rig.stages"}
#: the option table of each built-in kind: kind -> "module:TABLE"
CAMERA_OPTIONS = {
    "fake": "fakes.camera:FAKE_CAMERA_OPTIONS",
    "realsense": "drivers.realsense.camera:REALSENSE_OPTIONS",
    "oak": "drivers.oak:OAK_OPTIONS",
}
STAGE_OPTIONS = {
    "fake": "fakes.devices:FAKE_STAGE_OPTIONS",
    "none": "drivers.stage:NO_STAGE_OPTIONS",
    "grbl": "drivers.serial.rail:GRBL_OPTIONS",
    "zaber": "drivers.serial.rail:ZABER_OPTIONS",
}


@dataclass
class DeviceSpec:
    """A parsed device string: kind, optional path, options."""

    kind: str
    path: str = ""
    options: dict[str, str] = field(default_factory=dict)
    text: str = ""

    @classmethod
    def parse(cls, text: str) -> "DeviceSpec":
        if ":" not in text:
            raise DeviceError(
                f"device string {text!r} has no kind; write it as KIND:OPTIONS, e.g. 'fake:' or 'grbl:///dev/ttyUSB0'"
            )
        kind, rest = text.split(":", 1)
        kind = kind.strip().lower()
        if rest.startswith("//"):
            parts = urlsplit(text)
            path = (parts.netloc + parts.path) if parts.netloc else parts.path
            options: dict[str, str] = {}
            for item in filter(None, parts.query.split("&")):
                if "=" not in item:
                    raise DeviceError(f"device string {text!r}: option {unquote_plus(item)!r} is not KEY=VALUE; "
                                      f"write e.g. '{kind}:///dev/ttyUSB0?offset_m=0.3'")
                key, value = item.split("=", 1)
                _add_option(options, unquote_plus(key).strip(), unquote_plus(value), text)
            return cls(kind, path, options, text)
        options = {}
        for item in filter(None, (p.strip() for p in _split_options(rest))):
            if "=" not in item:
                raise DeviceError(f"device string {text!r}: option {item!r} is not KEY=VALUE; write e.g. 'fake:width=424'")
            key, value = item.split("=", 1)
            _add_option(options, key.strip(), value.strip(), text)
        return cls(kind, "", options, text)

    def take(self, table: OptionTable) -> dict[str, Any]:
        """Every option of `table`: those this string gives, parsed and checked, and the defaults of the others.

        Refuses in one line (the table's error class) a key the table lacks, with the nearest known key and the
        list of them, a value of the wrong type or out of range, and a path for a kind that takes none."""
        return table.take(self.options, self.text, self.path)

    def float(self, key: str, default: float) -> float:
        return self._typed(key, default, float)

    def int(self, key: str, default: int) -> int:
        return self._typed(key, default, int)

    def _typed(self, key: str, default: Any, typ: Callable[[str], Any]) -> Any:
        if key not in self.options:
            return default
        try:
            return typ(self.options[key])
        except ValueError:
            raise DeviceError(f"device {self.text!r}: {key}={self.options[key]!r} is not a {typ.__name__}") from None


def _add_option(options: dict[str, str], key: str, value: str, text: str) -> None:
    """One option into `options`; a key given twice is refused (which one was meant is anyone's guess)."""
    if key in options:
        raise DeviceError(f"device string {text!r} gives {key} twice ({options[key]!r} and {value!r}); keep one")
    options[key] = value


def _split_options(text: str) -> list[str]:
    """Split at commas and ampersands outside parentheses: `effects=outliers(fraction=0.01,width_px=1),seed=2`."""
    items, depth, current = [], 0, []
    for ch in text:
        if ch in "(":
            depth += 1
        elif ch == ")":
            depth = max(depth - 1, 0)
        if ch in ",&" and depth == 0:
            items.append("".join(current))
            current = []
        else:
            current.append(ch)
    items.append("".join(current))
    return items


Factory = Callable[[DeviceSpec, dict[str, Any]], Any]


def kinds(what: str) -> dict[str, str]:
    """Every kind of `what` ("camera" or "stage"): the built-in ones and those of installed plugins."""
    table = dict(CAMERA_KINDS if what == "camera" else STAGE_KINDS)
    for ep in entry_points(group=ENTRY_POINT_GROUPS[what]):
        table.setdefault(ep.name, ep.value)
    return table


def factory(what: str, kind: str, text: str = "") -> Factory:
    """The factory for a kind; a one-line DeviceError for a kind nobody provides."""
    table = kinds(what)
    if kind not in table:
        known = ", ".join(sorted(k + ":" for k in table))
        where = f" in {text!r}" if text else ""
        raise DeviceError(f"unknown {what} kind {kind!r}{where}; known kinds: {known}")
    module_name, _, attr = table[kind].partition(":")
    obj: Any = importlib.import_module(module_name)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def option_table(what: str, kind: str) -> OptionTable | None:
    """The option table of a kind of `what` ("camera" or "stage"); None for a plugin's kind that declares none."""
    make = factory(what, kind)
    if isinstance(getattr(make, "options", None), OptionTable):
        return make.options  # type: ignore[attr-defined]
    where = (CAMERA_OPTIONS if what == "camera" else STAGE_OPTIONS).get(kind)
    if where is None:
        return None
    module_name, _, attr = where.partition(":")
    return getattr(importlib.import_module(module_name), attr)


def build(what: str, text: str, context: dict[str, Any] | None = None) -> Any:
    """A camera or stage (unopened) from its device string."""
    spec = DeviceSpec.parse(text)
    return factory(what, spec.kind, text)(spec, context if context is not None else {})
