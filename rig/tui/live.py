"""A run as the Run screen sees it, without Textual: the same `Runner` as `rig run`, observed.

`LiveRun.run()` blocks (the UI calls it from a worker thread) and reports a `RunState`
snapshot to `on_update` after every runner event. Pause and abort go through the runner's own
`RunControl`, so they are safe from the UI thread. A `FrameTap` between the runner and the
camera adds what the runner's events do not carry yet: the current stop's live fill rate and
sigma at the centre, dropped frames (gaps in the camera's frame numbers) and frames whose
metadata differ from the settings asked for (which the runner skips or refuses).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterator

from drivers.camera import CameraInfo, CameraSettings, DepthCamera, Frame
from drivers.errors import DeviceError
from protocols.experiment_file import ExperimentFileError
from protocols.runner import ProgressEvent, RunControl, RunError, Runner, RunResult, settings_mismatch
from rig.devices import open_devices
from protocols.recording import RecordingError

from .centre import CentreStats
from .form import ExperimentSettings


class FrameTap(DepthCamera):
    """Passes everything through to the camera and watches the frames go by."""

    def __init__(self, inner: DepthCamera):
        self.inner = inner
        self.name = inner.name
        self.requested: CameraSettings | None = None
        self.stop_settings: CameraSettings | None = None
        self.live: CentreStats | None = None
        self.dropped = 0
        self.refused = 0
        self._last_number: int | None = None

    # the camera, unchanged
    def open(self) -> None:
        self.inner.open()

    def close(self) -> None:
        self.inner.close()

    def info(self) -> CameraInfo:
        return self.inner.info()

    def configure(self, settings: CameraSettings) -> CameraSettings:
        self.requested = settings
        return self.inner.configure(settings)

    def read_settings(self) -> CameraSettings:
        return self.inner.read_settings()

    def describe(self) -> dict[str, Any]:
        return self.inner.describe()

    def read(self) -> dict[str, Any]:
        return self.inner.read()

    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        for frame in self.inner.frames(n, ir=ir):
            self._observe(frame)
            yield frame

    # what it watches
    def begin_stop(self) -> None:
        info = self.inner.info()
        self.live = CentreStats((info.intrinsics.height, info.intrinsics.width), info.depth_scale_m)
        self.stop_settings = self.requested

    def _observe(self, frame: Frame) -> None:
        if self._last_number is not None and frame.frame_number > self._last_number + 1:
            self.dropped += frame.frame_number - self._last_number - 1
        self._last_number = frame.frame_number
        if self.requested is not None and settings_mismatch(self.requested, frame.metadata):
            self.refused += 1
        elif self.live is not None and self.requested == self.stop_settings:
            self.live.add(frame.depth)


@dataclass
class RunState:
    """One snapshot of a run for the screen: plain values, safe to hand to another thread."""

    status: str = "idle"  # idle, running, paused, done, aborted, failed
    output: str = ""
    stop: str = ""
    stop_index: int = 0
    n_stops: int = 0
    stops_done: int = 0
    frame: int = 0
    n_frames: int = 0
    fill_rate: float = math.nan
    centre_sigma_m: float = math.nan
    centre_mean_m: float = math.nan
    points: list[tuple[float, float]] = field(default_factory=list)  # (centre range, centre sigma) per stop, m
    elapsed_s: float = 0.0
    remaining_s: float | None = None
    dropped: int = 0
    refused: int = 0
    message: str = ""
    recorded: int = 0
    skipped: int = 0

    @property
    def active(self) -> bool:
        return self.status in ("running", "paused")


Clock = Callable[[], float]


class LiveRun:
    """Runs one experiment at a time and keeps its `RunState`."""

    def __init__(self, *, clock: Clock = time.monotonic, on_update: Callable[[RunState], None] | None = None):
        self.clock = clock
        self.on_update = on_update or (lambda s: None)
        self.observers: list[Callable[[ProgressEvent], None]] = []  # called in the run's thread, after the screen's update
        self.control = RunControl()
        self.state = RunState()
        self._lock = threading.Lock()
        self._tap: FrameTap | None = None
        self._t0 = 0.0
        self._paused_total = 0.0
        self._paused_at: float | None = None
        self._frames_total = 0
        self._frames_before = 0  # frames of the stops already done
        self._frames_by_stop: dict[str, int] = {}

    # -- from the UI thread -----------------------------------------------------------------
    def pause(self) -> None:
        with self._lock:
            if self.state.status == "running":
                self.control.pause()
                self._paused_at = self.clock()
                self.state.status = "paused"
        self._publish()

    def unpause(self) -> None:
        with self._lock:
            if self.state.status == "paused":
                if self._paused_at is not None:
                    self._paused_total += self.clock() - self._paused_at
                self._paused_at = None
                self.state.status = "running"
                self.control.unpause()
        self._publish()

    def abort(self) -> None:
        self.control.abort.set()
        self.control.unpause()

    def snapshot(self) -> RunState:
        with self._lock:
            self._tick()
            return replace(self.state, points=list(self.state.points))

    # -- in the worker thread ---------------------------------------------------------------
    def run(self, settings: ExperimentSettings, camera: str, stage: str, *, resume: bool = False) -> RunResult | None:
        """Run the experiment to the end (or abort, or failure); the state says which."""
        self.control = RunControl()
        self._t0, self._paused_total, self._paused_at = self.clock(), 0.0, None
        self.state = RunState(status="running", output=settings.output, message="starting")
        self._publish()
        try:
            plan = settings.plan()
            captures = plan.captures()
            self._frames_by_stop = {c.stop: c.n_frames for c in captures}
            self._frames_total, self._frames_before = sum(self._frames_by_stop.values()), 0
            with self._lock:
                self.state.n_stops = len(captures)
                self.state.message = f"opening {camera} and {stage}"
            self._publish()
            devices = open_devices(camera, stage, **settings.device_geometry())
            self._tap = FrameTap(devices.camera)
            runner = Runner(self._tap, devices.stage, progress=self._event, sleep=devices.sleep, control=self.control)
            result = runner.run(plan, Path(settings.output), resume=resume)
        except (RunError, DeviceError, ExperimentFileError, RecordingError, OSError) as e:
            self._finish("failed", in_keys(str(e)))
            return None
        except Exception as e:  # noqa: BLE001 - a device's or the runner's own bug: one line, the UI goes on
            self._finish("failed", f"the run stopped on an unexpected error ({type(e).__name__}: {e}); completed "
                                   "stops are kept; press u to resume")
            return None
        with self._lock:
            self.state.recorded, self.state.skipped = len(result.recorded), len(result.skipped)
        saved = len(result.recorded) + len(result.skipped)
        if result.aborted:
            self._finish("aborted", f"aborted: {saved} of {self.state.n_stops} stops are saved in {result.path}; "
                                    "press u to resume")
        else:
            self._finish("done", f"run complete: {len(result.recorded)} stops recorded"
                                 + (f", {len(result.skipped)} already there" if result.skipped else "")
                                 + f" in {result.path}")
        return result

    def _event(self, e: ProgressEvent) -> None:
        tap = self._tap
        with self._lock:
            s = self.state
            if e.kind == "stop_start":
                if tap is not None:
                    tap.begin_stop()
                s.stop, s.stop_index, s.n_stops, s.frame, s.n_frames = e.stop, e.stop_index, e.n_stops, 0, e.n_frames
                s.fill_rate = s.centre_sigma_m = s.centre_mean_m = math.nan
                s.message = f"stop {e.stop_index + 1} of {e.n_stops}: {e.stop} {e.text}".rstrip()
            elif e.kind == "frame":
                s.frame, s.n_frames = e.frame, e.n_frames
                if tap is not None and tap.live is not None:
                    s.fill_rate = tap.live.fill_rate
                    s.centre_mean_m, s.centre_sigma_m = tap.live.centre()
            elif e.kind == "stop_done":
                x = e.summary
                s.frame = s.n_frames = e.n_frames
                s.fill_rate, s.centre_sigma_m, s.centre_mean_m = x["fill_rate"], x["center_sigma_m"], x["center_mean_m"]
                s.points.append((x["center_mean_m"], x["center_sigma_m"]))
                s.stops_done += 1
                self._frames_before += e.n_frames
                s.message = f"stop {e.stop} done"
            elif e.kind == "stop_skipped":
                s.stops_done += 1
                s.n_stops = e.n_stops
                self._frames_total -= self._frames_by_stop.get(e.stop, 0)
                s.message = f"stop {e.stop} already recorded, skipped"
            elif e.kind in ("message", "warm_up"):
                s.message = e.text
            if tap is not None:
                s.dropped, s.refused = tap.dropped, tap.refused
            self._tick()
        self._publish()
        for observer in list(self.observers):
            observer(e)

    def _tick(self) -> None:
        """Update elapsed and remaining time (call with the lock held)."""
        s = self.state
        if not s.active:
            return
        now = self.clock()
        s.elapsed_s = now - self._t0
        paused = self._paused_total + ((now - self._paused_at) if self._paused_at is not None else 0.0)
        busy = s.elapsed_s - paused
        done = self._frames_before + (s.frame if s.stops_done < s.n_stops and s.frame < s.n_frames else 0)
        left = max(0, self._frames_total - done)
        s.remaining_s = busy / done * left if done > 0 else None
        if left == 0:
            s.remaining_s = 0.0

    def _finish(self, status: str, message: str) -> None:
        with self._lock:
            self._tick()
            self.state.status, self.state.message = status, message
            if status == "done":
                self.state.remaining_s = 0.0
        self._publish()

    def _publish(self) -> None:
        self.on_update(self.snapshot())


#: what the command line tells the user to do, and the key that does it here (Run screen: r runs, u resumes)
CLI_TO_KEYS = (
    ("re-run the same command with --resume", "press u to resume"),
    ("rerun with --resume", "press u to resume"),
    ("pass --resume to continue it", "press u to resume it"),
    ("run without --resume", "press r to run it"),
    ("resume again", "press u to resume"),
    ("rig run ... --resume records the rest", "press u on the Run screen records the rest"),
)


def in_keys(text: str) -> str:
    """A message of the runner or the recording, with the keys of the Run screen for the flags of `rig run`."""
    for cli, keys in CLI_TO_KEYS:
        text = text.replace(cli, keys)
    return text


def format_duration(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "--:--"
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m:02d}:{s:02d}"
