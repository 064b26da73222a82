"""Capture: the streaming statistics per frame, a whole capture through the runner (statistics, series,
continuity and the HDF5 recording), and the fake camera's rendering, each against its baseline."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Iterator

import numpy as np

from drivers.camera import CameraInfo, CameraSettings, DepthCamera, Frame
from fakes.camera import FakeCamera
from fakes.stage import FakeStage
from fakes.world import FakeWorld
from protocols import Runner, perpendicular
from protocols.stats import PixelMomentAccumulator

from .baselines import Welford
from .data import Size
from .figures import Figure, best_of

#: the capture target: 3x a D455's 90 frames/s
TARGET_FPS = 270.0


def _frames(size: Size, count: int = 64) -> list[np.ndarray]:
    cam = FakeCamera(FakeWorld.perpendicular(2.0), width=size.width, height=size.height, depth_scale_m=1e-4)
    with cam:
        cam.configure(CameraSettings())
        return [f.depth for f in cam.frames(count)]


def streaming(size: Size) -> list[Figure]:
    """`PixelMomentAccumulator.add` per frame against `frame.sum()` and a numpy Welford update, CPU s per frame."""
    frames = _frames(size)
    shape = frames[0].shape
    acc = PixelMomentAccumulator(shape, 1e-4)
    acc.add(frames[0])  # compiled before timing
    welford = Welford(shape)
    per = len(frames)
    t_stats = best_of(lambda: [acc.add(f) for f in frames]) / per
    t_sum = best_of(lambda: [f.sum() for f in frames]) / per
    t_welford = best_of(lambda: [welford.add(f) for f in frames]) / per
    label = f"{size.width}x{size.height}"
    return [
        Figure(f"streaming statistics per {label} frame", 1e3 * t_stats, 1e3 * t_sum, "ms",
               f">= {TARGET_FPS:.0f} frames/s; <= 4x frame.sum() is the long-run aim", 1 / t_stats >= TARGET_FPS,
               "frame.sum()", note=f"{1 / t_stats:.0f} frames/s; {t_stats / t_sum:.1f}x frame.sum()"),
        Figure(f"streaming statistics against a Welford update ({label})", 1e3 * t_stats, 1e3 * t_welford, "ms",
               "faster than the 2-moment textbook update", t_stats < t_welford, "numpy Welford"),
    ]


class ReplayCamera(DepthCamera):
    """Frames rendered beforehand, handed out in turn with running numbers and timestamps at 90 fps: a capture
    timed without the simulator's rendering."""

    name = "replay"

    def __init__(self, frames: list[np.ndarray], template: FakeCamera):
        self.pool, self.template = frames, template
        self.settings = CameraSettings()
        self.number = 0

    def open(self) -> None:
        self.template.open()

    def close(self) -> None:
        self.template.close()

    def info(self) -> CameraInfo:
        return self.template.info()

    def configure(self, settings: CameraSettings) -> CameraSettings:
        self.settings = settings
        return settings

    def read_settings(self) -> CameraSettings:
        return self.settings

    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        from drivers.camera import FrameMetadata

        s = self.settings
        meta = FrameMetadata(s.exposure_us, s.gain, s.projector_on, s.auto_exposure)
        for _ in range(n):
            yield Frame(self.pool[self.number % len(self.pool)], self.number, self.number * 1000 / 90, meta)
            self.number += 1


def capture(size: Size) -> list[Figure]:
    """A whole capture (3 stops of `size.frames` frames, recorded to HDF5 by the real runner) from a replaying
    camera, frames/s, against `frame.sum()` over the same frames."""
    frames = _frames(size)
    world = FakeWorld.perpendicular(1.0)
    template = FakeCamera(world, width=size.width, height=size.height, depth_scale_m=1e-4)
    n = 3 * size.frames
    with tempfile.TemporaryDirectory() as tmp:
        cam = ReplayCamera(frames, template)
        plan = perpendicular(stops_m=[1.0, 1.5, 2.0], frames_per_stop=size.frames, ir=False)
        t0 = time.process_time()
        Runner(cam, FakeStage(world), sleep=lambda s: None).run(plan, Path(tmp) / "capture.h5")
        t_run = time.process_time() - t0
    t_sum = best_of(lambda: [frames[i % len(frames)].sum() for i in range(n)], 1)
    fps = n / t_run
    return [Figure(f"capture: statistics + series + recording, {size.width}x{size.height}", fps, n / t_sum, "frames/s",
                   f">= {TARGET_FPS:.0f} frames/s on one core", fps >= TARGET_FPS, "frame.sum() alone",
                   note="higher is better; ratio = ours / baseline")]


def fake_camera(size: Size) -> list[Figure]:
    """The fake camera's depth + IR rendering per frame against one normal draw per pixel (the least a noisy
    frame costs), CPU s per frame."""
    cam = FakeCamera(FakeWorld.perpendicular(2.0), width=size.width, height=size.height, depth_scale_m=1e-4)
    rng = np.random.default_rng(0)
    shape = (size.height, size.width)
    with cam:
        cam.configure(CameraSettings())
        list(cam.frames(2, ir=True))
        t_cam = best_of(lambda: list(cam.frames(32, ir=True))) / 32
    t_draw = best_of(lambda: [rng.standard_normal(shape, dtype=np.float32) for _ in range(32)]) / 32
    sweep_s = 11 * size.frames * t_cam
    return [Figure(f"fake camera: a depth + IR frame, {size.width}x{size.height}", 1e3 * t_cam, 1e3 * t_draw, "ms",
                   "a full sweep's frames in about a minute", sweep_s <= 60.0, "one normal draw per pixel",
                   note=f"a full sweep ({11 * size.frames} frames): {sweep_s:.0f} s")]
