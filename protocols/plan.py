"""Plans: plain descriptions of what an experiment does, step by step.

A plan is a name, its parameters, and a generator of steps (bluesky-style): it says what
happens and touches no device. `protocols.runner` executes the steps against devices,
records, shows progress and turns device errors into messages.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Union

from drivers.camera import CameraSettings


@dataclass(frozen=True)
class Home:
    """Home the stage."""


@dataclass(frozen=True)
class Move:
    """Move the stage to a camera-to-wall distance in m and wait until it has settled."""

    position_m: float


@dataclass(frozen=True)
class Settle:
    """Wait this many seconds (vibration after a move, thermal settling)."""

    seconds: float


@dataclass(frozen=True)
class Configure:
    """Apply camera settings; the runner refuses to capture if the read-back differs."""

    settings: CameraSettings


@dataclass(frozen=True)
class WarmUp:
    """Stream frames until the frame mean depth drifts less than `drift_mm_per_min` (shown over the last `window_s`
    seconds by `protocols.warm_up`'s rule); give up after `max_s` seconds, recording nothing."""

    drift_mm_per_min: float
    window_s: float
    max_s: float


@dataclass(frozen=True)
class Capture:
    """Capture one stop: `n_frames` frames reduced to per-pixel statistics.

    stop: a unique label for the stop (used to resume); ir: also average the left IR image;
    ambient_frames: extra frames with the projector switched off, averaged as the ambient IR
    level (for the ambient-light effect); keep_raw: store the raw frames too.
    """

    stop: str
    n_frames: int
    ir: bool = False
    ambient_frames: int = 0
    keep_raw: bool = False


Step = Union[Home, Move, Settle, Configure, WarmUp, Capture]


@dataclass
class Plan:
    """A named experiment: its parameters (recorded verbatim) and its steps.

    stops_param: the parameter that says where the stops are (perpendicular: `stops_m`); errors about
    a stop's position name it, and it is the one parameter a resumed run may change
    (`protocols.plan_check.resume_problems`).
    """

    name: str
    params: dict[str, Any]
    make_steps: Callable[[], Iterator[Step]] = field(repr=False)
    stops_param: str = ""

    def steps(self) -> Iterator[Step]:
        return self.make_steps()

    def captures(self) -> list[Capture]:
        return [s for s in self.steps() if isinstance(s, Capture)]
