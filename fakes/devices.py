"""The simulated devices as device-string kinds (`fake:` camera, `fake:` stage), and how they share a world.

The fake camera always needs a wall to look at. The camera and stage built together share one
`FakeWorld`, kept in the registry's context under "world" (`drivers.registry`): moving the
fake stage moves the wall the fake camera sees. With a real stage (or a simulated controller on
a serial port) the fake camera's wall follows the stage's measured position instead
(`FollowingStage`).
"""

from __future__ import annotations

from typing import Any

from drivers.camera import DepthCamera
from drivers.errors import StageError
from drivers.options import AT_LEAST_0, POSITIVE, Option, OptionTable
from drivers.registry import DeviceSpec
from drivers.stage import Stage

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
    return FakeCamera.from_options(shared_world(context), spec.options, spec.text, spec.path)


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
