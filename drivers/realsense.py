"""Intel RealSense D4xx depth cameras through librealsense (pyrealsense2). Camera kind `realsense`.

Device strings:

    realsense:                                  the first RealSense camera found
    realsense:serial=123456789012               a given camera
    realsense:width=848,height=480,fps=30       the depth mode (these are the defaults)
    realsense:ir=0                              do not stream the left IR image unless a capture asks
    realsense:laser_power=150                   projector power in mW when the projector is on
    realsense:preset=High Accuracy              a visual preset, by name or number, applied at open
    realsense:record=run.db3                    also record everything streamed, with the SDK's recorder
    realsense:file=run.db3                      play a recording back (.db3; .bag from SDK <= 2.58)
    realsense:timeout=5                         seconds to wait for a frame

The driver uses the SDK's sensor API, the same building blocks `rs.pipeline` is made of: it
finds the depth sensor, opens the depth (z16) and left IR (y8) profiles of the chosen mode,
starts the sensor with a callback that copies each frame out of the SDK at once, and pairs
depth and IR frames by frame number.
The same code path therefore drives a real camera, a recording played back, and a
`rs.software_device` (see `fakes.realsense_software`), which the SDK's pipeline cannot see
from pyrealsense2 2.55 on (docs/hardware.md).

Importing this module never imports pyrealsense2; using the driver without it (or without
the system's libusb-1.0) raises a one-line `CameraError` naming what to install.
"""

from __future__ import annotations

import collections
import math
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from drivers.camera import CameraInfo, CameraSettings, DepthCamera, Frame, FrameMetadata, Intrinsics
from drivers.errors import CameraError
from rig.devices import DeviceSpec, register_camera

#: frames the host-side queue holds (depth and IR count separately); older ones are dropped
QUEUE_FRAMES = 64
#: timestamp domains that share the host clock, so frames older than a request can be told apart
HOST_CLOCK_DOMAINS = ("system_time", "global_time")
INSTALL_SDK = "pip install pyrealsense2"
INSTALL_LIBUSB = "apt-get install libusb-1.0-0"


def sdk() -> Any:
    """Import pyrealsense2, or raise a one-line CameraError saying what is missing and how to install it."""
    try:
        import pyrealsense2 as rs
    except ImportError as e:
        raise CameraError(import_problem(e)) from None
    if not hasattr(rs, "context"):  # the package is there but its compiled module did not load
        raise CameraError(f"realsense: pyrealsense2 is installed but incomplete; reinstall it with "
                          f"'pip install --force-reinstall pyrealsense2' and '{INSTALL_LIBUSB}'")
    return rs


def import_problem(e: ImportError) -> str:
    """The one-line message for a failed `import pyrealsense2`."""
    text = (str(e).splitlines() or [""])[0]
    if "libusb" in text:
        return (f"realsense: the system library libusb-1.0 that pyrealsense2 needs is missing ({text}); "
                f"install it with '{INSTALL_LIBUSB}', or simulate a camera with --camera fake:")
    if getattr(e, "name", None) == "pyrealsense2" or isinstance(e, ModuleNotFoundError):
        return (f"realsense: the Python package pyrealsense2 is not installed; install it with '{INSTALL_SDK}' "
                f"(it also needs '{INSTALL_LIBUSB}'), or simulate a camera with --camera fake:")
    return (f"realsense: pyrealsense2 failed to import ({text}); reinstall it with '{INSTALL_SDK}' "
            f"and '{INSTALL_LIBUSB}', or simulate a camera with --camera fake:")


def _one_line(e: BaseException) -> str:
    return (str(e).strip().splitlines() or [type(e).__name__])[0]


class RealSenseCamera(DepthCamera):
    """An Intel RealSense D4xx (or a recording of one, or a software device standing in for one).

    serial: open this camera (default: the first found). file: play this recording back.
    record: also record everything streamed to this file (.db3 with SDK 2.59+).
    context: an `rs.context` to search instead of a new one. device: use this `rs.device`
    directly (e.g. an `rs.software_device`) instead of searching.
    laser_power: projector power in mW applied when the projector is on (default: leave it).
    preset: a visual preset (name or number) applied at open.
    """

    name = "realsense"

    def __init__(self, *, serial: str | None = None, file: str | Path | None = None, record: str | Path | None = None,
                 width: int = 848, height: int = 480, fps: int = 30, ir: bool = True, laser_power: float | None = None,
                 preset: str | None = None, timeout_s: float = 5.0, context: Any = None, device: Any = None):
        self.serial = serial
        self.file = Path(file) if file else None
        self.record = Path(record) if record else None
        self.width, self.height, self.fps = int(width), int(height), int(fps)
        self.stream_ir = bool(ir)
        self.laser_power = laser_power
        self.preset = preset
        self.timeout_s = float(timeout_s)
        self._context = context
        self._given_device = device
        self._rs: Any = None
        self._dev: Any = None
        self._playback: Any = None
        self._sensor: Any = None
        self._profiles: list = []
        self._ir_profile: Any = None
        self._buffer: _FrameBuffer | None = None
        self._info: CameraInfo | None = None
        self._metadata_ok: bool | None = None
        self._played = 0
        self._last_number = -1
        self._pending: dict[int, dict[str, Any]] = {}
        if self.file is not None:
            self.name = f"realsense file {self.file.name}"
        elif serial:
            self.name = f"realsense {serial}"

    @classmethod
    def from_spec(cls, spec: DeviceSpec) -> "RealSenseCamera":
        known = {"serial", "file", "record", "width", "height", "fps", "ir", "laser_power", "preset", "timeout"}
        unknown = set(spec.options) - known
        if unknown:
            raise CameraError(f"realsense: unknown option(s) {sorted(unknown)} in {spec.text!r}; it takes {sorted(known)}")
        o = spec.options
        return cls(
            serial=o.get("serial") or None,
            file=o.get("file") or spec.path or None,
            record=o.get("record") or None,
            width=spec.int("width", 848),
            height=spec.int("height", 480),
            fps=spec.int("fps", 30),
            ir=o.get("ir", "1").lower() not in ("0", "off", "false", "no"),
            laser_power=spec.float("laser_power", float("nan")) if "laser_power" in o else None,
            preset=o.get("preset") or None,
            timeout_s=spec.float("timeout", 5.0),
        )

    # -- lifecycle -------------------------------------------------------------------------
    def open(self) -> None:
        rs = self._rs = sdk()
        try:
            if self.file is not None:
                if not self.file.exists():
                    raise CameraError(f"{self.name}: {self.file} does not exist; check the path of the recording")
                ctx = rs.context()
                dev = ctx.load_device(str(self.file))
                self._playback = dev.as_playback()
                self._playback.set_real_time(False)  # every frame, as fast as they are read
            elif self._given_device is not None:
                dev = self._given_device
            else:
                dev = self._find_device(rs)
            if self.serial is None and self.file is None:
                serial = _info(rs, dev, "serial_number")
                if serial:
                    self.name = f"realsense {serial}"
            if self.record is not None:
                try:
                    dev = rs.recorder(str(self.record), dev)
                except RuntimeError as e:
                    raise CameraError(f"{self.name}: cannot record to {self.record} ({_one_line(e)}); "
                                      "use a writable path ending in .db3 (the SDK's format since 2.59)") from None
            self._dev = dev
            self._sensor = self._depth_sensor(rs, dev)
            if self.preset is not None and self._playback is None:
                self._apply_preset(rs)
            self._start(with_ir=self.stream_ir)
            self._info = self._read_info(rs)
        except CameraError:
            self.close()
            raise
        except RuntimeError as e:
            self.close()
            raise CameraError(f"{self.name}: the SDK refused to start the camera ({_one_line(e)}); "
                              "unplug and replug it, check that no other program uses it, and try again") from None

    def close(self) -> None:
        if self._buffer is not None:
            self._buffer.close()  # lets a callback waiting for room return, so stop() can finish
        if self._sensor is not None:
            for step in ("stop", "close"):
                try:
                    getattr(self._sensor, step)()
                except RuntimeError:
                    pass
        # drop every SDK object so a recorder finalises its file and a playback releases it
        self._sensor = self._buffer = self._dev = self._playback = None
        self._profiles, self._ir_profile = [], None
        self._pending.clear()

    def _find_device(self, rs: Any) -> Any:
        ctx = self._context or rs.context()
        devices = list(ctx.query_devices())
        if not devices:
            raise CameraError("realsense: no RealSense camera is connected (none found on USB); plug one into a USB 3 "
                              "port and check with 'rig devices', or simulate a camera with --camera fake:")
        if self.serial is None:
            return devices[0]
        found = [_info(rs, d, "serial_number") for d in devices]
        for d, s in zip(devices, found):
            if s == self.serial:
                return d
        raise CameraError(f"realsense: no camera with serial {self.serial} (connected: {', '.join(found)}); "
                          "use one of these serials, or leave serial= out to take the first")

    def _depth_sensor(self, rs: Any, dev: Any) -> Any:
        for s in dev.query_sensors():
            if any(p.stream_type() == rs.stream.depth for p in s.get_stream_profiles()):
                return s
        raise CameraError(f"{self.name}: the device has no depth stream; use a RealSense D4xx depth camera")

    def _apply_preset(self, rs: Any) -> None:
        s, opt = self._sensor, rs.option.visual_preset
        if not s.supports(opt):
            raise CameraError(f"{self.name}: this camera has no visual presets; leave preset= out")
        r = s.get_option_range(opt)
        names = {s.get_option_value_description(opt, float(v)).lower(): float(v)
                 for v in np.arange(r.min, r.max + 0.5, max(r.step, 1.0))}
        key = str(self.preset).strip().lower()
        value = names.get(key)
        if value is None:
            try:
                value = float(key)
            except ValueError:
                raise CameraError(f"{self.name}: unknown visual preset {self.preset!r}; choose one of "
                                  f"{sorted(names)}") from None
        s.set_option(opt, value)

    def _choose_profiles(self, rs: Any, with_ir: bool) -> tuple[Any, Any]:
        profiles = list(self._sensor.get_stream_profiles())
        depth = [p for p in profiles if p.stream_type() == rs.stream.depth and p.format() == rs.format.z16]
        irs = [p for p in profiles if p.stream_type() == rs.stream.infrared and p.stream_index() == 1
               and p.format() == rs.format.y8]
        if self._playback is not None:  # a recording offers what was recorded
            if not depth:
                raise CameraError(f"{self.name}: the recording holds no depth stream; record depth (z16) with the camera")
            d = depth[0].as_video_stream_profile()
            ir = next((p for p in irs if _same_mode(p, d)), None)
            return depth[0], ir if with_ir else None

        def mode(p: Any) -> tuple[int, int, int]:
            v = p.as_video_stream_profile()
            return v.width(), v.height(), v.fps()

        want = (self.width, self.height, self.fps)
        d = next((p for p in depth if mode(p) == want), None)
        if d is None:
            have = sorted({mode(p) for p in depth}, reverse=True)
            listed = ", ".join(f"{w}x{h}@{f}" for w, h, f in have[:12])
            raise CameraError(f"{self.name}: no depth mode {self.width}x{self.height} at {self.fps} fps; "
                              f"it offers {listed}; pass width=, height= and fps= accordingly")
        ir = next((p for p in irs if mode(p) == want), None)
        if with_ir and ir is None:
            raise CameraError(f"{self.name}: no left IR (y8) stream at {self.width}x{self.height} {self.fps} fps; "
                              "choose a mode that has one, or pass ir=0")
        return d, ir if with_ir else None

    def _start(self, *, with_ir: bool) -> None:
        rs = self._rs
        depth, ir = self._choose_profiles(rs, with_ir)
        self._profiles = [depth] + ([ir] if ir is not None else [])
        self._ir_profile = ir
        self._sensor.open(self._profiles)
        self._buffer = _FrameBuffer(rs, lossless=self._playback is not None)
        self._sensor.start(self._buffer)
        self._pending.clear()
        self._last_number = -1  # frame numbers start again with the stream

    def _restart(self, *, with_ir: bool) -> None:
        self._buffer.close()
        self._sensor.stop()
        self._sensor.close()
        self._start(with_ir=with_ir)

    # -- identity and calibration ------------------------------------------------------------
    def _read_info(self, rs: Any) -> CameraInfo:
        dev, s = self._dev, self._sensor
        depth = self._profiles[0].as_video_stream_profile()
        intr = depth.get_intrinsics()
        intrinsics = Intrinsics(width=intr.width, height=intr.height, fx=float(intr.fx), fy=float(intr.fy),
                                cx=float(intr.ppx), cy=float(intr.ppy))
        if s.supports(rs.option.depth_units):
            depth_scale = float(s.get_option(rs.option.depth_units))
        else:
            depth_scale = float(s.as_depth_sensor().get_depth_scale())
        baseline, source = self._baseline(rs)
        extra: dict[str, Any] = {
            "sdk": "pyrealsense2 " + str(getattr(rs, "__version__", "?")),
            "source": f"playback of {self.file}" if self._playback is not None else "device",
            "fps": depth.fps(),
            "depth_stream": f"{intr.width}x{intr.height} z16 @ {depth.fps()} fps",
            "ir_stream": "left y8" if self._ir_profile is not None else "off",
            "distortion": {"model": str(intr.model).split(".")[-1], "coeffs": [float(c) for c in intr.coeffs]},
            "baseline_source": source,
        }
        for key in ("usb_type_descriptor", "product_line", "product_id", "camera_locked", "firmware_update_id",
                    "asic_serial_number", "physical_port"):
            v = _info(rs, dev, key)
            if v:
                extra["usb_type" if key == "usb_type_descriptor" else key] = v
        if self.record is not None:
            extra["recording_to"] = str(self.record)
        extra["options"] = self._all_options(rs)
        if s.supports(rs.option.visual_preset):
            v = s.get_option(rs.option.visual_preset)
            try:
                extra["visual_preset"] = s.get_option_value_description(rs.option.visual_preset, v)
            except RuntimeError:
                extra["visual_preset"] = v
        adv = self._advanced_mode_json(rs)
        if adv is not None:
            extra["advanced_mode_json"] = adv
        return CameraInfo(
            model=_info(rs, dev, "name") or "Intel RealSense",
            serial=_info(rs, dev, "serial_number") or "",
            firmware=_info(rs, dev, "firmware_version") or "",
            intrinsics=intrinsics,
            baseline_m=baseline,
            depth_scale_m=depth_scale,
            extra=extra,
        )

    def _baseline(self, rs: Any) -> tuple[float, str]:
        """Baseline in m: extrinsics between the IR imagers, else depth -> right IR, else the option."""
        profiles = list(self._sensor.get_stream_profiles())
        ir1 = [p for p in profiles if p.stream_type() == rs.stream.infrared and p.stream_index() == 1]
        ir2 = [p for p in profiles if p.stream_type() == rs.stream.infrared and p.stream_index() == 2]
        for name, a, b in (("extrinsics left IR -> right IR", ir1, ir2), ("extrinsics depth -> right IR", self._profiles[:1], ir2)):
            if a and b:
                try:
                    t = a[0].get_extrinsics_to(b[0]).translation
                except RuntimeError:
                    continue
                b_m = math.sqrt(sum(float(x) ** 2 for x in t))
                if b_m > 1e-4:
                    return b_m, name
        if self._sensor.supports(rs.option.stereo_baseline):
            return float(self._sensor.get_option(rs.option.stereo_baseline)) / 1000.0, "option stereo_baseline (mm)"
        raise CameraError(f"{self.name}: the camera reports no baseline (no right-IR extrinsics and no stereo_baseline "
                          "option); record the right IR stream too, or use a D4xx camera")

    def _all_options(self, rs: Any) -> dict[str, float]:
        out: dict[str, float] = {}
        for opt in self._sensor.get_supported_options():
            try:
                out[str(opt).split(".")[-1]] = float(self._sensor.get_option(opt))
            except RuntimeError:
                pass
        return out

    def _advanced_mode_json(self, rs: Any) -> str | None:
        if self._playback is not None or self._given_device is not None:
            return None
        try:
            adv = rs.rs400_advanced_mode(self._dev)
            return adv.serialize_json() if adv.is_enabled() else None
        except (RuntimeError, TypeError):
            return None

    def info(self) -> CameraInfo:
        self._require_open()
        assert self._info is not None
        return self._info

    # -- settings --------------------------------------------------------------------------
    def _option(self, opt: Any, default: float | None = None) -> float | None:
        if self._sensor.supports(opt):
            return float(self._sensor.get_option(opt))
        return default

    def _set(self, opt: Any, value: float, what: str, unit: str = "") -> None:
        s = self._sensor
        if not s.supports(opt):
            raise CameraError(f"{self.name}: the camera has no {what} control; use a D4xx camera or leave the setting at its default")
        r = s.get_option_range(opt)
        if not r.min <= value <= r.max:
            raise CameraError(f"{self.name}: {what} {value:g}{unit} is outside {r.min:g}-{r.max:g}{unit}; choose one inside")
        try:
            s.set_option(opt, float(value))
        except RuntimeError as e:
            raise CameraError(f"{self.name}: the camera refused {what} = {value:g}{unit} ({_one_line(e)}); "
                              "check that no other program controls it") from None

    def configure(self, settings: CameraSettings) -> CameraSettings:
        self._require_open()
        rs = self._rs
        if self._playback is not None:
            return self.read_settings()  # a recording's settings are what they were; the runner compares
        self._set(rs.option.enable_auto_exposure, 1.0 if settings.auto_exposure else 0.0, "auto-exposure")
        if not settings.auto_exposure:
            self._set(rs.option.exposure, float(round(settings.exposure_us)), "exposure", " us")
            self._set(rs.option.gain, float(round(settings.gain)), "gain")
        if self._sensor.supports(rs.option.emitter_enabled):
            self._set(rs.option.emitter_enabled, 1.0 if settings.projector_on else 0.0, "emitter")
        elif settings.projector_on:
            raise CameraError(f"{self.name}: the camera has no projector control; run with the projector off")
        if settings.projector_on and self.laser_power is not None:
            self._set(rs.option.laser_power, float(self.laser_power), "laser power", " mW")
        period_us = 1e6 / max(1, self._profiles[0].fps())
        if not settings.auto_exposure and settings.exposure_us > period_us:
            warnings.warn(f"{self.name}: exposure {settings.exposure_us:g} us is longer than the frame period "
                          f"{period_us:.0f} us at {self._profiles[0].fps()} fps, so the camera drops frames or "
                          f"shortens it; choose at most {period_us:.0f} us or a lower fps", RuntimeWarning, stacklevel=2)
        self._pending.clear()
        return self.read_settings()

    def read_settings(self) -> CameraSettings:
        self._require_open()
        rs = self._rs
        emitter = self._option(rs.option.emitter_enabled, 0.0)
        laser = self._option(rs.option.laser_power, None)
        return CameraSettings(
            projector_on=bool(emitter) and (laser is None or laser > 0),
            exposure_us=float(self._option(rs.option.exposure, float("nan"))),
            gain=float(self._option(rs.option.gain, float("nan"))),
            auto_exposure=bool(self._option(rs.option.enable_auto_exposure, 0.0)),
        )

    # -- frames ----------------------------------------------------------------------------
    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        self._require_open()
        if ir and self._ir_profile is None and self._playback is None:
            self._restart(with_ir=True)
        pair = ir and self._ir_profile is not None
        live = self._playback is None
        requested_ms = time.time() * 1000.0
        last_before = self._last_number
        if live:  # frames already buffered were exposed before this request (e.g. during a stage move)
            last_before = max(last_before, self._buffer.drain())
            self._pending.clear()
        produced = 0
        while produced < n:
            item = self._next_item()
            number = item.number
            self._last_number = max(self._last_number, number)
            if live:
                # host-clock timestamps tell directly whether a frame began before the request; with the
                # camera's own clock, skip the frame that was in flight while the buffer was drained
                if item.domain in HOST_CLOCK_DOMAINS:
                    if item.timestamp_ms <= requested_ms:
                        continue
                elif number <= last_before + 1:
                    continue
            if item.kind == "ir" and not pair:
                continue
            slot = self._pending.setdefault(number, {})
            if len(self._pending) > QUEUE_FRAMES:
                raise CameraError(f"{self.name}: depth and IR frames do not pair up by frame number; update the camera's "
                                  "firmware, or pass ir=0 and capture without the IR image")
            slot[item.kind] = item
            if "depth" in slot and (not pair or "ir" in slot):
                del self._pending[number]
                for old in [k for k in self._pending if k < number]:  # partners that will never come
                    del self._pending[old]
                produced += 1
                d = slot["depth"]
                yield Frame(depth=d.data, frame_number=number, timestamp_ms=d.timestamp_ms, metadata=self._metadata(d.metadata),
                            ir=slot["ir"].data if ir and "ir" in slot else None)

    def _next_item(self) -> "_Item":
        rs = self._rs
        deadline = time.monotonic() + self.timeout_s
        while True:
            item = self._buffer.get(0.1)
            if item is not None:
                self._played += 1
                return item
            if self._buffer.error is not None:
                raise CameraError(f"{self.name}: reading a frame failed ({_one_line(self._buffer.error)}); "
                                  "unplug and replug the camera and re-run with --resume")
            if self._playback is not None and self._playback.current_status() == rs.playback_status.stopped:
                item = self._buffer.get(0.0)
                if item is not None:
                    self._played += 1
                    return item
                raise CameraError(f"{self.name}: the recording ended after {self._played} frames; "
                                  "ask for fewer frames or record a longer one")
            if time.monotonic() > deadline:
                raise CameraError(f"{self.name}: no frame for {self.timeout_s:g} s; check the USB 3 cable and port "
                                  "(a USB 2 link may not carry this mode), then re-run with --resume")

    def _metadata(self, raw: dict[str, float]) -> FrameMetadata:
        exposure = raw.get("actual_exposure")
        if exposure is None:
            if self._metadata_ok is None:
                warnings.warn(f"{self.name}: frames carry no metadata, so exposure, gain and projector state are taken "
                              "from the options instead of each frame; on Linux use a kernel with the RealSense "
                              "metadata patch (or a librealsense built for the RSUSB backend)", RuntimeWarning, stacklevel=3)
            self._metadata_ok = False
            s = self.read_settings()
            return FrameMetadata(exposure_us=s.exposure_us, gain=s.gain, projector_on=s.projector_on,
                                 auto_exposure=s.auto_exposure)
        self._metadata_ok = True
        auto = raw.get("auto_exposure")
        return FrameMetadata(
            exposure_us=exposure,
            gain=raw.get("gain_level", float("nan")),
            projector_on=projector_state(raw.get("frame_emitter_mode"), raw.get("frame_laser_power_mode"),
                                         raw.get("frame_laser_power")),
            auto_exposure=bool(auto) if auto is not None else False,
        )

    def _require_open(self) -> None:
        if self._sensor is None:
            raise CameraError(f"{self.name}: not open; use it as a context manager ('with camera:') or call open()")


METADATA_KEYS = ("actual_exposure", "gain_level", "auto_exposure", "frame_emitter_mode", "frame_laser_power_mode",
                 "frame_laser_power")


@dataclass
class _Item:
    """One frame copied out of the SDK: which stream, its number, clock, metadata and pixels."""

    kind: str  # "depth" or "ir"
    number: int
    timestamp_ms: float
    domain: str
    metadata: dict[str, float]
    data: np.ndarray


class _FrameBuffer:
    """The sensor's frame callback: copies each frame out at once (so the SDK's frame pool never
    runs dry) into a bounded buffer.

    Live, a full buffer drops its oldest frame, as the SDK's own queues do. Playing a recording
    back (not in real time) it is lossless: the SDK's thread waits in the callback until the
    reader has made room. (An `rs.frame_queue(keep_frames=True)` deadlocks there with
    pyrealsense2 2.59 as soon as the reader is slower than the file; docs/hardware.md.)
    """

    def __init__(self, rs: Any, *, lossless: bool, size: int = QUEUE_FRAMES):
        self.rs = rs
        self.lossless = lossless
        self.size = size
        self.items: collections.deque[_Item] = collections.deque()
        self.cv = threading.Condition()
        self.closed = False
        self.error: BaseException | None = None
        md = rs.frame_metadata_value
        self._md = [(k, getattr(md, k)) for k in METADATA_KEYS if hasattr(md, k)]

    def __call__(self, f: Any) -> None:  # on the SDK's thread
        try:
            rs = self.rs
            p = f.get_profile()
            stype = p.stream_type()
            if stype == rs.stream.depth:
                kind = "depth"
            elif stype == rs.stream.infrared and p.stream_index() == 1:
                kind = "ir"
            else:
                return
            raw = {k: float(f.get_frame_metadata(v)) for k, v in self._md if f.supports_frame_metadata(v)} if kind == "depth" else {}
            item = _Item(kind, int(f.get_frame_number()), float(f.get_timestamp()), _domain(f), raw,
                         np.array(np.asanyarray(f.get_data()), copy=True))
        except BaseException as e:  # reported to the reader
            self.error = e
            return
        with self.cv:
            if self.lossless:
                while len(self.items) >= self.size and not self.closed:
                    self.cv.wait(0.05)
            elif len(self.items) >= self.size:
                self.items.popleft()
            if not self.closed:
                self.items.append(item)
                self.cv.notify_all()

    def get(self, timeout_s: float) -> _Item | None:
        with self.cv:
            if not self.items and timeout_s > 0:
                self.cv.wait_for(lambda: bool(self.items) or self.closed, timeout_s)
            if not self.items:
                return None
            item = self.items.popleft()
            self.cv.notify_all()
            return item

    def drain(self) -> int:
        """Discard every buffered frame; return the highest frame number discarded (-1 if none)."""
        with self.cv:
            last = max((i.number for i in self.items), default=-1)
            self.items.clear()
            self.cv.notify_all()
            return last

    def close(self) -> None:
        with self.cv:
            self.closed = True
            self.cv.notify_all()


def projector_state(emitter_mode: float | None, laser_power_mode: float | None, laser_power_mw: float | None) -> bool:
    """Whether a frame was exposed with the projector on, from its metadata.

    frame_emitter_mode (newer firmware): 0 = all emitters off, 1 = laser, 2 = laser auto, 3 = LED.
    frame_laser_power_mode (D4xx): 1 = emitter on, 0 = off. frame_laser_power: mW, 0 = off.
    """
    if emitter_mode is not None:
        on = emitter_mode != 0
    elif laser_power_mode is not None:
        on = laser_power_mode != 0
    else:
        on = laser_power_mw is None or laser_power_mw > 0
    if laser_power_mw is not None and laser_power_mw <= 0:
        on = False
    return bool(on)


def _info(rs: Any, dev: Any, key: str) -> str:
    ci = getattr(rs.camera_info, key, None)
    try:
        return str(dev.get_info(ci)) if ci is not None and dev.supports(ci) else ""
    except RuntimeError:
        return ""


def _domain(f: Any) -> str:
    return str(f.get_frame_timestamp_domain()).split(".")[-1]


def _same_mode(p: Any, d: Any) -> bool:
    v = p.as_video_stream_profile()
    return (v.width(), v.height()) == (d.width(), d.height())


def list_realsense() -> list[dict[str, str]]:
    """Connected RealSense cameras as plain data (for `rig devices`); raises CameraError without the SDK."""
    rs = sdk()
    out = []
    for d in rs.context().query_devices():
        out.append({"kind": "realsense", "model": _info(rs, d, "name"), "serial": _info(rs, d, "serial_number"),
                    "firmware": _info(rs, d, "firmware_version"), "usb": _info(rs, d, "usb_type_descriptor"),
                    "string": f"realsense:serial={_info(rs, d, 'serial_number')}"})
    return out


@register_camera("realsense")
def _realsense_camera(spec: DeviceSpec, world: Any) -> DepthCamera:
    return RealSenseCamera.from_spec(spec)
