"""A camera that replays a folder's stops, frame by frame, for the runner (used by `rig import`)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterator

from ..camera import (
    CameraInfo,
    CameraSettings,
    DepthCamera,
    Frame,
    FrameMetadata,
    Intrinsics,
)
from ..errors import FolderImportError
from .manifest import ImportSettings
from .stops import StopSource


class FolderCamera(DepthCamera):
    """Replays the stops' frames as a camera, for the runner.

    Each `frames(n)` call serves the next stop, in order: the runner asks once per capture
    (the frames' metadata are the configured settings, so none is refused).
    """

    name = "import"

    def __init__(self, stops: list[StopSource], settings: ImportSettings, shape: tuple[int, int], source: Path):
        self.stops = stops
        self.settings = settings
        self.shape = shape
        self.source = source
        self._pending = iter(stops)
        self._camera_settings = CameraSettings(settings.projector_on, settings.exposure_us, settings.gain, False)
        self._frame_number = 0

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass

    def info(self) -> CameraInfo:
        s, (h, w) = self.settings, self.shape
        return CameraInfo(model=s.camera_model, serial=s.camera_serial, firmware="",
                          intrinsics=Intrinsics(w, h, s.fx, s.fy, s.cx, s.cy), baseline_m=s.baseline_m,
                          depth_scale_m=s.depth_unit_m, extra={"imported_from": str(self.source)})

    def configure(self, settings: CameraSettings) -> CameraSettings:
        self._camera_settings = settings
        return settings

    def read_settings(self) -> CameraSettings:
        return self._camera_settings

    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        stop = next(self._pending)
        c = self._camera_settings
        meta = FrameMetadata(c.exposure_us, c.gain, c.projector_on, c.auto_exposure)
        ir_images = stop.ir_frames() if ir else iter(())
        served = 0
        for depth, _path in stop.frames():
            yield Frame(depth=depth, frame_number=self._frame_number, timestamp_ms=math.nan, metadata=meta,
                        ir=next(ir_images, None))
            self._frame_number += 1
            served += 1
        if served != n:
            raise FolderImportError(f"{stop.folder}: {served} frames read, {n} counted before; did the folder change during the import?")
