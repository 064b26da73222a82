"""Open cameras and stages from the strings users type.

Device strings look like URLs: `fake:`, `fake:width=424,height=240`, `none:`,
`grbl:///dev/ttyUSB0?baud=115200`, `zaber:///dev/ttyUSB0`, `realsense:serial=123`.
The part before the first colon picks the kind; the rest is either `//path?key=value&...`
or `key=value,key=value`.

The fake camera always needs a world to look at. When the stage is fake too they share one;
when the stage is real (or a simulated controller on a serial port), the fake camera's wall
follows the stage's measured position after each move.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable
from urllib.parse import parse_qsl, urlsplit

from drivers.camera import DepthCamera
from drivers.errors import DeviceError
from drivers.stage import NoStage, Stage


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
        for item in filter(None, (p.strip() for p in rest.replace("&", ",").split(","))):
            if "=" not in item:
                raise DeviceError(f"device string {text!r}: option {item!r} is not KEY=VALUE; write e.g. 'fake:width=424'")
            key, value = item.split("=", 1)
            options[key.strip()] = value.strip()
        return cls(kind, "", options, text)

    def float(self, key: str, default: float) -> float:
        return _typed(self, key, default, float)

    def int(self, key: str, default: int) -> int:
        return _typed(self, key, default, int)


def _typed(spec: DeviceSpec, key: str, default: Any, typ: Callable[[str], Any]) -> Any:
    if key not in spec.options:
        return default
    try:
        return typ(spec.options[key])
    except ValueError:
        raise DeviceError(f"device {spec.text!r}: {key}={spec.options[key]!r} is not a {typ.__name__}") from None


CameraFactory = Callable[[DeviceSpec, Any], DepthCamera]
StageFactory = Callable[[DeviceSpec, Any], Stage]

_CAMERAS: dict[str, CameraFactory] = {}
_STAGES: dict[str, StageFactory] = {}


def register_camera(kind: str) -> Callable[[CameraFactory], CameraFactory]:
    def deco(f: CameraFactory) -> CameraFactory:
        _CAMERAS[kind] = f
        return f

    return deco


def register_stage(kind: str) -> Callable[[StageFactory], StageFactory]:
    def deco(f: StageFactory) -> StageFactory:
        _STAGES[kind] = f
        return f

    return deco


@register_camera("fake")
def _fake_camera(spec: DeviceSpec, world: Any) -> DepthCamera:
    from fakes.camera import FakeCamera

    return FakeCamera.from_options(world, spec.options)


@register_stage("fake")
def _fake_stage(spec: DeviceSpec, world: Any) -> Stage:
    from fakes.stage import FakeStage

    return FakeStage(world, speed_m_s=spec.float("speed", 0.1), settle_s=spec.float("settle", 0.5))


@register_stage("none")
def _no_stage(spec: DeviceSpec, world: Any) -> Stage:
    return NoStage()


def _load_plugins() -> None:
    """Import driver modules that register further kinds (serial stages, real cameras)."""
    import importlib

    for module in ("drivers.serial_stages", "drivers.realsense", "drivers.oak"):
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as e:
            if e.name != module:
                raise


class FollowingStage(Stage):
    """Wraps a real stage so that a fake camera's wall follows its measured position."""

    def __init__(self, inner: Stage, world: Any):
        self.inner = inner
        self.world = world
        self.name = inner.name
        self.tolerance_m = inner.tolerance_m

    def open(self) -> None:
        self.inner.open()

    def close(self) -> None:
        self.inner.close()

    @property
    def limits_m(self) -> tuple[float, float]:
        return self.inner.limits_m

    def home(self) -> None:
        self.inner.home()

    def move_to(self, position_m: float) -> float:
        measured = self.inner.move_to(position_m)
        self.world.set_distance(measured)
        return measured

    def position_m(self) -> float:
        return self.inner.position_m()

    def describe(self) -> dict[str, Any]:
        return self.inner.describe()


@dataclass
class RigDevices:
    """A camera and a stage built from device strings, unopened, and how to wait between steps.

    With simulated devices only, waiting advances the simulated clock instead of sleeping.
    """

    camera: DepthCamera
    stage: Stage
    world: Any = None
    simulated: bool = False

    def sleep(self, seconds: float) -> None:
        if self.simulated:
            self.world.time_s += seconds
        else:
            time.sleep(seconds)


def open_devices(camera: str, stage: str, *, tilt_deg: float = 0.0, distance_m: float = 1.0) -> RigDevices:
    """Build the camera and stage from device strings. Devices are returned unopened."""
    from fakes.world import FakeWorld, Wall

    _load_plugins()
    cam_spec, stage_spec = DeviceSpec.parse(camera), DeviceSpec.parse(stage)
    world = FakeWorld(Wall(distance_m=distance_m, tilt_deg=tilt_deg))
    for spec, table, what in ((cam_spec, _CAMERAS, "camera"), (stage_spec, _STAGES, "stage")):
        if spec.kind not in table:
            known = ", ".join(sorted(k + ":" for k in table))
            raise DeviceError(f"unknown {what} kind {spec.kind!r} in {spec.text!r}; known kinds: {known}")
    cam = _CAMERAS[cam_spec.kind](cam_spec, world)
    stg = _STAGES[stage_spec.kind](stage_spec, world)
    if stage_spec.kind == "none":
        stg = NoStage(position_m=distance_m)
    if cam_spec.kind == "fake" and stage_spec.kind != "fake":
        stg = FollowingStage(stg, world)
    simulated = cam_spec.kind == "fake" and stage_spec.kind in ("fake", "none")
    return RigDevices(cam, stg, world, simulated)
