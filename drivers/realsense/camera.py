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

import time
import warnings
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..camera import CameraInfo, CameraSettings, DepthCamera, Frame, FrameMetadata
from ..errors import CameraError
from ..options import AT_LEAST_0, POSITIVE, Option, OptionTable
from ..registry import DeviceSpec
from .frame_buffer import QUEUE_FRAMES, FrameBuffer, Item
from .identity import read_info
from .metadata import projector_state
from .sdk import device_info, one_line, sdk

#: the device-string options (docs/hardware.md); `realsense:///path/run.db3` is file=
REALSENSE_OPTIONS = OptionTable("realsense", "camera", (
    Option("serial", str, None, None, "", "open the camera with this serial number", example="123456789012",
           absent="the first found"),
    Option("file", str, None, None, "", "play this recording back (.db3; .bag from SDK <= 2.58)", example="run.db3",
           absent="a live camera"),
    Option("record", str, None, None, "", "also record everything streamed to this file, with the SDK's recorder",
           example="run.db3", absent="none"),
    Option("width", int, 848, POSITIVE, "px", "depth mode width"),
    Option("height", int, 480, POSITIVE, "px", "depth mode height"),
    Option("fps", int, 30, POSITIVE, "fps", "depth mode frame rate"),
    Option("ir", bool, True, None, "", "stream the left IR image (0: only when a capture asks)"),
    Option("laser_power", float, None, AT_LEAST_0, "mW", "projector power applied when the projector is on",
           example=150, absent="leave the camera's"),
    Option("preset", str, None, None, "", "a visual preset, by name or number, applied at open",
           example="High Accuracy", absent="leave the camera's"),
    Option("timeout", float, 5.0, POSITIVE, "s", "how long to wait for a frame"),
), path="recording to play back (as file=)", error=CameraError)

#: timestamp domains that share the host clock, so frames older than a request can be told apart
HOST_CLOCK_DOMAINS = ("system_time", "global_time")


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
        self._buffer: FrameBuffer | None = None
        self._info: CameraInfo | None = None
        self._metadata_ok: bool | None = None
        self._played = 0
        self._last_raw: dict[str, float] | None = None  # the metadata of the last depth frame read
        self._last_number = -1
        self._pending: dict[int, dict[str, Any]] = {}
        if self.file is not None:
            self.name = f"realsense file {self.file.name}"
            self.plays_back = True  # settings as recorded (auto-exposure included), noted by the runner
        elif serial:
            self.name = f"realsense {serial}"

    @classmethod
    def from_spec(cls, spec: DeviceSpec) -> "RealSenseCamera":
        o = spec.take(REALSENSE_OPTIONS)
        return cls(
            serial=o["serial"],
            file=o["file"] or spec.path or None,
            record=o["record"],
            width=o["width"],
            height=o["height"],
            fps=o["fps"],
            ir=o["ir"],
            laser_power=o["laser_power"],
            preset=o["preset"],
            timeout_s=o["timeout"],
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
                serial = device_info(rs, dev, "serial_number")
                if serial:
                    self.name = f"realsense {serial}"
            if self.record is not None:
                try:
                    dev = rs.recorder(str(self.record), dev)
                except RuntimeError as e:
                    raise CameraError(f"{self.name}: cannot record to {self.record} ({one_line(e)}); "
                                      "use a writable path ending in .db3 (the SDK's format since 2.59)") from None
            self._dev = dev
            self._sensor = self._depth_sensor(rs, dev)
            if self.preset is not None and self._playback is None:
                self._apply_preset(rs)
            # read before streaming: a recording's options read while the SDK's playback thread replays the file
            # corrupted the heap now and then (about 1 open in 300 with three at once on 2 cores)
            self._info = read_info(rs, self._dev, self._sensor, *self._choose_profiles(rs, self.stream_ir), name=self.name,
                                   playback_file=self.file if self._playback is not None else None, record=self.record,
                                   advanced_mode=self._playback is None and self._given_device is None)
            self._start(with_ir=self.stream_ir)
        except CameraError:
            self.close()
            raise
        except RuntimeError as e:
            self.close()
            raise CameraError(f"{self.name}: the SDK refused to start the camera ({one_line(e)}); "
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
        found = [device_info(rs, d, "serial_number") for d in devices]
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
            ir = next((p for p in irs if same_mode(p, d)), None)
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
        self._buffer = FrameBuffer(rs, lossless=self._playback is not None)
        self._sensor.start(self._buffer)
        self._pending.clear()
        self._last_number = -1  # frame numbers start again with the stream

    def _restart(self, *, with_ir: bool) -> None:
        self._buffer.close()
        self._sensor.stop()
        self._sensor.close()
        self._start(with_ir=with_ir)

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
            raise CameraError(f"{self.name}: the camera refused {what} = {value:g}{unit} ({one_line(e)}); "
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
        """The camera's settings; a recording's as its frames' metadata state them (`_as_its_frames_say`)."""
        self._require_open()
        options = self._option_settings()
        return self._as_its_frames_say(options) if self._playback is not None else options

    def _option_settings(self) -> CameraSettings:
        rs = self._rs
        emitter = self._option(rs.option.emitter_enabled, 0.0)
        laser = self._option(rs.option.laser_power, None)
        return CameraSettings(
            projector_on=bool(emitter) and (laser is None or laser > 0),
            exposure_us=float(self._option(rs.option.exposure, float("nan"))),
            gain=float(self._option(rs.option.gain, float("nan"))),
            auto_exposure=bool(self._option(rs.option.enable_auto_exposure, 0.0)),
        )

    def _as_its_frames_say(self, options: CameraSettings) -> CameraSettings:
        """A recording's settings as the metadata of its next depth frame state them (of the last one read at its
        end; the first one waited for before any); the playback's options for what the metadata lack.

        The options are a snapshot the recorder took near the start, on the SDK's thread: they can differ from what
        the frames were exposed with (auto-exposure switched on as a recording began read back as off while its first
        frame had it on: 1 of 12 recordings, tests/test_realsense.py)."""
        wait_s = self.timeout_s if self._last_raw is None else 0.0
        item = self._buffer.first("depth", wait_s) if self._buffer is not None else None
        raw = item.metadata if item is not None else (self._last_raw or {})
        if "actual_exposure" not in raw:
            return options
        m = self._metadata(raw)
        emitter = any(k in raw for k in ("frame_emitter_mode", "frame_laser_power_mode", "frame_laser_power"))
        return CameraSettings(projector_on=m.projector_on if emitter else options.projector_on, exposure_us=m.exposure_us,
                              gain=m.gain if "gain_level" in raw else options.gain,
                              auto_exposure=m.auto_exposure if "auto_exposure" in raw else options.auto_exposure)

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
                self._last_raw = d.metadata
                yield Frame(depth=d.data, frame_number=number, timestamp_ms=d.timestamp_ms, metadata=self._metadata(d.metadata),
                            ir=slot["ir"].data if ir and "ir" in slot else None)

    def _next_item(self) -> "Item":
        rs = self._rs
        deadline = time.monotonic() + self.timeout_s
        while True:
            item = self._buffer.get(0.1)
            if item is not None:
                self._played += 1
                return item
            if self._buffer.error is not None:
                raise CameraError(f"{self.name}: reading a frame failed ({one_line(self._buffer.error)}); "
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


def same_mode(p: Any, d: Any) -> bool:
    v = p.as_video_stream_profile()
    return (v.width(), v.height()) == (d.width(), d.height())


def open_realsense(spec: DeviceSpec, context: dict[str, Any]) -> DepthCamera:
    """Factory for `realsense:...` (see drivers.registry)."""
    return RealSenseCamera.from_spec(spec)
