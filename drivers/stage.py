"""What every linear stage offers the rig, real or simulated.

Positions are camera-to-wall distances in metres (`position_m`); a driver maps them to its
own axis (steps, mm, direction, offset). `move_to()` blocks until the stage has settled and
returns the position it measured afterwards.
"""

from __future__ import annotations

import abc
from typing import Any, Callable

from .errors import StageError
from .options import OptionTable
from .registry import DeviceSpec


class Stage(abc.ABC):
    """A linear stage that sets the camera-to-wall distance."""

    name: str = "stage"
    #: how far the measured position may be from the commanded one before capture is refused
    tolerance_m: float = 0.002

    def __enter__(self) -> "Stage":
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        """Connect to the device (no-op for stages that need none)."""

    def close(self) -> None:
        """Disconnect."""

    @property
    @abc.abstractmethod
    def limits_m(self) -> tuple[float, float]:
        """Travel limits as (nearest, farthest) camera-to-wall distance in m."""

    @abc.abstractmethod
    def home(self) -> None:
        """Run the homing cycle; afterwards positions are meaningful."""

    @abc.abstractmethod
    def move_to(self, position_m: float) -> float:
        """Move to `position_m`, wait until settled, return the measured position in m."""

    @abc.abstractmethod
    def position_m(self) -> float:
        """The measured position in m."""

    def check_limits(self, position_m: float) -> None:
        lo, hi = self.limits_m
        if not lo <= position_m <= hi:
            raise StageError(
                f"{self.name}: {position_m:.3f} m is outside the travel limits {lo:.3f}-{hi:.3f} m; "
                "change the plan's stops or the stage's offset"
            )

    def check_arrived(self, commanded_m: float, measured_m: float) -> None:
        """Refuse to go on if the stage is not where it was sent."""
        if abs(measured_m - commanded_m) > self.tolerance_m:
            raise StageError(
                f"{self.name}: commanded {commanded_m:.4f} m but measured {measured_m:.4f} m "
                f"(tolerance {self.tolerance_m * 1000:.1f} mm); check the stage for slip or obstruction and re-home"
            )

    def setup_problems(self) -> list[str]:
        """What the opened device knows will stop any plan before anything moves: one line each, naming
        the setting to change. None by default."""
        return []

    def travel_note(self) -> str:
        """Where `limits_m` comes from, as one more fix for stops beyond it ("" if there is nothing to add)."""
        return ""

    def describe(self) -> dict[str, Any]:
        lo, hi = self.limits_m
        return {"kind": "stage", "name": self.name, "limits_m": [lo, hi], "tolerance_m": self.tolerance_m}

    def read(self) -> dict[str, Any]:
        return {"position_m": self.position_m()}


class NoStage(Stage):
    """No stage: the operator (or a fixed mount) sets the distance. Moves only check the plan.

    Used for the tilted experiment, where the camera does not move, and for hand-placed rigs.
    """

    name = "none"

    def __init__(self, position_m: float = float("nan")):
        self._position_m = position_m
        #: who places the camera: called with a one-line request before each move, returning once it is done (None:
        #: nobody is asked; a plan of one stop is set up beforehand)
        self.ask: Callable[[str], None] | None = None

    @property
    def limits_m(self) -> tuple[float, float]:
        return (0.0, float("inf"))

    def home(self) -> None:
        pass

    def move_to(self, position_m: float) -> float:
        if self.ask is not None:
            self.ask(f"place the camera {position_m:.3f} m from the wall")
        self._position_m = position_m
        return position_m

    def position_m(self) -> float:
        return self._position_m


#: `none:` takes no options
NO_STAGE_OPTIONS = OptionTable("none", "stage", (), error=StageError)


def no_stage(spec: DeviceSpec, context: dict[str, Any]) -> NoStage:
    """Factory for `none:`: no stage; the distance is the one the experiment states (context "distance_m")."""
    spec.take(NO_STAGE_OPTIONS)
    return NoStage(position_m=float(context.get("distance_m", float("nan"))))
