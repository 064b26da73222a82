"""Device strings, and the kinds of camera and stage they name: every kind is an entry point.

Device strings look like URLs: `fake:`, `fake:width=424,height=240`, `none:`,
`grbl:///dev/ttyUSB0?baud=115200`, `zaber:///dev/ttyUSB0`, `realsense:serial=123`.
The part before the first colon picks the kind; the rest is either `//path?key=value&...`
or `key=value,key=value`.

A kind is described once, by a `DeviceKind` beside its driver: its factory, its device-string options
(an `OptionTable`, drivers.options), its probe (what `rig devices` lists as attached), and for a camera the
settings it takes and its gain unit (`GainScale`: gain is given in rig's unit, 16 = x1, on every camera, so the
default plan runs on any of them). Kinds are found through the entry-point groups `rig.cameras` and
`rig.stages`, rig's own (in its pyproject.toml, the simulator's included) exactly as an installed plugin's:

    [project.entry-points."rig.cameras"]
    mycam = "mypkg.camera:MYCAM"          # a DeviceKind; a bare factory function works too

Nothing here names a kind, and loading one imports only its module. After adding an entry point to an
editable install, install it again (`pip install -e .`; `python3 dev.py` does when pyproject.toml changes).

A factory is called as `factory(spec, context)`: `spec` is the parsed `DeviceSpec`, `context` a dict shared by
the camera and stage built together. A factory may append to `context[ON_BUILT]` a function `hook(devices)`,
called once both are built with an object whose `camera` and `stage` it may replace and whose `clock` it may set
(a function that waits by advancing a simulated clock instead of sleeping): the simulated camera uses it to make
its wall follow a real stage and to run a simulated rig on its own clock (fakes.devices).

Each kind reads its options with `spec.take(TABLE)`, which refuses an unknown key (suggesting the nearest known
one) or a bad value in one line.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Callable
from urllib.parse import unquote_plus, urlsplit

from .camera import GainScale
from .errors import DeviceError
from .options import OptionTable

ENTRY_POINT_GROUPS = {"camera": "rig.cameras", "stage": "rig.stages"}
#: the key of `context` under which factories leave hooks for when both devices are built
ON_BUILT = "on_built"
#: one device a probe found: display fields (camera: kind, model, serial, firmware, usb; serial port: port,
#: description, usb, serial, protocol, adapter) and "string", the device string that opens it
Found = dict[str, str]


@dataclass(frozen=True)
class Probe:
    """What is attached of some kinds: `run()` lists it (a `Found` per device) within a few seconds, or raises a
    one-line DeviceError (e.g. its SDK is missing). Kinds that share a bus share a probe (the serial stages)."""

    name: str
    run: Callable[[], list[Found]] | str  # or "module:function", imported when it runs

    def __call__(self) -> list[Found]:
        return _resolve(self.run)()


@dataclass(frozen=True)
class DeviceKind:
    """One kind of camera or stage, all rig needs to know of it. Fields given as "module:attr" are imported on use.

    name: the kind in device strings (`realsense` in `realsense:serial=1`); what: "camera" or "stage".
    factory: `factory(spec, context)` builds the device, unopened.
    options: its device-string options (`rig devices --options KIND`); None if it declares none.
    probe: what `rig devices` lists as attached; None if it cannot tell (a simulator).
    summary: a few words for listings; simulated: a simulator, suggested when nothing is attached.
    exposure_us: (cameras) the exposure range it takes, in us.
    gain: (cameras) its own gain unit and range, mapped to rig's (16 = x1).
    """

    name: str
    what: str
    factory: Callable[..., Any] | str
    options: OptionTable | str | None = None
    probe: Probe | None = None
    summary: str = ""
    simulated: bool = False
    exposure_us: tuple[float, float] = (1.0, 200_000.0)
    gain: GainScale = field(default_factory=GainScale)

    def make(self) -> Callable[..., Any]:
        return _resolve(self.factory)

    def option_table(self) -> OptionTable | None:
        table = _resolve(self.options) if isinstance(self.options, str) else self.options
        if table is None:  # a bare factory may carry its table as the attribute `options`
            table = getattr(self.make(), "options", None)
        return table if isinstance(table, OptionTable) else None

    def settings_text(self) -> str:
        """What settings a camera takes, in rig's units ('' for a stage)."""
        if self.what != "camera":
            return ""
        lo, hi = self.exposure_us
        return f"settings: exposure {lo:g}-{hi:g} us; gain {self.gain.text()}"


def _resolve(ref: Any) -> Any:
    """`ref` itself, or the object a "module:attr.attr" string names."""
    if not isinstance(ref, str):
        return ref
    module_name, _, attr = ref.partition(":")
    obj: Any = importlib.import_module(module_name)
    for part in filter(None, attr.split(".")):
        obj = getattr(obj, part)
    return obj


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
                if item.startswith("/") or item[:3].upper() == "COM":  # a port where the URL form wants //: say that
                    raise DeviceError(f"device string {text!r}: {item!r} looks like a port; write it after '//', as "
                                      f"'{kind}://{item}' (a path gives three slashes)")
                port = "" if kind in ("fake", "none") else f", or a port as '{kind}:///dev/ttyUSB0'"
                raise DeviceError(f"device string {text!r}: option {item!r} is not KEY=VALUE; write e.g. "
                                  f"'{kind}:KEY=VALUE' ('fake:width=424'){port}")
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


def kind_names(what: str) -> list[str]:
    """The names of every kind of `what` ("camera" or "stage"), from the entry points; nothing is imported."""
    return sorted({ep.name for ep in entry_points(group=ENTRY_POINT_GROUPS[what])})


def kinds(what: str) -> dict[str, DeviceKind]:
    """Every kind of `what`, loaded (each imports its own module only), by name."""
    return {name: kind(what, name) for name in kind_names(what)}


def kind(what: str, name: str, text: str = "") -> DeviceKind:
    """The kind `name` of `what`; a one-line DeviceError for a kind nobody provides."""
    found = [ep for ep in entry_points(group=ENTRY_POINT_GROUPS[what]) if ep.name == name]
    if not found:
        known = kind_names(what)
        where = f" in {text!r}" if text else ""
        listed = ", ".join(k + ":" for k in known) if known else (
            "none (rig's own are entry points: reinstall rig, e.g. pip install -e .)")
        raise DeviceError(f"unknown {what} kind {name!r}{where}; known kinds: {listed}")
    ep = found[0]
    try:
        obj = ep.load()
    except (ImportError, AttributeError) as e:
        raise DeviceError(f"the {what} kind {name!r} cannot be loaded from {ep.value!r} ({e}); reinstall the package "
                          "that provides it") from None
    if isinstance(obj, DeviceKind):
        if (obj.name, obj.what) != (name, what):
            raise DeviceError(f"the entry point {name!r} of {ENTRY_POINT_GROUPS[what]} names the {obj.what} kind "
                              f"{obj.name!r} ({ep.value}); give it the kind's own name")
        return obj
    if callable(obj):  # a bare factory: a kind with no probe
        return DeviceKind(name, what, obj, summary=(obj.__doc__ or "").strip().split("\n")[0])
    raise DeviceError(f"the {what} kind {name!r} ({ep.value}) is neither a DeviceKind nor a factory")


def factory(what: str, name: str, text: str = "") -> Factory:
    """The factory for a kind; a one-line DeviceError for a kind nobody provides."""
    return kind(what, name, text).make()


def option_table(what: str, name: str) -> OptionTable | None:
    """The option table of a kind of `what` ("camera" or "stage"); None for a plugin's kind that declares none."""
    return kind(what, name).option_table()


def build(what: str, text: str, context: dict[str, Any] | None = None) -> Any:
    """A camera or stage (unopened) from its device string."""
    spec = DeviceSpec.parse(text)
    return factory(what, spec.kind, text)(spec, context if context is not None else {})
