"""How every stop of an experiment is captured: one frozen object every protocol shares.

The protocols take these as flat keyword arguments (`perpendicular(projector_on=False,
gain=32)`), as the experiment files' [parameters] tables and the recordings'
`protocol_params` spell them: each is a parameter of every protocol (`CAPTURE_PARAMS`, after the
protocol's own), and `ProtocolSpec.plan` collects them into one `CaptureSettings`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from drivers.camera import CameraSettings

from .plan import Capture, WarmUp
from .plan_values import ProtocolParam, between, whole_between
from .region_of_interest import check_region

#: the widest ranges any supported camera takes (RealSense D4xx: exposure 1-165000 us, gain 16-248;
#: OAK-D: exposure up to 33000 us, ISO 100-1600); a device refuses what it cannot do when configured
EXPOSURE_US = (1.0, 200_000.0)
GAIN = (0.0, 10_000.0)

#: the capture settings every protocol takes, as its parameters (after its own and frames_per_stop)
CAPTURE_PARAMS = (
    ProtocolParam("projector_on", bool, True, label="Projector", help="the IR pattern projector", option="--projector"),
    ProtocolParam("exposure_us", float, 8500.0, "us", "Exposure [us]", "exposure time (auto exposure is always off)",
                  between(*EXPOSURE_US, "us (auto exposure is always off: rig fixes the exposure so that sigma "
                                        "depends on range only)")),
    ProtocolParam("gain", float, 16.0, "", "Gain", "the sensor's analog gain in the device's units "
                  "(RealSense: 16-248, x1 = 16)", between(*GAIN)),
    ProtocolParam("settle_s", float, 1.0, "s", "Settle [s]", "seconds to wait after each move before capturing",
                  between(0.0, 3600.0, "s"), form=False),
    ProtocolParam("ir", bool, True, label="IR image", help="also average the left IR image", form=False),
    ProtocolParam("ambient_frames", int, 0, "", "Ambient frames", "extra frames per stop with the projector "
                  "off (the ambient light level)", whole_between(0, 10_000), form=False),
    ProtocolParam("keep_raw", bool, False, label="Keep raw frames", help="store the raw frames too", form=False),
    ProtocolParam("warm_up_drift_mm_per_min", float, 0.0, "mm/min", "Warm-up drift [mm/min]",
                  "before the first stop, wait until the frame mean depth drifts less than this (0: do not wait)",
                  between(0.0, 100.0, "mm/min (0: do not wait)"), form=False),
    ProtocolParam("warm_up_window_s", float, 60.0, "s", "Warm-up window [s]",
                  "the seconds of frames the drift is fitted over", between(1.0, 3600.0, "s"),
                  form=False),
    ProtocolParam("warm_up_max_s", float, 1800.0, "s", "Warm-up at most [s]",
                  "a camera still drifting after this long stops the run", between(1.0, 86_400.0, "s"), form=False),
    ProtocolParam("region_px", list, [], "px", "Region [px]", "x, y, width, height of the part of the image the "
                  "wall fills, when a target does not fill the frame: only it is recorded (empty: the whole image)",
                  check_region),
)
#: the warm-up's parameters: they change no stop's recording, so a resumed run may change them (plan_check)
WARM_UP_PARAMS = ("warm_up_drift_mm_per_min", "warm_up_window_s", "warm_up_max_s")
_DEFAULT = {p.name: p.default for p in CAPTURE_PARAMS}


@dataclass(frozen=True)
class CaptureSettings:
    """Camera settings and capture options, fixed for the whole experiment (each described in CAPTURE_PARAMS).

    projector_on: the IR pattern projector; exposure_us: exposure time in microseconds;
    gain: the sensor's analog gain in the device's units (RealSense: 16..248, x1 = 16);
    settle_s: seconds to wait after each move before capturing; ir: also average the left IR
    image; ambient_frames: extra frames per stop with the projector off (the ambient light
    level); keep_raw: store the raw frames too; warm_up_drift_mm_per_min: before the first stop, wait until the
    frame mean depth drifts less than this (0: do not wait), judged over the last warm_up_window_s seconds, for
    at most warm_up_max_s seconds (`plan.WarmUp`); region_px: [x, y, width, height] of the image to record, px
    ([]: the whole image; protocols.region_of_interest).
    """

    projector_on: bool = _DEFAULT["projector_on"]
    exposure_us: float = _DEFAULT["exposure_us"]
    gain: float = _DEFAULT["gain"]
    settle_s: float = _DEFAULT["settle_s"]
    ir: bool = _DEFAULT["ir"]
    ambient_frames: int = _DEFAULT["ambient_frames"]
    keep_raw: bool = _DEFAULT["keep_raw"]
    warm_up_drift_mm_per_min: float = _DEFAULT["warm_up_drift_mm_per_min"]
    warm_up_window_s: float = _DEFAULT["warm_up_window_s"]
    warm_up_max_s: float = _DEFAULT["warm_up_max_s"]
    region_px: list = field(default_factory=list)

    def __post_init__(self) -> None:
        for p in CAPTURE_PARAMS:
            object.__setattr__(self, p.name, p.checked("capture settings", getattr(self, p.name)))
        if self.warm_up_drift_mm_per_min > 0 and self.warm_up_max_s < self.warm_up_window_s:
            raise ValueError(f"capture settings: warm_up_max_s = {self.warm_up_max_s:g} is shorter than "
                             f"warm_up_window_s = {self.warm_up_window_s:g}, so the drift is never judged; give "
                             f"warm_up_max_s of at least {self.warm_up_window_s:g} s or a shorter window")

    def camera(self) -> CameraSettings:
        """The camera settings to configure (auto-exposure always off)."""
        return CameraSettings(projector_on=self.projector_on, exposure_us=self.exposure_us, gain=self.gain,
                              auto_exposure=False)

    def capture(self, stop: str, n_frames: int) -> Capture:
        """The capture step of one stop."""
        return Capture(stop, n_frames, ir=self.ir, ambient_frames=self.ambient_frames, keep_raw=self.keep_raw)

    def warm_up(self) -> list[WarmUp]:
        """The warm-up step the protocols take after configuring the camera, when asked for one ([] if not)."""
        if self.warm_up_drift_mm_per_min <= 0:
            return []
        return [WarmUp(self.warm_up_drift_mm_per_min, self.warm_up_window_s, self.warm_up_max_s)]

    def to_params(self) -> dict[str, Any]:
        """The flat parameters, as recorded in `protocol_params` and written to experiment files."""
        return asdict(self)
