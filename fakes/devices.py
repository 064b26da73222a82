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


def fake_camera(spec: DeviceSpec, context: dict[str, Any]) -> DepthCamera:
    """Factory for `fake:...` cameras (options: see `FakeCamera.from_options`)."""
    return FakeCamera.from_options(shared_world(context), spec.options)


def fake_stage(spec: DeviceSpec, context: dict[str, Any]) -> Stage:
    """Factory for the `fake:` stage (options speed in m/s, settle in s, and its travel: min_m, max_m, the
    nearest and farthest camera-to-wall distances, default 0.3 and 3.5)."""
    lo, hi = spec.float("min_m", 0.3), spec.float("max_m", 3.5)
    if not 0.0 <= lo < hi:
        raise StageError(f"device {spec.text!r}: travel min_m={lo:g} to max_m={hi:g} m is empty; give 0 <= min_m < max_m")
    return FakeStage(shared_world(context), limits_m=(lo, hi), speed_m_s=spec.float("speed", 0.1),
                     settle_s=spec.float("settle", 0.5))


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
