"""Luxonis OAK-D cameras through depthai v3. Camera kind `oak`.

Device strings:

    oak:                                   the first OAK found
    oak:id=14442C108144F1D000              a given device (its device id, IP address or USB path)
    oak:width=640,height=400,fps=30        the mono resolution fed to stereo (these are the defaults)
    oak:preset=DEFAULT                     StereoDepth preset (DEFAULT, ACCURACY, DENSITY, ROBOTICS, ...)
    oak:confidence=200,subpixel=1,lr_check=1
    oak:projector=0.5                      IR dot projector intensity (0..1) when the projector is on
    oak:search=3                           seconds to look for devices

The pipeline: the left (CAM_B) and right (CAM_C) mono cameras feed a StereoDepth node with
the preset, subpixel, left-right check and confidence threshold given, every post-processing filter
off whatever the preset (RAW_FILTERS, read back and recorded), depth aligned to the left camera, in
millimetres. The IR flood light stays off; the dot projector's intensity is set with the projector
on and 0 with it off. Exposure and ISO are set manually through CameraControl on both cameras; each
frame's exposure and sensitivity are read back from the left camera's frame (StereoDepth's
syncedLeft output), paired with the depth frame by sequence number. The OAK reports no per-frame
projector state, so a frame's projector flag is the intensity last set (docs/hardware.md).

Gain is given in rig's unit (16 = x1) like on every camera, and set as the sensors' ISO (100 = x1, up to
1600: `OAK_GAIN`), so the default plan's 16 is ISO 100; the frames' ISO is reported back in rig's unit.
depthai's logger writes to standard output; its import, device search and opening run with that pointed
at standard error (drivers.console). `OAK` is the kind's entry (drivers.registry), named by the entry
point `rig.cameras` in pyproject.toml.

Importing this module never imports depthai; using the driver without it raises a one-line
`CameraError` naming what to install.
"""

from __future__ import annotations

import datetime
import os
import time
import warnings
from typing import Any, Iterator

import numpy as np

from .camera import CameraInfo, CameraSettings, DepthCamera, Frame, FrameMetadata, GainScale, Intrinsics
from .console import sdk_chatter_to_stderr
from .errors import CameraError
from .options import POSITIVE, Option, OptionTable, between
from .registry import DeviceKind, DeviceSpec, Probe

INSTALL = "pip install 'depthai>=3,<4'"
#: the mono sensors' sensitivity: ISO 100 (x1) to 1600 (CameraControl.setManualExposure), as rig's gain 16-256
OAK_GAIN = GainScale("ISO", 100.0, (100.0, 1600.0))
EXPOSURE_RANGE_US = (20, 33000)
#: frames to wait after a settings change for the frames to report them
SETTLE_FRAMES = 30
#: StereoDepthConfig.postProcessing with each filter off, as stereo_settings reads it back: threshold 0-65535 mm passes
#: all uint16 depth; brightness 0-256, depthai's default, invalidates only pixels of brightness 0 (docs/hardware.md)
RAW_FILTERS = {"median_filter": "MEDIAN_OFF", "bilateral_sigma": 0, "temporal_filter": False, "spatial_filter": False,
               "speckle_filter": False, "decimation_factor": 1, "threshold_filter_mm": [0, 65535],
               "brightness_filter": [0, 256], "hole_filling": False, "adaptive_median_filter": False}
#: the device-string options (docs/hardware.md); `oak://ID` is id=
OAK_OPTIONS = OptionTable("oak", "camera", (
    Option("id", str, None, None, "", "the device id, IP address or USB path of the OAK to open",
           example="14442C108144F1D000", absent="the first found"),
    Option("width", int, 640, POSITIVE, "px", "mono resolution fed to stereo, width"),
    Option("height", int, 400, POSITIVE, "px", "mono resolution fed to stereo, height"),
    Option("fps", float, 30.0, POSITIVE, "fps", "frame rate"),
    Option("preset", str, "DEFAULT", None, "", "StereoDepth preset (DEFAULT, ACCURACY, DENSITY, ROBOTICS, ...)"),
    Option("confidence", int, 200, between(0, 255), "", "StereoDepth confidence threshold"),
    Option("subpixel", bool, True, None, "", "subpixel disparity"),
    Option("lr_check", bool, True, None, "", "left-right consistency check"),
    Option("projector", float, 0.5, between(0, 1), "", "IR dot projector intensity when the projector is on"),
    Option("search", float, 3.0, POSITIVE, "s", "how long to look for devices"),
    Option("timeout", float, 5.0, POSITIVE, "s", "how long to wait for a frame"),
), path="device id (as id=)", error=CameraError)


def sdk(search_s: float = 3.0) -> Any:
    """Import depthai v3, with a short device search; or raise a one-line CameraError saying how to install it."""
    os.environ.setdefault("DEPTHAI_SEARCH_TIMEOUT", str(int(search_s * 1000)))
    try:
        with sdk_chatter_to_stderr():
            import depthai as dai
    except ImportError as e:
        text = (str(e).splitlines() or [""])[0]
        if getattr(e, "name", None) == "depthai":
            raise CameraError(f"oak: the Python package depthai is not installed; install it with {INSTALL} "
                              "(or pip install 'rig[oak]'), or simulate a camera with --camera fake:") from None
        raise CameraError(f"oak: depthai failed to import ({text}); reinstall it with {INSTALL}, "
                          "or simulate a camera with --camera fake:") from None
    major = str(getattr(dai, "__version__", "0")).split(".")[0]
    if major != "3":
        raise CameraError(f"oak: depthai {getattr(dai, '__version__', '?')} is installed but this driver needs depthai 3; "
                          f"upgrade with {INSTALL}")
    return dai


def list_oak() -> list[dict[str, str]]:
    """OAK devices that answer a search (USB and network), without booting them. Takes about 0.5 s."""
    dai = sdk()
    out = []
    with sdk_chatter_to_stderr():
        found = dai.Device.getAllAvailableDevices()
    for d in found:
        out.append({"kind": "oak", "model": d.name or str(d.platform).split(".")[-1], "serial": d.getDeviceId(),
                    "firmware": "(booted on open)", "usb": str(d.protocol).split(".")[-1] + " " + str(d.state).split(".")[-1],
                    "string": f"oak:id={d.getDeviceId()}"})
    return out


# -- pieces that need depthai objects but no device (tested without hardware) ---------------------

def calibration_from_handler(calib: Any, width: int, height: int, *, left: Any = None, right: Any = None) -> tuple[Intrinsics, float]:
    """Intrinsics of the (left) camera the depth is aligned to, scaled to width x height, and the
    baseline in m. depthai stores translations, and returns the baseline, in centimetres."""
    import depthai as dai

    left = left if left is not None else dai.CameraBoardSocket.CAM_B
    right = right if right is not None else dai.CameraBoardSocket.CAM_C
    try:
        m = calib.getCameraIntrinsics(left, width, height)
        baseline_cm = calib.getBaselineDistance(right, left, False, dai.LengthUnit.CENTIMETER)
    except RuntimeError as e:
        raise CameraError(f"oak: the device holds no stereo calibration ({(str(e).splitlines() or [''])[0]}); "
                          "calibrate it with Luxonis' calibration tool before measuring") from None
    baseline_m = abs(float(baseline_cm)) / 100.0
    if not 0.01 < baseline_m < 1.0:
        raise CameraError(f"oak: the calibration gives a baseline of {baseline_cm:g} cm; recalibrate the device")
    return Intrinsics(width=int(width), height=int(height), fx=float(m[0][0]), fy=float(m[1][1]),
                      cx=float(m[0][2]), cy=float(m[1][2])), baseline_m


def exposure_control(settings: CameraSettings) -> Any:
    """The CameraControl message that applies settings' exposure and ISO (gain) to a mono camera."""
    import depthai as dai

    ctrl = dai.CameraControl()
    if settings.auto_exposure:
        ctrl.setAutoExposureEnable()
        return ctrl
    lo, hi = EXPOSURE_RANGE_US
    if not lo <= settings.exposure_us <= hi:
        raise CameraError(f"oak: exposure {settings.exposure_us:g} us is outside {lo}-{hi} us; choose one inside")
    iso = OAK_GAIN.check(settings.gain, "oak")
    ctrl.setManualExposure(int(round(settings.exposure_us)), int(round(iso)))
    return ctrl


def apply_stereo_settings(cfg: Any, *, confidence: int, subpixel: bool, lr_check: bool) -> None:
    """Set a StereoDepthConfig as the rig measures, raw, whatever the preset set: every post-processing
    filter off (RAW_FILTERS), depth in millimetres."""
    import depthai as dai

    cfg.setConfidenceThreshold(int(confidence))
    cfg.setSubpixel(bool(subpixel))
    cfg.setLeftRightCheck(bool(lr_check))
    cfg.setMedianFilter(dai.StereoDepthConfig.MedianFilter.MEDIAN_OFF)
    cfg.setBilateralFilterSigma(0)
    pp = cfg.postProcessing
    for f in (pp.temporalFilter, pp.spatialFilter, pp.speckleFilter, pp.holeFilling, pp.adaptiveMedianFilter):
        f.enable = False
    pp.decimationFilter.decimationFactor = 1
    pp.thresholdFilter.minRange, pp.thresholdFilter.maxRange = RAW_FILTERS["threshold_filter_mm"]
    pp.brightnessFilter.minBrightness, pp.brightnessFilter.maxBrightness = RAW_FILTERS["brightness_filter"]
    cfg.setDepthUnit(dai.LengthUnit.MILLIMETER)


def stereo_settings(cfg: Any, preset: str) -> dict[str, Any]:
    """What a StereoDepthConfig holds, read back, for the recording: every post-processing filter included."""
    pp = cfg.postProcessing
    return {
        "preset": preset,
        "subpixel": bool(cfg.getSubpixel()),
        "subpixel_fractional_bits": int(cfg.getSubpixelFractionalBits()),
        "lr_check": bool(cfg.getLeftRightCheck()),
        "lr_check_threshold": int(cfg.getLeftRightCheckThreshold()),
        "confidence_threshold": int(cfg.getConfidenceThreshold()),
        "median_filter": str(cfg.getMedianFilter()).split(".")[-1],
        "bilateral_sigma": int(cfg.getBilateralFilterSigma()),
        "temporal_filter": bool(pp.temporalFilter.enable),
        "spatial_filter": bool(pp.spatialFilter.enable),
        "speckle_filter": bool(pp.speckleFilter.enable),
        "decimation_factor": int(pp.decimationFilter.decimationFactor),
        "threshold_filter_mm": [int(pp.thresholdFilter.minRange), int(pp.thresholdFilter.maxRange)],
        "brightness_filter": [int(pp.brightnessFilter.minBrightness), int(pp.brightnessFilter.maxBrightness)],
        "hole_filling": bool(pp.holeFilling.enable),
        "adaptive_median_filter": bool(pp.adaptiveMedianFilter.enable),
        "filtering_order": [str(f).split(".")[-1] for f in pp.filteringOrder],
        "extended_disparity": bool(cfg.getExtendedDisparity()),
        "depth_unit": str(cfg.getDepthUnit()).split(".")[-1],
    }


def check_raw(settings: dict[str, Any], name: str = "oak") -> None:
    """Refuse, in one line, stereo settings read back with a post-processing filter not off."""
    on = [f"{k}={settings.get(k)}" for k, off in RAW_FILTERS.items() if settings.get(k) != off]
    if on:
        raise CameraError(f"{name}: StereoDepth post-processing read back on after the driver set it off ({', '.join(on)}); "
                          "the rig measures raw depth: install the depthai release docs/hardware.md was tested with")


def frame_metadata(msg: Any, *, projector_on: bool, auto_exposure: bool) -> FrameMetadata:
    """Exposure (us) and sensitivity (ISO, as rig's gain: ISO 100 = 16) that one ImgFrame reports."""
    exposure = msg.getExposureTime()
    exposure_us = exposure.total_seconds() * 1e6 if isinstance(exposure, datetime.timedelta) else float(exposure)
    return FrameMetadata(exposure_us=float(round(exposure_us, 3)), gain=OAK_GAIN.from_native(float(msg.getSensitivity())),
                         projector_on=projector_on, auto_exposure=auto_exposure)


def frame_from_messages(depth: Any, left: Any | None, *, projector_on: bool, auto_exposure: bool,
                        ir: bool = False) -> Frame:
    """A rig Frame from a StereoDepth depth ImgFrame (uint16 mm) and the left mono ImgFrame it was
    computed from (exposure and sensitivity; the IR image)."""
    d = depth.getFrame()
    if d.dtype != np.uint16 or d.ndim != 2:
        raise CameraError(f"oak: the depth frame is {d.dtype} {d.shape}, not a uint16 image; link StereoDepth.depth "
                          "(not disparity) to the host")
    if left is not None and left.getSequenceNum() != depth.getSequenceNum():
        raise CameraError(f"oak: depth frame {depth.getSequenceNum()} was paired with left frame "
                          f"{left.getSequenceNum()}; pair frames by sequence number")
    source = left if left is not None else depth
    return Frame(
        depth=np.array(d, dtype=np.uint16, copy=True),
        frame_number=int(depth.getSequenceNum()),
        timestamp_ms=depth.getTimestampDevice().total_seconds() * 1000.0,
        metadata=frame_metadata(source, projector_on=projector_on, auto_exposure=auto_exposure),
        ir=np.array(left.getFrame(), copy=True) if ir and left is not None else None,
    )


# -- the driver ---------------------------------------------------------------------------------

class OakCamera(DepthCamera):
    """An OAK-D (Pro) stereo camera: mono pair into StereoDepth, manual exposure, dot projector."""

    name = "oak"

    def __init__(self, *, device_id: str | None = None, width: int = 640, height: int = 400, fps: float = 30.0,
                 preset: str = "DEFAULT", confidence: int = 200, subpixel: bool = True, lr_check: bool = True,
                 projector: float = 0.5, search_s: float = 3.0, timeout_s: float = 5.0):
        self.device_id = device_id
        self.width, self.height, self.fps = int(width), int(height), float(fps)
        self.preset = preset.upper()
        self.confidence, self.subpixel, self.lr_check = int(confidence), bool(subpixel), bool(lr_check)
        self.projector = float(projector)
        self.search_s, self.timeout_s = float(search_s), float(timeout_s)
        self._dai: Any = None
        self._device: Any = None
        self._pipeline: Any = None
        self._queues: dict[str, Any] = {}
        self._controls: list[Any] = []
        self._info: CameraInfo | None = None
        self._settings = CameraSettings(projector_on=False, exposure_us=float("nan"), gain=float("nan"), auto_exposure=True)
        self._pending: dict[int, dict[str, Any]] = {}
        if device_id:
            self.name = f"oak {device_id}"

    @classmethod
    def from_spec(cls, spec: DeviceSpec) -> "OakCamera":
        o = spec.take(OAK_OPTIONS)
        return cls(device_id=o["id"] or spec.path or None, width=o["width"], height=o["height"], fps=o["fps"],
                   preset=o["preset"], confidence=o["confidence"], subpixel=o["subpixel"], lr_check=o["lr_check"],
                   projector=o["projector"], search_s=o["search"], timeout_s=o["timeout"])

    # -- lifecycle -------------------------------------------------------------------------
    def find(self) -> Any:
        """The DeviceInfo to connect to; a one-line CameraError within about a second if there is none."""
        dai = self._dai = sdk(self.search_s)
        t0 = time.monotonic()
        with sdk_chatter_to_stderr():
            found = list(dai.Device.getAllAvailableDevices())
        if not found:
            raise CameraError(f"oak: no OAK device found (searched USB and the network for {time.monotonic() - t0:.1f} s); "
                              "plug the OAK-D into a USB 3 port and check with 'rig devices', "
                              "or simulate a camera with --camera fake:")
        if self.device_id is None:
            return found[0]
        for d in found:
            if self.device_id in (d.getDeviceId(), d.name):
                return d
        raise CameraError(f"oak: no device {self.device_id} (found: {', '.join(d.getDeviceId() for d in found)}); "
                          "use one of these ids, or leave id= out to take the first")

    def open(self) -> None:
        info = self.find()
        dai = self._dai
        try:
            with sdk_chatter_to_stderr():
                self._device = dai.Device(info)
            self._build_pipeline(dai)
            self._info = self._read_info(dai)
        except CameraError:
            self.close()
            raise
        except RuntimeError as e:
            self.close()
            raise CameraError(f"{self.name}: depthai could not start the camera ({(str(e).splitlines() or [''])[0]}); "
                              "unplug and replug it and use a USB 3 port") from None

    def _build_pipeline(self, dai: Any) -> None:
        p = self._pipeline = dai.Pipeline(self._device)
        size = (self.width, self.height)
        cams = []
        for socket in (dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C):
            cams.append(p.create(dai.node.Camera).build(socket, sensorFps=self.fps))
        stereo = self._stereo = p.create(dai.node.StereoDepth)
        try:
            stereo.setDefaultProfilePreset(getattr(dai.node.StereoDepth.PresetMode, self.preset))
        except AttributeError:
            names = [n for n in dir(dai.node.StereoDepth.PresetMode) if n.isupper()]
            raise CameraError(f"{self.name}: unknown StereoDepth preset {self.preset!r}; choose one of {names}") from None
        cams[0].requestOutput(size, type=dai.ImgFrame.Type.GRAY8, fps=self.fps).link(stereo.left)
        cams[1].requestOutput(size, type=dai.ImgFrame.Type.GRAY8, fps=self.fps).link(stereo.right)
        stereo.setDepthAlign(dai.CameraBoardSocket.CAM_B)
        stereo.setSubpixel(self.subpixel)
        stereo.setLeftRightCheck(self.lr_check)
        apply_stereo_settings(stereo.initialConfig, confidence=self.confidence, subpixel=self.subpixel, lr_check=self.lr_check)
        self._stereo_settings = stereo_settings(stereo.initialConfig, self.preset)
        check_raw(self._stereo_settings, self.name)
        self._queues = {"depth": stereo.depth.createOutputQueue(maxSize=8, blocking=False),
                        "left": stereo.syncedLeft.createOutputQueue(maxSize=8, blocking=False)}
        self._controls = [c.inputControl.createInputQueue() for c in cams]
        p.start()
        self._device.setIrFloodLightIntensity(0.0)
        self._device.setIrLaserDotProjectorIntensity(0.0)

    def close(self) -> None:
        for obj, step in ((self._pipeline, "stop"), (self._device, "close")):
            if obj is not None:
                try:
                    getattr(obj, step)()
                except RuntimeError:
                    pass
        self._pipeline = self._device = None
        self._queues, self._controls = {}, []
        self._pending.clear()

    def _read_info(self, dai: Any) -> CameraInfo:
        dev = self._device
        intrinsics, baseline_m = calibration_from_handler(dev.readCalibration(), self.width, self.height)
        return CameraInfo(
            model=str(dev.getProductName() or dev.getDeviceName()),
            serial=str(dev.getDeviceId()),
            firmware=str(dev.getBootloaderVersion() or "depthai " + dai.__version__),
            intrinsics=intrinsics,
            baseline_m=baseline_m,
            depth_scale_m=0.001,
            extra={"sdk": "depthai " + dai.__version__, "fps": self.fps, "usb_speed": str(dev.getUsbSpeed()).split(".")[-1],
                   "stereo": self._stereo_settings, "ir_drivers": [str(d) for d in dev.getIrDrivers()],
                   "projector_intensity_on": self.projector, "flood_light": 0.0,
                   "intrinsics_of": "left camera (CAM_B), depth aligned to it"},
        )

    def info(self) -> CameraInfo:
        self._require_open()
        assert self._info is not None
        return self._info

    # -- settings --------------------------------------------------------------------------
    def configure(self, settings: CameraSettings) -> CameraSettings:
        self._require_open()
        ctrl = exposure_control(settings)
        if settings.projector_on and not self._device.getIrDrivers():
            raise CameraError(f"{self.name}: this OAK has no IR dot projector (an OAK-D Pro has one); run with the projector off")
        period_us = 1e6 / self.fps
        if not settings.auto_exposure and settings.exposure_us > period_us:
            warnings.warn(f"{self.name}: exposure {settings.exposure_us:g} us is longer than the frame period "
                          f"{period_us:.0f} us at {self.fps:g} fps; choose at most {period_us:.0f} us or a lower fps",
                          RuntimeWarning, stacklevel=2)
        for q in self._controls:
            q.send(ctrl)
        self._device.setIrFloodLightIntensity(0.0)
        self._device.setIrLaserDotProjectorIntensity(self.projector if settings.projector_on else 0.0)
        self._settings = CameraSettings(projector_on=settings.projector_on, exposure_us=float("nan"), gain=float("nan"),
                                        auto_exposure=settings.auto_exposure)
        # read the settings back from the frames: the first frames after the change carry the old ones
        last = None
        for i, frame in enumerate(self._frames(SETTLE_FRAMES, ir=False)):
            last = frame.metadata
            if settings.auto_exposure or (abs(last.exposure_us - settings.exposure_us) <= max(1.0, 0.01 * settings.exposure_us)
                                          and abs(last.gain - settings.gain) <= 0.5):
                break
        if last is not None:
            self._settings = CameraSettings(projector_on=settings.projector_on, exposure_us=last.exposure_us,
                                            gain=last.gain, auto_exposure=settings.auto_exposure)
        return self.read_settings()

    def read_settings(self) -> CameraSettings:
        """Exposure and ISO as the latest frame reported them; projector and auto-exposure as last set."""
        return self._settings

    # -- frames ----------------------------------------------------------------------------
    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        self._require_open()
        # frames queued before this request were exposed earlier (e.g. while the stage moved): drop them,
        # and any still in flight, by their host-synchronised timestamps
        for q in self._queues.values():
            q.tryGetAll()
        self._pending.clear()
        for frame in self._frames(n, ir=ir, since=self._dai.Clock.now()):
            m = frame.metadata
            self._settings = CameraSettings(projector_on=m.projector_on, exposure_us=m.exposure_us, gain=m.gain,
                                            auto_exposure=m.auto_exposure)
            yield frame

    def _frames(self, n: int, *, ir: bool, since: datetime.timedelta | None = None) -> Iterator[Frame]:
        produced = 0
        while produced < n:
            got = False
            deadline = time.monotonic() + self.timeout_s
            while not got:
                for key, q in self._queues.items():
                    msg = q.tryGet()
                    if msg is None:
                        continue
                    got = True
                    if since is not None and msg.getTimestamp() < since:
                        continue
                    slot = self._pending.setdefault(int(msg.getSequenceNum()), {})
                    slot[key] = msg
                    if len(self._pending) > 64:
                        raise CameraError(f"{self.name}: depth and left frames do not pair up by sequence number; "
                                          "update depthai and the device firmware, then re-run with --resume")
                if not got:
                    if time.monotonic() > deadline:
                        raise CameraError(f"{self.name}: no frame for {self.timeout_s:g} s; check the USB 3 cable and port, "
                                          "then re-run with --resume")
                    time.sleep(0.002)
            for seq in sorted(k for k, v in self._pending.items() if "depth" in v and "left" in v):
                slot = self._pending.pop(seq)
                for old in [k for k in self._pending if k < seq]:
                    del self._pending[old]
                s = self._settings
                yield frame_from_messages(slot["depth"], slot["left"], projector_on=s.projector_on,
                                          auto_exposure=s.auto_exposure, ir=ir)
                produced += 1
                if produced >= n:
                    return

    def _require_open(self) -> None:
        if self._device is None:
            raise CameraError(f"{self.name}: not open; use it as a context manager ('with camera:') or call open()")


def open_oak(spec: DeviceSpec, context: dict[str, Any]) -> DepthCamera:
    """Factory for `oak:...` (see drivers.registry)."""
    return OakCamera.from_spec(spec)


OAK = DeviceKind("oak", "camera", open_oak, OAK_OPTIONS, Probe("oak", list_oak), summary="Luxonis OAK-D (depthai 3)",
                 exposure_us=(float(EXPOSURE_RANGE_US[0]), float(EXPOSURE_RANGE_US[1])), gain=OAK_GAIN)
