"""What every depth camera offers the rig, real or simulated.

A camera is opened as a context manager, configured with `CameraSettings`, and then yields
`Frame`s. `configure()` returns the settings the device actually applied (read back, not
echoed), and every frame carries the device's own report of exposure, gain and projector
state so a recording can prove its settings.

Geometry follows the paper (Huber et al., "Cubic Range Error Model for Stereo Vision with
Illuminators", eq. dist_to_disp): range Z = f * b / d, with f in px, baseline b in m and
disparity d in px.
"""

from __future__ import annotations

import abc
from dataclasses import asdict, dataclass, field
from typing import Any, Iterator

import numpy as np


@dataclass(frozen=True)
class CameraSettings:
    """Sensor settings a run fixes for the whole experiment.

    exposure_us: exposure time in microseconds; gain: the sensor's analog gain in the
    device's own units (RealSense: 16..248, x1 = 16); projector_on: the IR pattern projector.
    """

    projector_on: bool = True
    exposure_us: float = 8500.0
    gain: float = 16.0
    auto_exposure: bool = False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CameraSettings":
        return cls(**{k: d[k] for k in ("projector_on", "exposure_us", "gain", "auto_exposure") if k in d})


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of the depth image: focal lengths and principal point in px."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class FrameMetadata:
    """What the device reports it used for one frame (not what was requested)."""

    exposure_us: float
    gain: float
    projector_on: bool
    auto_exposure: bool = False


@dataclass
class Frame:
    """One depth frame.

    depth: uint16 array (height, width) in depth units (multiply by `depth_scale_m`), 0 = no data.
    ir: the left infrared image (uint8 or uint16) when it was asked for, else None.
    timestamp_ms: the device's clock in milliseconds.
    """

    depth: np.ndarray
    frame_number: int
    timestamp_ms: float
    metadata: FrameMetadata
    ir: np.ndarray | None = None


@dataclass
class CameraInfo:
    """Identity and calibration, fixed while the camera is open."""

    model: str
    serial: str
    firmware: str
    intrinsics: Intrinsics
    baseline_m: float
    depth_scale_m: float
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        return d


class DepthCamera(abc.ABC):
    """A stereo depth camera.

    Lifecycle: `with camera:` opens and closes it. `configure()` applies settings and returns
    what the device read back. `frames(n)` yields n frames with those settings.
    """

    #: a short name for progress lines and errors
    name: str = "camera"

    def __enter__(self) -> "DepthCamera":
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @abc.abstractmethod
    def open(self) -> None: ...

    @abc.abstractmethod
    def close(self) -> None: ...

    @abc.abstractmethod
    def info(self) -> CameraInfo:
        """Model, serial, intrinsics, baseline in m and depth scale in m per unit."""

    @abc.abstractmethod
    def configure(self, settings: CameraSettings) -> CameraSettings:
        """Apply settings; return the settings read back from the device."""

    @abc.abstractmethod
    def read_settings(self) -> CameraSettings:
        """The settings the device reports now."""

    @abc.abstractmethod
    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        """Yield `n` frames; with `ir=True` each carries the left infrared image."""

    def describe(self) -> dict[str, Any]:
        """What this device is, in plain data (ophyd-style `describe()`)."""
        info = self.info()
        return {"kind": "camera", "name": self.name, **info.to_dict()}

    def read(self) -> dict[str, Any]:
        """The device's current state: the settings it reports."""
        return self.read_settings().to_dict()
