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
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Callable
from urllib.parse import parse_qsl, urlsplit

from .errors import DeviceError

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
            return cls(kind, path, dict(parse_qsl(parts.query)), text)
        options: dict[str, str] = {}
        for item in filter(None, (p.strip() for p in _split_options(rest))):
            if "=" not in item:
                raise DeviceError(f"device string {text!r}: option {item!r} is not KEY=VALUE; write e.g. 'fake:width=424'")
            key, value = item.split("=", 1)
            options[key.strip()] = value.strip()
        return cls(kind, "", options, text)

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


def build(what: str, text: str, context: dict[str, Any] | None = None) -> Any:
    """A camera or stage (unopened) from its device string."""
    spec = DeviceSpec.parse(text)
    return factory(what, spec.kind, text)(spec, context if context is not None else {})
