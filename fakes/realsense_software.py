"""A RealSense D4xx made of librealsense's own `rs.software_device`, seeing the fake world.

The SDK's software device is a device like any other to the SDK: sensors, stream profiles
with intrinsics, options, extrinsics, per-frame metadata, the recorder. This module fills
one with what a D435's depth sensor has (a "Stereo Module" with depth z16, left and right
IR y8, depth units, the stereo baseline, exposure, gain, auto-exposure, emitter and laser
power) and feeds it frames drawn by the fake camera's physics (`fakes.camera.FakeCamera`)
for the wall of a `FakeWorld`. `drivers.realsense.RealSenseCamera(device=...)` then drives
it exactly as it drives a real camera.

A feeder thread pushes a frame pair (depth and left IR, same frame number, host-clock
timestamps) whenever the sensor is streaming, at `rate_hz` (default: the stream's fps in
real time). Each frame is rendered with the settings the sensor's options hold when the
frame starts, and its metadata report them (actual_exposure, gain_level, auto_exposure,
frame_laser_power, frame_laser_power_mode, frame_emitter_mode) unless `report` overrides
what is reported, to simulate a camera that does not do what it is told.
"""

from __future__ import annotations

import threading
import time
from dataclasses import replace
from typing import Any

import numpy as np

from drivers.camera import CameraSettings
from drivers.realsense import RealSenseCamera, sdk

from .camera import FakeCamera
from .effects import parse_effects
from .world import FakeWorld

#: what a D435 reports before anyone configures it: auto-exposure on, projector on
CAMERA_DEFAULTS = CameraSettings(projector_on=True, exposure_us=8500.0, gain=16.0, auto_exposure=True)
#: the exposure the toy auto-exposure settles on, us
AUTO_EXPOSURE_US = 16000.0
#: laser power the emitter uses when on, mW (D435 default)
LASER_POWER_MW = 150.0

_range_quirk: bool | None = None


def option_range_args_swapped(rs: Any) -> bool:
    """True if this pyrealsense2 passes an option_range's step and default the wrong way round.

    pyrealsense2 2.59's `software_sensor.add_option(option, option_range(min, max, step, default))`
    registers `step` as the default and `default` as the step (so a default equal to min, like
    gain 16 in 16..248, is refused as out of range). Probed once on a throwaway sensor.
    """
    global _range_quirk
    if _range_quirk is None:
        probe = rs.software_device().add_sensor("probe")
        probe.add_option(rs.option.gain, rs.option_range(0.0, 10.0, 1.0, 5.0), True)
        r = probe.get_option_range(rs.option.gain)
        _range_quirk = bool(r.step == 5.0 and r.default == 1.0)
    return _range_quirk


def add_writable_option(rs: Any, sensor: Any, option: Any, lo: float, hi: float, step: float, default: float) -> None:
    """Register a writable option on a software sensor and check the SDK recorded it as meant."""
    args = (lo, hi, default, step) if option_range_args_swapped(rs) else (lo, hi, step, default)
    sensor.add_option(option, rs.option_range(*args), True)
    r = sensor.get_option_range(option)
    if (r.min, r.max, r.step, r.default) != (lo, hi, step, default):
        raise RuntimeError(f"software sensor option {option}: registered {r.min, r.max, r.step, r.default}, "
                           f"meant {lo, hi, step, default}")


class SoftwareRealSense:
    """An `rs.software_device` D435 whose frames come from `FakeCamera` physics.

    world: the fake wall (shared with a `FakeStage`). width, height, fps, depth_unit_mm,
    baseline_mm, seed, effects, light: as for the fake camera (`light="auto"`: the room light
    is on exactly when the projector is off, the paper's day-time passive and night-time
    active runs). initial: the options before anyone sets them (default: a D435's, with
    auto-exposure on). rate_hz: frames per second of wall-clock time the feeder pushes
    (default: fps). report: metadata to report instead of the truth, any of
    `auto_exposure`, `exposure_us`, `gain`, `projector_on`. keep_log: keep every depth frame
    pushed, by frame number, in `log`. clock: "host" stamps frames with the host's clock in the
    system_time domain (like a D4xx with global time on); "device" with the simulated camera's
    own clock in the hardware_clock domain.
    """

    def __init__(self, world: FakeWorld, *, width: int = 64, height: int = 36, fps: int = 30,
                 depth_unit_mm: float = 1.0, baseline_mm: float = 50.0, seed: int = 0, effects: str = "",
                 light: str = "auto", serial: str = "SW-D435-0001", initial: CameraSettings = CAMERA_DEFAULTS,
                 rate_hz: float | None = None, report: dict[str, Any] | None = None, keep_log: bool = False,
                 clock: str = "host"):
        rs = self.rs = sdk()
        self.world = world
        self.fps = int(fps)
        self.rate_hz = float(rate_hz or fps)
        self.report = dict(report or {})
        unknown = set(self.report) - {"auto_exposure", "exposure_us", "gain", "projector_on"}
        if unknown:
            raise ValueError(f"report: unknown key(s) {sorted(unknown)}; use auto_exposure, exposure_us, gain, projector_on")
        self.light = light
        self.fake = FakeCamera(world, width=width, height=height, baseline_m=baseline_mm / 1000.0,
                               depth_scale_m=depth_unit_mm / 1000.0, fps=fps, effects=parse_effects(effects),
                               seed=seed, serial=serial, light="night" if light == "auto" else light)
        if clock not in ("host", "device"):
            raise ValueError(f"clock={clock!r}; use 'host' (system_time timestamps) or 'device' (hardware_clock)")
        self.clock = clock
        self.keep_log = keep_log
        self.log: dict[int, np.ndarray] = {}
        self.pushed = 0
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._rendered: CameraSettings | None = None
        self._build(width, height, depth_unit_mm, baseline_mm, serial, initial)

    # -- the device --------------------------------------------------------------------------
    def _build(self, width: int, height: int, depth_unit_mm: float, baseline_mm: float, serial: str,
               initial: CameraSettings) -> None:
        rs = self.rs
        dev = self.device = rs.software_device()
        for key, value in (("name", "Intel RealSense D435 (software device, fake physics)"), ("serial_number", serial),
                           ("firmware_version", "5.16.0.1"), ("product_line", "D400"), ("product_id", "0B07"),
                           ("usb_type_descriptor", "3.2")):
            dev.register_info(getattr(rs.camera_info, key), value)
        s = self.sensor = dev.add_sensor("Stereo Module")
        i = self.fake.intrinsics
        intr = rs.intrinsics()
        intr.width, intr.height = i.width, i.height
        intr.fx, intr.fy, intr.ppx, intr.ppy = i.fx, i.fy, i.cx, i.cy
        intr.model = rs.distortion.brown_conrady
        intr.coeffs = [0.0] * 5

        def stream(kind: Any, index: int, fmt: Any, bpp: int, uid: int) -> Any:
            v = rs.video_stream()
            v.type, v.index, v.uid, v.width, v.height, v.fps, v.bpp, v.fmt = kind, index, uid, width, height, self.fps, bpp, fmt
            v.intrinsics = intr
            return v

        self.depth_profile = s.add_video_stream(stream(rs.stream.depth, 0, rs.format.z16, 2, 0), True)
        self.ir_profile = s.add_video_stream(stream(rs.stream.infrared, 1, rs.format.y8, 1, 1), True)
        self.ir2_profile = s.add_video_stream(stream(rs.stream.infrared, 2, rs.format.y8, 1, 2), False)
        s.add_read_only_option(rs.option.depth_units, depth_unit_mm / 1000.0)
        s.add_read_only_option(rs.option.stereo_baseline, baseline_mm)
        add_writable_option(rs, s, rs.option.enable_auto_exposure, 0, 1, 1, float(initial.auto_exposure))
        add_writable_option(rs, s, rs.option.exposure, 1, 165000, 1, float(round(initial.exposure_us)))
        add_writable_option(rs, s, rs.option.gain, 16, 248, 1, float(round(initial.gain)))
        add_writable_option(rs, s, rs.option.emitter_enabled, 0, 2, 1, float(initial.projector_on))
        add_writable_option(rs, s, rs.option.laser_power, 0, 360, 30, LASER_POWER_MW)
        identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        for target, tx in ((self.ir_profile, 0.0), (self.ir2_profile, -baseline_mm / 1000.0)):
            e = rs.extrinsics()
            e.rotation = identity
            e.translation = [tx, 0.0, 0.0]
            self.depth_profile.register_extrinsics_to(target, e)
        dev.create_matcher(rs.matchers.di)

    def camera(self, **kw: Any) -> RealSenseCamera:
        """The RealSense driver on this device (keyword arguments as for `RealSenseCamera`)."""
        return RealSenseCamera(device=self.device, **kw)

    # -- the feeder ----------------------------------------------------------------------------
    def start(self) -> "SoftwareRealSense":
        if self._thread is None:
            self.fake.open()
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="software-realsense", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        if self.error is not None:
            err, self.error = self.error, None
            raise RuntimeError(f"software RealSense feeder failed: {err}") from err

    def __enter__(self) -> "SoftwareRealSense":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def settings_now(self) -> CameraSettings:
        """The settings the sensor's options hold now (what the next frame is rendered with)."""
        rs, s = self.rs, self.sensor
        auto = bool(s.get_option(rs.option.enable_auto_exposure))
        on = bool(s.get_option(rs.option.emitter_enabled)) and s.get_option(rs.option.laser_power) > 0
        exposure = AUTO_EXPOSURE_US if auto else float(s.get_option(rs.option.exposure))
        return CameraSettings(projector_on=on, exposure_us=exposure, gain=float(s.get_option(rs.option.gain)),
                              auto_exposure=auto)

    def _run(self) -> None:
        try:
            period = 1.0 / self.rate_hz
            next_t = time.monotonic()
            while not self._stop.is_set():
                active = {(p.stream_type(), p.stream_index()) for p in self.sensor.get_active_streams()}
                if not active:
                    time.sleep(0.002)
                    next_t = time.monotonic()
                    continue
                self._push_one(active)
                next_t += period
                delay = next_t - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                else:
                    next_t = time.monotonic()
        except BaseException as e:  # reported by stop()
            self.error = e

    def _push_one(self, active: set) -> None:
        rs, s = self.rs, self.sensor
        settings = self.settings_now()
        if settings != self._rendered:
            if self.light == "auto":
                self.fake._room_lit = not settings.projector_on  # the room light follows the projector
            self.fake.configure(settings)
            self._rendered = settings
        want_depth = (rs.stream.depth, 0) in active
        want_ir = (rs.stream.infrared, 1) in active
        stamp_ms = time.time() * 1000.0  # taken before the world is read: frames later than a request saw it
        frame = next(self.fake.frames(1, ir=want_ir))
        if self.clock == "device":
            stamp_ms = frame.timestamp_ms
        reported = replace(settings, **self.report)
        md = rs.frame_metadata_value
        laser = LASER_POWER_MW if reported.projector_on else 0.0
        for key, value in ((md.actual_exposure, reported.exposure_us), (md.gain_level, reported.gain),
                           (md.auto_exposure, float(reported.auto_exposure)), (md.frame_laser_power, laser),
                           (md.frame_laser_power_mode, float(reported.projector_on)),
                           (md.frame_emitter_mode, 1.0 if reported.projector_on else 0.0),
                           (md.frame_counter, float(frame.frame_number)), (md.actual_fps, float(self.fps))):
            s.set_metadata(key, int(round(value)))
        if want_depth:
            self._inject(self.depth_profile, frame.depth, 2, frame.frame_number, stamp_ms, depth=True)
            if self.keep_log:
                self.log[frame.frame_number] = frame.depth
        if want_ir and frame.ir is not None:
            ir8 = np.ascontiguousarray((frame.ir >> 2).astype(np.uint8))  # 10-bit to the y8 stream
            self._inject(self.ir_profile, ir8, 1, frame.frame_number, stamp_ms, depth=False)
        self.pushed += 1

    def _inject(self, profile: Any, pixels: np.ndarray, bpp: int, number: int, stamp_ms: float, *, depth: bool) -> None:
        rs = self.rs
        f = rs.software_video_frame()
        f.pixels = np.ascontiguousarray(pixels)
        f.stride = pixels.shape[1] * bpp
        f.bpp = bpp
        f.timestamp = stamp_ms
        f.domain = rs.timestamp_domain.system_time if self.clock == "host" else rs.timestamp_domain.hardware_clock
        f.frame_number = number
        f.profile = profile.as_video_stream_profile()
        if depth:
            f.depth_units = self.fake.depth_scale_m
        try:
            self.sensor.on_video_frame(f)
        except RuntimeError:
            if self.sensor.get_active_streams():  # stopping between the check and the push is fine
                raise
