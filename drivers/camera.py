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

from .errors import CameraError


#: rig's gain unit, the same on every camera: GAIN_X1 is the sensor's unity (lowest) analog gain, so 16 = x1 and
#: 32 = x2. It is the RealSense D4xx's own scale (16..248), which plans, experiment files and recordings have
#: always used; a camera with another scale converts (its kind's `GainScale`: an OAK's ISO 100 = 16).
GAIN_X1 = 16.0


@dataclass(frozen=True)
class GainScale:
    """How a kind of camera's own gain setting maps to rig's unit (GAIN_X1 = 16 = x1).

    native: the name of its own setting ("gain", "ISO"); per_x1: its own value at x1 (RealSense 16, OAK ISO 100);
    native_range: what it accepts, in its own units.
    """

    native: str = "gain"
    per_x1: float = GAIN_X1
    native_range: tuple[float, float] = (GAIN_X1, 248.0)

    def to_native(self, gain: float) -> float:
        return gain / GAIN_X1 * self.per_x1

    def from_native(self, value: float) -> float:
        return value / self.per_x1 * GAIN_X1

    @property
    def range(self) -> tuple[float, float]:
        """What it accepts, in rig's unit."""
        return (self.from_native(self.native_range[0]), self.from_native(self.native_range[1]))

    def check(self, gain: float, who: str) -> float:
        """The native value for `gain` (rig's unit); a one-line CameraError if the camera cannot take it."""
        lo, hi = self.range
        if not lo - 1e-9 <= gain <= hi + 1e-9:
            raise CameraError(f"{who}: gain {gain:g} is outside {lo:g}-{hi:g} (rig's unit: {GAIN_X1:g} = x1"
                             f"{self.native_words()}); choose one inside")
        return self.to_native(gain)

    def native_words(self) -> str:
        """'' when the camera's own scale is rig's; else e.g. ', = ISO 100 on this camera'."""
        if self.native == "gain" and self.per_x1 == GAIN_X1:
            return ""
        return f", = {self.native} {self.per_x1:g} on this camera"

    def text(self) -> str:
        """'16-256 (16 = x1 = ISO 100; ISO 100-1600)', for `rig devices --options`."""
        lo, hi = self.range
        if not self.native_words():
            return f"{lo:g}-{hi:g} ({GAIN_X1:g} = x1)"
        a, b = self.native_range
        return f"{lo:g}-{hi:g} ({GAIN_X1:g} = x1 = {self.native} {self.per_x1:g}; {self.native} {a:g}-{b:g})"


@dataclass(frozen=True)
class CameraSettings:
    """Sensor settings a run fixes for the whole experiment.

    exposure_us: exposure time in microseconds; gain: the sensor's analog gain in rig's unit, the same on
    every camera (GAIN_X1 = 16 = x1; a driver converts to its own, `GainScale`); projector_on: the IR pattern
    projector. The defaults are the default plan's, and every camera kind takes them.
    """

    projector_on: bool = True
    exposure_us: float = 8500.0
    gain: float = GAIN_X1
    auto_exposure: bool = False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CameraSettings":
        return cls(**{k: d[k] for k in ("projector_on", "exposure_us", "gain", "auto_exposure") if k in d})


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of the depth image: its size, focal lengths and principal point in px.

    The one intrinsics type: `CameraCalibration` adds what turns depth counts into ranges."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class CameraCalibration(Intrinsics):
    """The intrinsics with the stereo baseline (m) and the depth unit (m per count): what a recording stores in
    its /camera attributes (docs/data-format.md) and the models read back."""

    baseline_m: float = float("nan")
    depth_scale_m: float = float("nan")

    @property
    def intrinsics(self) -> Intrinsics:
        return Intrinsics(self.width, self.height, self.fx, self.fy, self.cx, self.cy)


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

    def calibration(self) -> CameraCalibration:
        i = self.intrinsics
        return CameraCalibration(i.width, i.height, i.fx, i.fy, i.cx, i.cy, self.baseline_m, self.depth_scale_m)


class DepthCamera(abc.ABC):
    """A stereo depth camera.

    Lifecycle: `with camera:` opens and closes it. `configure()` applies settings and returns
    what the device read back. `frames(n)` yields n frames with those settings.
    """

    #: a short name for progress lines and errors
    name: str = "camera"
    #: a recording played back (a file, a bag): its settings are what they were when it was made and cannot be
    #: changed, so the runner records them as they were, with a note, instead of refusing them (issue 31)
    plays_back: bool = False
    #: the IR image's top value (DN) when it is below its dtype's top (e.g. 1023 for 10-bit IR in uint16); None: the
    #: dtype's top (255 for uint8). A sample there is clipped: the runner counts them per pixel (ir_saturated)
    ir_full_scale_dn: int | None = None

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

    def true_distance_m(self) -> float | None:
        """The true camera-to-wall distance, which only a simulated camera knows (None: a real one does not)."""
        return None
