"""The Devices screen's work, without Textual: connect, read back, home, test capture.

Every call may block on hardware; the UI runs them in a worker thread. Failures are the
drivers' one-line `DeviceError`s, passed on unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from drivers.camera import CameraSettings
from drivers.errors import DeviceError
from drivers.registry import kind
from drivers.stage import NoStage, Stage
from protocols.plan_check import RigLimits
from rig.devices import DeviceSpec, RigDevices, open_devices

from .centre import CentreStats

#: what the status line adds when a device string fails
HINT = "use fake: to try the simulated rig"


def device_words(what: str, text: str) -> str:
    """A device string and what it is, without opening it: "fake: (simulated)", "none: (no stage: the distance is
    set by hand or fixed)", "realsense:serial=1 (Intel RealSense ...)"; what is wrong with it when no kind takes it."""
    try:
        found = kind(what, DeviceSpec.parse(text).kind, text)
    except DeviceError as e:
        return str(e)  # (it names the string)
    return f"{text} ({'simulated' if found.simulated else found.summary or found.name})"


@dataclass
class TestCapture:
    frames: int
    fill_rate: float
    centre_mean_m: float
    centre_sigma_m: float


@dataclass
class DeviceReport:
    """What the Devices screen shows: plain (label, value) rows."""

    camera: list[tuple[str, str]] = field(default_factory=list)
    stage: list[tuple[str, str]] = field(default_factory=list)
    limits: RigLimits | None = None  # the stage's travel and the camera's image, for the experiment form


def homed(stage: Stage) -> bool | None:
    """Whether the stage has been homed; None when it cannot say (no stage)."""
    inner = getattr(stage, "inner", stage)
    if isinstance(inner, NoStage):
        return None
    for name in ("homed", "_homed"):
        value = getattr(inner, name, None)
        if isinstance(value, bool):
            return value
    return None


class DeviceSession:
    """The camera and stage the operator is looking at, open between connect() and disconnect()."""

    def __init__(self) -> None:
        self.devices: RigDevices | None = None
        self.camera_text = ""
        self.stage_text = ""

    @property
    def connected(self) -> bool:
        return self.devices is not None

    def connect(self, camera: str, stage: str, *, tilt_deg: float = 0.0, distance_m: float = 1.0) -> DeviceReport:
        """Open both devices (closing any open ones first) and read them back."""
        self.disconnect()
        devices = open_devices(camera, stage, tilt_deg=tilt_deg, distance_m=distance_m)
        devices.camera.open()
        try:
            devices.stage.open()
        except BaseException:
            devices.camera.close()
            raise
        self.devices, self.camera_text, self.stage_text = devices, camera, stage
        return self.report()

    def disconnect(self) -> None:
        d, self.devices = self.devices, None
        if d is None:
            return
        try:
            d.camera.close()
        finally:
            d.stage.close()

    def home(self) -> DeviceReport:
        self._need()
        assert self.devices is not None
        self.devices.stage.home()
        return self.report()

    def report(self) -> DeviceReport:
        self._need()
        assert self.devices is not None
        cam, stage = self.devices.camera, self.devices.stage
        info = cam.info()
        i = info.intrinsics
        s = cam.read_settings()
        camera = [
            ("model", info.model), ("serial", info.serial), ("firmware", info.firmware),
            ("image", f"{i.width} x {i.height} px"), ("focal length", f"fx {i.fx:.1f}  fy {i.fy:.1f} px"),
            ("principal point", f"cx {i.cx:.1f}  cy {i.cy:.1f} px"), ("baseline", f"{info.baseline_m * 1000:.1f} mm"),
            ("depth unit", f"{info.depth_scale_m * 1000:g} mm"), ("projector", "on" if s.projector_on else "off"),
            ("exposure", f"{s.exposure_us:g} us" + (" (auto)" if s.auto_exposure else "")), ("gain", f"{s.gain:g}"),
        ]
        kind = DeviceSpec.parse(self.stage_text).kind if self.stage_text else "?"
        h = homed(stage)
        lo, hi = stage.limits_m
        pos = stage.position_m()
        rows = [("kind", f"{kind}: ({stage.name})"),
                ("position", "not known (no stage)" if math.isnan(pos) else f"{pos:.4f} m"),
                ("homed", "n/a" if h is None else ("yes" if h else "no: press h to home")),
                ("travel", f"{lo:.2f}-{hi:.2f} m" if math.isfinite(hi) else "unlimited (no stage)")]
        return DeviceReport(camera, rows, RigLimits.of(stage, (i.height, i.width)))

    def test_capture(self, settings: CameraSettings, n_frames: int = 10) -> TestCapture:
        """Apply the experiment's settings and capture a few frames where the stage stands now."""
        self._need()
        assert self.devices is not None
        cam = self.devices.camera
        cam.configure(settings)
        info = cam.info()
        stats = CentreStats((info.intrinsics.height, info.intrinsics.width), info.depth_scale_m)
        for frame in cam.frames(n_frames):
            stats.add(frame.depth)
        mean, sigma = stats.centre()
        return TestCapture(stats.frames, stats.fill_rate, mean, sigma)

    def _need(self) -> None:
        if self.devices is None:
            raise DeviceError("no devices connected; press c to connect the camera and stage")


def describe_error(e: BaseException) -> str:
    """The status line for a failed connect: the driver's message, and a way to try the tool anyway."""
    text = str(e).splitlines()[0] if str(e) else type(e).__name__
    return text if "fake:" in text else f"{text} ({HINT})"
