"""A simulated stereo depth camera looking at the wall of a `FakeWorld`.

Defaults are those of a RealSense D435 depth stream at 848x480: fx = fy = 425 px, baseline
50 mm, depth unit 1 mm, 30 fps. A smaller image bins native pixels (see `fakes.physics`), so
the range noise is the same at any resolution and only the number of samples changes.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Iterator

import numpy as np

from drivers.camera import CameraInfo, CameraSettings, DepthCamera, Frame, FrameMetadata, Intrinsics
from drivers.errors import CameraError
from drivers.options import AT_LEAST_0, Check, Option, OptionTable, below, between, one_of

from .effects import Effect, parse_effects
from .kinds import EXPOSURE_RANGE_US, GAIN
from .render import depth_from_disparity, depth_from_noise, ir_from_uniform, temporal_filter
from .physics import NATIVE_FX_PX, NATIVE_WIDTH, FrameContext, SensorPhysics, StopField, base_truth, build_field
from .world import FakeWorld

#: digital numbers per photo-electron of the IR image at gain 16 (x1); the image is 10-bit (Y16)
IR_DN_PER_E = 0.04
IR_MAX_DN = 1023

_NUMBER = Check(lambda v: 0 < v < 1e4, "above 0 and below 10000")
#: the options of `fake:` cameras (FakeCamera.from_options)
FAKE_CAMERA_OPTIONS = OptionTable("fake", "camera", (
    Option("width", int, NATIVE_WIDTH, between(4, 4096), "px", "image width (a D455 is 1280x720 at most)", example=424),
    Option("height", int, None, between(2, 4096), "px", "image height", example=240, absent="width * 480 / 848"),
    Option("depth_unit_mm", float, 1.0, _NUMBER, "mm", "depth unit: the size of one depth count"),
    Option("baseline_mm", float, 50.0, _NUMBER, "mm", "stereo baseline"),
    Option("fps", float, 30.0, _NUMBER, "fps", "frame rate"),
    Option("seed", int, 0, AT_LEAST_0, "", "random seed"),
    Option("effects", str, "", None, "", "extra physical effects, e.g. noise_floor(sigma_px=0.03)+slant_range",
           example="noise_floor"),
    Option("fail_at_frame", int, None, AT_LEAST_0, "", "raise a CameraError at this frame (a simulated unplug)",
           example=10, absent="never"),
    Option("light", str, "auto", one_of("day", "night", "auto"), "",
           "day: room light on the wall; night: the projector only; auto: night if first configured with it on"),
    Option("drop", float, 0.0, below(0, 1), "", "probability that a frame is lost", example=0.01),
    Option("duplicate", float, 0.0, below(0, 1), "", "probability that a frame is handed over twice", example=0.01),
    Option("temporal_alpha", float, None, between(0.01, 1), "",
           "a temporal post-filter (RealSense/OAK-D style): out = alpha in + (1 - alpha) previous out", example=0.4,
           absent="off"),
    Option("ir_gain", float, 1.0, _NUMBER, "", "IR image gain (DN per photo-electron times this): above about 2, the "
           "10-bit IR clips at 1023 near the wall with the projector on, as real IR images saturate at short range",
           example=4),
    Option("warmup_sd", float, 0.0, between(0, 1), "", "run to run: the light's level differs by this fraction "
           "(a standard deviation) from one seed to the next, as a camera not yet warm does; k varies with it",
           example=0.05, absent="0: every run alike"),
    Option("room_light_sd", float, 0.0, between(0, 1), "", "run to run: the room light on the wall differs by this "
           "fraction (a standard deviation) from one seed to the next, as daylight through a window does; with light=day "
           "and the projector on, lambda varies with it", example=0.3, absent="0: every run alike"),
    Option("mount_sd_mm", float, 0.0, between(0, 100), "mm", "run to run: the camera sits this much (a standard "
           "deviation) nearer or farther from the wall from one seed to the next, as a remounted camera does",
           example=5, absent="0: every run alike"),
), error=CameraError)


class FakeCamera(DepthCamera):
    """Renders depth (and left IR) frames of a flat matte wall with the paper's noise physics.

    effects: extra physical effects (see `fakes.effects`), e.g. [NoiseFloor(0.03)].
    fail_at_frame: raise a CameraError when this frame number is reached (a simulated unplug).
    conceal: leave the physics and effects out of `info()` (for blind tests: the recording
        must not say what was simulated).
    drop, duplicate: the probability that a frame is lost on the way (its number and time pass
        without it) or handed over twice, as a busy USB bus does.
    ir_gain: the IR image's DN per photo-electron, times IR_DN_PER_E; the 10-bit image clips at IR_MAX_DN (its
        `ir_full_scale_dn`), near the wall with the projector on when the gain is high, as real IR images do.
    temporal_alpha: smooth the depth over time as a camera's temporal post-filter does (exponential smoothing
        with this weight on the new frame; None: off): consecutive frames become correlated.
    light: "day" (room light on the wall), "night" (the projector is the only light), or "auto":
        night if the camera is first configured with the projector on (the paper's night-time
        active runs), day otherwise (its day-time passive runs).
    """

    name = "fake-camera"
    ir_full_scale_dn = IR_MAX_DN

    def __init__(
        self,
        world: FakeWorld,
        *,
        width: int = NATIVE_WIDTH,
        height: int = 480,
        baseline_m: float = 0.050,
        depth_scale_m: float = 0.001,
        fps: float = 30.0,
        physics: SensorPhysics | None = None,
        effects: list[Effect] | None = None,
        seed: int = 0,
        fail_at_frame: int | None = None,
        serial: str = "FAKE-0001",
        light: str = "auto",
        conceal: bool = False,
        drop: float = 0.0,
        duplicate: float = 0.0,
        temporal_alpha: float | None = None,
        ir_gain: float = 1.0,
        warmup_sd: float = 0.0,
        room_light_sd: float = 0.0,
        mount_sd_mm: float = 0.0,
    ):
        self.world = world
        scale = width / NATIVE_WIDTH
        self.intrinsics = Intrinsics(
            width=width,
            height=height,
            fx=NATIVE_FX_PX * scale,
            fy=NATIVE_FX_PX * scale,
            cx=(width - 1) / 2.0,
            cy=(height - 1) / 2.0,
        )
        self.baseline_m = baseline_m
        self.depth_scale_m = depth_scale_m
        self.fps = fps
        # run-to-run variation, drawn once per seed from a stream of its own (the depth noise of a seed stays the same)
        run_rng = np.random.default_rng(seed + 15485863)
        level, room = (float(np.exp(run_rng.normal(0.0, sd))) for sd in (warmup_sd, room_light_sd))
        self.warmup_sd, self.room_light_sd = warmup_sd, room_light_sd
        self.mount_offset_m = float(run_rng.normal(0.0, mount_sd_mm)) / 1000.0  # added to the wall's distance
        physics = physics or SensorPhysics()
        self.physics = replace(physics, pattern_e_per_ms_at_1m=physics.pattern_e_per_ms_at_1m * level,
                               texture_e_per_ms=physics.texture_e_per_ms * level * room)
        self.effects = list(effects or [])
        self.seed = seed
        self.fail_at_frame = fail_at_frame
        self.serial = serial
        self._rng = np.random.default_rng(seed)
        # IR noise and injected transport faults draw from their own streams: the depth noise of a
        # seed is the same whether or not IR frames are rendered or frames are dropped
        self._ir_rng = np.random.default_rng(seed + 104729)
        self._fault_rng = np.random.default_rng(seed + 1299709)
        self.drop = drop
        self.duplicate = duplicate
        self.temporal_alpha = temporal_alpha
        self.ir_gain = ir_gain
        self._filter: tuple[StopField, np.ndarray] | None = None  # the temporal filter's memory, per stop
        self._render: tuple[StopField, _RenderArrays] | None = None
        self._settings = CameraSettings()
        self._open = False
        self._frame_number = 0
        self._opened_at_s = 0.0
        self._field_key: tuple | None = None
        self._field: StopField | None = None
        relief_rng = np.random.default_rng(seed + 7919)
        # the projected dots: a random 7x7 cell of bright and dark dots, normalised to mean 1 and
        # tiled, so every matching window (7x7) holds the same light: the mean signal the noise uses
        cell = relief_rng.choice(np.array([1 / 3, 5 / 3]), size=(7, 7))
        cell /= cell.mean()
        self._dots = np.tile(cell, (height // 7 + 1, width // 7 + 1))[:height, :width].astype(np.float32)
        self._relief = relief_rng.standard_normal((height, width))  # the wall's relief, times roughness_m
        self.light = light
        self.conceal = conceal
        self._room_lit: bool | None = {"day": True, "night": False, "auto": None}[light]

    @classmethod
    def from_options(cls, world: FakeWorld, options: dict[str, str], text: str = "", path: str = "") -> "FakeCamera":
        """Build from device-string options (`FAKE_CAMERA_OPTIONS`); `text` and `path` are the device string's."""
        o = FAKE_CAMERA_OPTIONS.take(options, text, path)
        width = o["width"]
        try:
            effects = parse_effects(o["effects"])
        except ValueError as e:
            raise CameraError(f"fake camera: bad effects={o['effects']!r} ({e}); "
                              "e.g. fake:effects=noise_floor(sigma_px=0.03)+slant_range") from None
        return cls(
            world,
            width=width,
            height=o["height"] if o["height"] is not None else round(width * 480 / NATIVE_WIDTH),
            depth_scale_m=o["depth_unit_mm"] / 1000.0,
            baseline_m=o["baseline_mm"] / 1000.0,
            seed=o["seed"],
            fps=o["fps"],
            effects=effects,
            fail_at_frame=o["fail_at_frame"],
            light=o["light"],
            drop=o["drop"],
            duplicate=o["duplicate"],
            temporal_alpha=o["temporal_alpha"],
            ir_gain=o["ir_gain"],
            warmup_sd=o["warmup_sd"],
            room_light_sd=o["room_light_sd"],
            mount_sd_mm=o["mount_sd_mm"],
        )

    # -- lifecycle -------------------------------------------------------------------------
    def open(self) -> None:
        self._open = True
        self._opened_at_s = self.world.time_s

    def close(self) -> None:
        self._open = False

    def info(self) -> CameraInfo:
        return CameraInfo(
            model="Fake D435 (simulated)",
            serial=self.serial,
            firmware="sim",
            intrinsics=self.intrinsics,
            baseline_m=self.baseline_m,
            depth_scale_m=self.depth_scale_m,
            extra={"fps": self.fps} if self.conceal else {
                "physics": vars(self.physics),
                "effects": [e.to_dict() for e in self.effects],
                "light": self.light,
                "temporal_alpha": self.temporal_alpha,
                "ir_gain": self.ir_gain,
                "seed": self.seed,
                "fps": self.fps,
            },
        )

    def describe(self) -> dict[str, Any]:
        d = super().describe()
        d["simulated"] = True
        return d

    # -- settings --------------------------------------------------------------------------
    def configure(self, settings: CameraSettings) -> CameraSettings:
        self._require_open()
        lo, hi = EXPOSURE_RANGE_US
        if not lo <= settings.exposure_us <= hi:
            raise CameraError(f"{self.name}: exposure {settings.exposure_us:g} us is outside {lo:.0f}-{hi:.0f} us; choose one inside")
        GAIN.check(settings.gain, self.name)
        self._settings = replace(settings, exposure_us=float(round(settings.exposure_us)), gain=float(round(settings.gain)))
        if self._room_lit is None:
            self._room_lit = not settings.projector_on
        return self.read_settings()

    def read_settings(self) -> CameraSettings:
        return self._settings

    # -- truth, for tests and demos ----------------------------------------------------------
    def true_distance_m(self) -> float:
        return float(self.world.wall.distance_m) + self.mount_offset_m

    def base_truth(self, settings: CameraSettings | None = None) -> tuple[float, float]:
        """(k, lambda) of the base physics without effects, for `settings` (default: the current ones)."""
        s = settings or self._settings
        return base_truth(
            self.physics,
            fx=self.intrinsics.fx,
            baseline_m=self.baseline_m,
            width=self.intrinsics.width,
            height=self.intrinsics.height,
            exposure_us=s.exposure_us,
            projector_on=s.projector_on,
        )

    def current_field(self) -> StopField:
        """The per-pixel field for the wall's present position and the present settings."""
        s, wall = self._settings, self.world.wall
        room_lit = bool(self._room_lit)
        distance_m = wall.distance_m + self.mount_offset_m
        key = (distance_m, wall.tilt_deg, wall.roughness_m, s.projector_on, s.exposure_us, s.gain, room_lit)
        if key != self._field_key:
            i = self.intrinsics
            self._field = build_field(
                self.physics,
                shape=(i.height, i.width),
                fx=i.fx,
                fy=i.fy,
                cx=i.cx,
                cy=i.cy,
                baseline_m=self.baseline_m,
                distance_m=distance_m,
                tilt_deg=wall.tilt_deg,
                projector_on=s.projector_on,
                exposure_us=s.exposure_us,
                gain=s.gain,
                effects=self.effects,
                room_lit=room_lit,
                roughness_m=wall.roughness_m * self._relief,
            )
            self._field_key = key
        assert self._field is not None
        return self._field

    # -- frames ----------------------------------------------------------------------------
    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        self._require_open()
        f = self.current_field()
        r = self._render_arrays(f)
        meta = FrameMetadata(
            exposure_us=self._settings.exposure_us,
            gain=self._settings.gain,
            projector_on=self._settings.projector_on,
            auto_exposure=self._settings.auto_exposure,
        )
        frame_effects = [e for e in self.effects if type(e).frame is not Effect.frame]
        shape = f.valid.shape
        i = 0
        while i < n:
            if self.fail_at_frame is not None and self._frame_number >= self.fail_at_frame:
                raise CameraError(f"{self.name}: device disconnected at frame {self._frame_number}; reconnect it and re-run with --resume")
            if self.drop and self._fault_rng.random() < self.drop:  # lost on the way: its number and time pass
                self._frame_number += 1
                self.world.time_s += 1.0 / self.fps
                continue
            noise = self._rng.standard_normal(shape, dtype=np.float32)
            depth = np.empty(shape, np.uint16)
            if frame_effects:
                d = noise
                d *= r.sigma_d_px
                d += r.d_true_px
                valid = f.valid.copy()
                ctx = FrameContext(f, self._rng, self.world.time_s - self._opened_at_s, i)
                for e in frame_effects:
                    e.frame(ctx, d, valid)
                depth_from_disparity(d, valid, r.units_per_px, depth)
            else:
                depth_from_noise(noise, r.sigma_d_px, r.d_true_px, f.valid, r.units_per_px, depth)
            if self.temporal_alpha is not None:
                if self._filter is None or self._filter[0] is not f:  # a new stop or new settings: no memory
                    self._filter = (f, np.zeros(shape, np.float32))
                temporal_filter(depth, self._filter[1], self.temporal_alpha)
            frame = Frame(
                depth=depth,
                frame_number=self._frame_number,
                timestamp_ms=self.world.time_s * 1000.0,
                metadata=meta,
                ir=self._render_ir(r) if ir else None,
            )
            self._frame_number += 1
            self.world.time_s += 1.0 / self.fps
            yield frame
            i += 1
            if i < n and self.duplicate and self._fault_rng.random() < self.duplicate:  # handed over twice
                yield frame
                i += 1

    def _render_arrays(self, f: StopField) -> "_RenderArrays":
        """What every frame of the stop uses, computed once per stop."""
        if self._render is None or self._render[0] is not f:
            with np.errstate(invalid="ignore"):
                sigma_d = np.where(f.valid, np.sqrt(np.where(f.valid, f.sigma_d2_px2, 0.0)), 0.0).astype(np.float32)
            light_e = ((f.signal_e * self._dots + f.ambient_e) / f.binning).astype(np.float32)
            self._render = (f, _RenderArrays(
                d_true_px=f.d_true_px.astype(np.float32),
                sigma_d_px=sigma_d,
                units_per_px=np.float32(f.fb_px_m / self.depth_scale_m),  # Z/unit = (f b / unit) / d
                ir_light_e=light_e,
                ir_noise_e=np.sqrt(light_e),
            ))
        return self._render[1]

    def _render_ir(self, r: "_RenderArrays") -> np.ndarray:
        """Left IR image in DN (10-bit in uint16): dots (projector on) or texture, plus ambient light, with shot noise."""
        out = np.empty(r.ir_light_e.shape, np.uint16)
        uniform = self._ir_rng.random(out.shape, dtype=np.float32)
        dn_per_e = IR_DN_PER_E * self.ir_gain * self._settings.gain / 16.0
        ir_from_uniform(uniform, r.ir_light_e, r.ir_noise_e, np.float32(dn_per_e), IR_MAX_DN, out)
        return out

    def _require_open(self) -> None:
        if not self._open:
            raise CameraError(f"{self.name}: not open; use it as a context manager ('with camera:') or call open()")


@dataclass(frozen=True)
class _RenderArrays:
    """Per-stop arrays of a frame's rendering: the true disparity and its noise (px), depth units per
    (1 / px of disparity), the IR light and its shot noise (photo-electrons per native pixel)."""

    d_true_px: np.ndarray
    sigma_d_px: np.ndarray
    units_per_px: np.float32
    ir_light_e: np.ndarray
    ir_noise_e: np.ndarray
