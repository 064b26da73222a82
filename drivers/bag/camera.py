"""Bags played back as a camera, one bag (or one bag's stream) per stop, for the runner (`rig import`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

from ..camera import CameraInfo, CameraSettings, DepthCamera, Frame, FrameMetadata, Intrinsics
from ..errors import FolderImportError
from .contents import BagFacts, frames


@dataclass
class BagStop:
    """One stop: a bag, its label and the camera-to-wall distance in m."""

    label: str
    facts: BagFacts
    distance_m: float
    #: the stop's frames when a bag holds several stops: header stamps from start to end, ms (None: the whole bag)
    window_ms: tuple[float, float] | None = None

    @property
    def n_frames(self) -> int:
        if self.window_ms is None:
            return self.facts.n_frames
        lo, hi = self.window_ms
        return sum(lo <= t <= hi for t in self.facts.stamps_ms)


def frame_metadata(meta: dict[str, str], recorded: CameraSettings) -> FrameMetadata:
    """A frame's settings from its own metadata (librealsense's keys), else as recorded for the whole bag."""

    def number(key: str, default: float) -> float:
        try:
            return float(meta[key])
        except (KeyError, ValueError):
            return default

    projector = recorded.projector_on
    if "Frame Laser Power Mode" in meta:
        projector = bool(number("Frame Laser Power Mode", 1.0)) and number("Frame Laser Power", 1.0) > 0
    return FrameMetadata(exposure_us=number("Actual Exposure", recorded.exposure_us),
                         gain=number("Gain Level", recorded.gain), projector_on=projector,
                         auto_exposure=bool(number("Auto Exposure", float(recorded.auto_exposure))))


class BagCamera(DepthCamera):
    """Replays the stops' bags as a camera: each `frames(n)` call serves the next stop.

    A recording cannot be changed (`plays_back`): `configure` returns the settings it was made with, and
    each frame carries its own metadata; the runner records both and notes where they differ from the plan.
    """

    name = "bag import"
    plays_back = True

    def __init__(self, stops: list[BagStop], settings: CameraSettings, calibration: dict[str, float],
                 identity: dict[str, str], extra: dict):
        self.stops = stops
        self.recorded = settings
        self.calibration = calibration
        self.identity = identity
        self.extra = extra
        self._pending = iter(stops)

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass

    def info(self) -> CameraInfo:
        c, f = self.calibration, self.stops[0].facts
        return CameraInfo(model=self.identity.get("camera_model") or "imported bag", serial=self.identity.get("camera_serial", ""),
                          firmware=self.identity.get("camera_firmware", ""),
                          intrinsics=Intrinsics(f.width, f.height, c["fx"], c["fy"], c["cx"], c["cy"]),
                          baseline_m=c["baseline_m"], depth_scale_m=c["depth_unit_m"], extra=self.extra)

    def configure(self, settings: CameraSettings) -> CameraSettings:
        return self.recorded

    def read_settings(self) -> CameraSettings:
        return self.recorded

    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        stop = next(self._pending)
        served = 0
        for f in frames(stop.facts, stop.window_ms, self.calibration["depth_unit_m"]):
            yield Frame(depth=f.depth, frame_number=f.frame_number,
                        timestamp_ms=f.timestamp_ms if math.isfinite(f.timestamp_ms) else math.nan,
                        metadata=frame_metadata(f.metadata, self.recorded))
            served += 1
        if served != n:
            raise FolderImportError(f"{stop.facts.path}: {served} frames read, {n} counted before; did the bag change during the import?")
