"""A simulated linear stage: travel limits, finite speed, settling, and a little jitter."""

from __future__ import annotations

import time

import numpy as np

from drivers.errors import StageError
from drivers.stage import Stage

from .world import FakeWorld


class FakeStage(Stage):
    """A linear stage that moves the wall of a `FakeWorld`.

    speed_m_s: travel speed; settle_s: time to settle after a move; position_noise_m: the
    standard deviation of the measured position about the true one (encoder jitter).
    realtime: if True, moves take wall-clock time (speed and settling); otherwise they only
    advance the world's simulated clock, so tests and demos run fast.
    """

    name = "fake-stage"

    def __init__(
        self,
        world: FakeWorld,
        limits_m: tuple[float, float] = (0.3, 3.5),
        speed_m_s: float = 0.1,
        settle_s: float = 0.5,
        position_noise_m: float = 0.0001,
        realtime: bool = False,
        seed: int = 0,
    ):
        self.world = world
        self._limits = limits_m
        self.speed_m_s = speed_m_s
        self.settle_s = settle_s
        self.position_noise_m = position_noise_m
        self.realtime = realtime
        self._rng = np.random.default_rng(seed)
        self._homed = False

    @property
    def limits_m(self) -> tuple[float, float]:
        return self._limits

    def home(self) -> None:
        self._homed = True

    def move_to(self, position_m: float) -> float:
        if not self._homed:
            raise StageError(f"{self.name}: not homed; call home() (or run the plan's home step) before moving")
        self.check_limits(position_m)
        travel_s = abs(position_m - self.world.wall.distance_m) / self.speed_m_s + self.settle_s
        if self.realtime:
            time.sleep(travel_s)
        self.world.time_s += travel_s
        self.world.set_distance(position_m)
        return self.position_m()

    def position_m(self) -> float:
        return self.world.wall.distance_m + float(self._rng.normal(0.0, self.position_noise_m))

    def describe(self) -> dict:
        return {**super().describe(), "speed_m_s": self.speed_m_s, "settle_s": self.settle_s, "simulated": True}
