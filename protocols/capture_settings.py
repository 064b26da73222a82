"""How every stop of an experiment is captured: one frozen object both protocols share.

The protocols take these as flat keyword arguments (`perpendicular(projector_on=False,
gain=32)`), as the experiment files' [parameters] tables and the recordings'
`protocol_params` spell them; `CaptureSettings.from_options` collects and checks them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

from drivers.camera import CameraSettings

from .plan import Capture
from .plan_values import flag, number, whole

#: the widest ranges any supported camera takes (RealSense D4xx: exposure 1-165000 us, gain 16-248;
#: OAK-D: exposure up to 33000 us, ISO 100-1600); a device refuses what it cannot do when configured
EXPOSURE_US = (1.0, 200_000.0)
GAIN = (0.0, 10_000.0)


@dataclass(frozen=True)
class CaptureSettings:
    """Camera settings and capture options, fixed for the whole experiment.

    projector_on: the IR pattern projector; exposure_us: exposure time in microseconds;
    gain: the sensor's analog gain in the device's units (RealSense: 16..248, x1 = 16);
    settle_s: seconds to wait after each move before capturing; ir: also average the left IR
    image; ambient_frames: extra frames per stop with the projector off (the ambient light
    level); keep_raw: store the raw frames too.
    """

    projector_on: bool = True
    exposure_us: float = 8500.0
    gain: float = 16.0
    settle_s: float = 1.0
    ir: bool = True
    ambient_frames: int = 0
    keep_raw: bool = False

    def __post_init__(self) -> None:
        w = "capture settings"
        checked = dict(projector_on=flag(w, "projector_on", self.projector_on),
                       exposure_us=number(w, "exposure_us", self.exposure_us, *EXPOSURE_US, "us (auto exposure is "
                                          "always off: rig fixes the exposure so that sigma depends on range only)"),
                       gain=number(w, "gain", self.gain, *GAIN),
                       settle_s=number(w, "settle_s", self.settle_s, 0.0, 3600.0, "s"),
                       ir=flag(w, "ir", self.ir), ambient_frames=whole(w, "ambient_frames", self.ambient_frames, 0, 10_000),
                       keep_raw=flag(w, "keep_raw", self.keep_raw))
        for k, v in checked.items():
            object.__setattr__(self, k, v)

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in fields(cls)]

    @classmethod
    def from_options(cls, protocol: str, options: dict[str, Any]) -> "CaptureSettings":
        """From flat keyword arguments; an unknown name is a TypeError naming the protocol and what it takes."""
        unknown = [k for k in options if k not in cls.names()]
        if unknown:
            raise TypeError(f"{protocol}() got unexpected keyword argument(s) {unknown}; capture settings are {cls.names()}")
        return cls(**options)

    def camera(self) -> CameraSettings:
        """The camera settings to configure (auto-exposure always off)."""
        return CameraSettings(projector_on=self.projector_on, exposure_us=self.exposure_us, gain=self.gain,
                              auto_exposure=False)

    def capture(self, stop: str, n_frames: int) -> Capture:
        """The capture step of one stop."""
        return Capture(stop, n_frames, ir=self.ir, ambient_frames=self.ambient_frames, keep_raw=self.keep_raw)

    def to_params(self) -> dict[str, Any]:
        """The flat parameters, as recorded in `protocol_params` and written to experiment files."""
        return asdict(self)
