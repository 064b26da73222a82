"""The factories of the simulated devices (`fake:` camera, `fake:` stage; their kinds: fakes.kinds), and how they
share a world.

The fake camera always needs a wall to look at. The camera and stage built together share one
`FakeWorld`, kept in the registry's context under "world" (`drivers.registry`): moving the
fake stage moves the wall the fake camera sees. Once both are built (the registry's ON_BUILT hook), a
fake camera in front of a real stage (or a simulated controller on a serial port) makes its wall follow
the stage's measured position (`FollowingStage`), and a fake camera with the fake stage or none runs the
rig on the world's simulated clock: waiting advances it instead of sleeping.
"""

from __future__ import annotations

from typing import Any

from drivers.camera import DepthCamera
from drivers.errors import StageError
from drivers.options import AT_LEAST_0, POSITIVE, Option, OptionTable
from drivers.registry import ON_BUILT, DeviceSpec
from drivers.stage import NoStage, Stage

from .camera import FakeCamera
from .stage import FakeStage
from .world import FakeWorld, Wall


def shared_world(context: dict[str, Any]) -> FakeWorld:
    """The world of the devices built with this context (made on first use, at the context's distance and tilt)."""
    if "world" not in context:
        context["world"] = FakeWorld(Wall(distance_m=float(context.get("distance_m", 1.0)),
                                          tilt_deg=float(context.get("tilt_deg", 0.0))))
    return context["world"]


#: the options of the `fake:` stage
FAKE_STAGE_OPTIONS = OptionTable("fake", "stage", (
    Option("min_m", float, 0.3, AT_LEAST_0, "m", "the nearest camera-to-wall distance of its travel"),
    Option("max_m", float, 3.5, POSITIVE, "m", "the farthest camera-to-wall distance of its travel"),
    Option("speed", float, 0.1, POSITIVE, "m/s", "carriage speed"),
    Option("settle", float, 0.5, AT_LEAST_0, "s", "wait after a move"),
), error=StageError)


def fake_camera(spec: DeviceSpec, context: dict[str, Any]) -> DepthCamera:
    """Factory for `fake:...` cameras (options: `fakes.camera.FAKE_CAMERA_OPTIONS`)."""
    world = shared_world(context)
    camera = FakeCamera.from_options(world, spec.options, spec.text, spec.path)
    context.setdefault(ON_BUILT, []).append(lambda devices: wire_to_stage(devices, world))
    return camera


def wire_to_stage(devices: Any, world: FakeWorld) -> None:
    """Once the fake camera's stage is built: a real stage moves the wall by its measured position; with the fake
    stage or none, the rig runs on the world's clock."""
    if not isinstance(devices.stage, FakeStage):
        devices.stage = FollowingStage(devices.stage, world)
    if isinstance(getattr(devices.stage, "inner", devices.stage), (FakeStage, NoStage)):
        devices.clock = lambda seconds: _advance(world, seconds)


def _advance(world: FakeWorld, seconds: float) -> None:
    world.time_s += seconds


def fake_stage(spec: DeviceSpec, context: dict[str, Any]) -> Stage:
    """Factory for the `fake:` stage (options: `FAKE_STAGE_OPTIONS`)."""
    o = spec.take(FAKE_STAGE_OPTIONS)
    lo, hi = o["min_m"], o["max_m"]
    if not lo < hi:
        raise StageError(f"device {spec.text!r}: travel min_m={lo:g} to max_m={hi:g} m is empty; give 0 <= min_m < max_m")
    return FakeStage(shared_world(context), limits_m=(lo, hi), speed_m_s=o["speed"], settle_s=o["settle"])


class FollowingStage(Stage):
    """Wraps a real stage so that a fake camera's wall follows its measured position."""

    def __init__(self, inner: Stage, world: FakeWorld):
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

    def setup_problems(self) -> list[str]:
        return self.inner.setup_problems()

    def travel_note(self) -> str:
        return self.inner.travel_note()
