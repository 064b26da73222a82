"""The runner: executes a plan's steps against a camera and a stage and records them.

It owns everything the plan leaves out: devices, the file, progress, errors, resuming and
aborting. Moves and settling are deferred until the capture that needs them, so a resumed
run skips completed stops without driving the stage through them.
"""

from __future__ import annotations

import math
import shutil
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from drivers.camera import CameraSettings, DepthCamera, FrameMetadata
from drivers.errors import CameraError, DeviceError
from drivers.image_regions import center_box
from drivers.stage import Stage

from .run_errors import PlanRefused, RunError, saved_words  # noqa: F401  (re-exported: protocols.runner.RunError)
from .plan import Capture, Configure, Home, Move, Plan, Settle, WarmUp
from .disk_space import RESERVE_BYTES, free_bytes, is_disk_full, is_storage_failure, megabytes, size_text, stop_bytes
from .frame_continuity import FrameContinuity
from . import interruption
from .plan_check import RigLimits, disk_need_bytes, plan_problems, stop_recipes
from .recording import FrameSeries, RecordingError
from .recording_errors import AssemblyError
from .recording_writer import RecordingWriter
from .region_of_interest import through_region
from .stop_journal import journal_dir
from .stats import MeanImageAccumulator, PixelMomentAccumulator
from .warm_up import StillDrifting, wait_until_warm

#: frames right after a settings change that may still carry the old settings
MAX_STALE_FRAMES = 30
#: fraction of a stop's frames that may be refused for wrong metadata before the run stops
MAX_REFUSED_FRACTION = 0.05


@dataclass
class ProgressEvent:
    """What the runner tells a progress display.

    kind: 'stop_start', 'frame', 'stop_done', 'stop_skipped', 'warm_up' (its summary: `warm_up.wait_until_warm`),
    'message', 'done'.
    """

    kind: str
    stop: str = ""
    stop_index: int = 0
    n_stops: int = 0
    frame: int = 0
    n_frames: int = 0
    text: str = ""
    summary: dict = field(default_factory=dict)


ProgressCallback = Callable[[ProgressEvent], None]


@dataclass
class RunResult:
    path: Path
    recorded: list[str]
    skipped: list[str]
    aborted: bool = False


class RunControl:
    """Pause and abort, safe to set from another thread (a UI)."""

    def __init__(self) -> None:
        self.abort = threading.Event()
        self.resume_event = threading.Event()
        self.resume_event.set()

    def pause(self) -> None:
        self.resume_event.clear()

    def unpause(self) -> None:
        self.resume_event.set()

    def wait_if_paused(self) -> None:
        while not self.resume_event.wait(0.1):
            if self.abort.is_set():
                return


def settings_mismatch(requested: CameraSettings, reported: CameraSettings | FrameMetadata) -> list[str]:
    """Human-readable differences between requested settings and what the device reports."""
    out = []
    if bool(reported.projector_on) != requested.projector_on:
        out.append(f"projector {'on' if reported.projector_on else 'off'} (asked {'on' if requested.projector_on else 'off'})")
    if bool(reported.auto_exposure) != requested.auto_exposure:
        out.append(f"auto-exposure {'on' if reported.auto_exposure else 'off'} (asked {'on' if requested.auto_exposure else 'off'})")
    if abs(reported.exposure_us - requested.exposure_us) > max(1.0, 0.01 * requested.exposure_us):
        out.append(f"exposure {reported.exposure_us:g} us (asked {requested.exposure_us:g} us)")
    if abs(reported.gain - requested.gain) > 0.5:
        out.append(f"gain {reported.gain:g} (asked {requested.gain:g})")
    return out


class Runner:
    """Run plans against one camera and one stage, recording to HDF5."""

    def __init__(self, camera: DepthCamera, stage: Stage, *, progress: ProgressCallback | None = None,
                 sleep: Callable[[float], None] = time.sleep, control: RunControl | None = None):
        self.camera = camera
        self.stage = stage
        self.progress = progress or (lambda e: None)
        self.sleep = sleep
        self.control = control or RunControl()

    def run(self, plan: Plan, path: str | Path, *, resume: bool = False) -> RunResult:
        path = Path(path)
        captures = plan.captures()
        labels = [c.stop for c in captures]
        if len(set(labels)) != len(labels):
            raise RunError(f"plan {plan.name!r} has duplicate stop labels; give each capture a unique label")
        problems = plan_problems(plan, output=path)  # what is known before any device is opened
        if problems:
            raise PlanRefused(self._refused(problems, path, resume, set()), problems)
        try:
            writer = RecordingWriter(path, resume=resume)
        except (RecordingError, OSError) as e:
            raise RunError(str(e)) from None
        created = not resume
        recorded: list[str] = []
        skipped: list[str] = []
        whole_camera, self.camera = self.camera, through_region(self.camera, plan.params.get("region_px"))
        try:
            with writer, self.camera, self.stage:
                info = self.camera.info()
                i = info.intrinsics
                calibration = info.calibration()
                camera, stage = self.camera.describe(), self.stage.describe()
                done = writer.completed_stops()
                try:
                    if resume:
                        writer.resume_change(plan, camera, stage, calibration)  # a different experiment: say so first
                    self._check_plan(plan, path, resume, done, (i.height, i.width))
                    change = writer.start_experiment(plan=plan, camera=camera, stage=stage, calibration=calibration)
                except RecordingError as e:
                    raise RunError(str(e)) from None
                if change:
                    self.progress(ProgressEvent("message", text=f"resuming with a changed plan: {change}"))
                pending_move: float | None = None
                pending_settle = 0.0
                pending_warm_up: WarmUp | None = None
                requested: CameraSettings | None = None
                needs_home = homed = False
                for step in plan.steps():
                    interruption.check()
                    if self.control.abort.is_set():
                        raise _Aborted()
                    if isinstance(step, Home):
                        needs_home, homed = True, False  # home lazily, before the first move that is needed
                    elif isinstance(step, Move):
                        pending_move = step.position_m
                    elif isinstance(step, Settle):
                        pending_settle += step.seconds
                    elif isinstance(step, WarmUp):
                        pending_warm_up = step  # before the next stop to record, the camera standing still
                    elif isinstance(step, Configure):
                        requested = step.settings
                        self._configure(requested)
                    elif isinstance(step, Capture):
                        index = labels.index(step.stop)
                        if step.stop in done:
                            skipped.append(step.stop)
                            self.progress(ProgressEvent("stop_skipped", step.stop, index, len(labels), text="already recorded"))
                        else:
                            if requested is None:
                                raise RunError(f"plan {plan.name!r}: capture {step.stop!r} comes before any Configure step; configure the camera first")
                            warm_up = {}
                            if pending_warm_up is not None:
                                warm_up = self._warm_up(pending_warm_up, requested)
                                pending_warm_up = None
                            commanded = float("nan")
                            if pending_move is not None:
                                if needs_home and not homed:
                                    self.progress(ProgressEvent("message", text=f"homing {self.stage.name}"))
                                    self.stage.home()
                                    homed = True
                                commanded = pending_move
                                self.stage.check_limits(commanded)
                                measured = self.stage.move_to(commanded)
                                self.stage.check_arrived(commanded, measured)
                            if pending_settle > 0:
                                self.sleep(pending_settle)
                            measured = self.stage.position_m() if pending_move is not None else float("nan")
                            if pending_move is not None:
                                self.stage.check_arrived(commanded, measured)
                            self._capture(writer, step, index, len(labels), requested, commanded, measured, warm_up)
                            recorded.append(step.stop)
                        pending_move, pending_settle = None, 0.0
                writer.finish()
        except _Aborted:
            self.progress(ProgressEvent("done", text="aborted"))
            return RunResult(path, recorded, skipped, aborted=True)
        except KeyboardInterrupt:
            raise RunError("run interrupted; " + self._saved_message(path, recorded, skipped, len(labels), created)) from None
        except _DiskFull as e:
            saved = len(recorded) + len(skipped)
            if saved == 0 and created:  # nothing to resume: the empty file goes, and the command is run again
                self._saved_message(path, recorded, skipped, len(labels), created)
                raise RunError(f"disk full at stop {e.index + 1} of {len(labels)}; nothing was recorded; free about "
                               f"{megabytes(e.need)} and run the command again") from None
            raise RunError(f"disk full at stop {e.index + 1} of {len(labels)}; free about {megabytes(e.need)}; "
                           + saved_words(saved, len(labels), path)) from None
        except AssemblyError as e:  # every stop is saved; only the final file is missing
            raise RunError(str(e)) from None
        except (DeviceError, RecordingError, StillDrifting) as e:
            raise RunError(f"{e}; " + self._saved_message(path, recorded, skipped, len(labels), created)) from None
        except OSError as e:
            if is_storage_failure(e):  # an I/O error, a read-only disk: what is saved, and how to go on
                raise RunError(f"writing {path} failed ({e.strerror or e}); check the disk (dmesg); "
                               + self._saved_message(path, recorded, skipped, len(labels), created)) from None
            if not is_disk_full(e):
                raise
            saved = len(recorded) + len(skipped)
            if saved == 0 and created:
                self._saved_message(path, recorded, skipped, len(labels), created)
                raise RunError("disk full before the first stop was saved; nothing was recorded; free some space and "
                               "run the command again") from None
            raise RunError("disk full; free some space; " + saved_words(saved, len(labels), path)) from None
        finally:
            self.camera = whole_camera
        self.progress(ProgressEvent("done", text=f"{len(recorded)} stops recorded, {len(skipped)} already there"))
        return RunResult(path, recorded, skipped)

    def _check_plan(self, plan: Plan, path: Path, resume: bool, done: set[str], shape: tuple[int, int]) -> None:
        """The whole plan against the opened devices, before homing or writing anything (`plan_check`)."""
        limits = RigLimits.of(self.stage, shape)
        problems = plan_problems(plan, limits, output=path, resume=resume, recorded=done)
        if problems:
            raise PlanRefused(self._refused(problems, path, resume, done), problems)
        todo = {k: r for k, r in stop_recipes(plan).items() if k not in done}
        lo, hi = limits.travel_m
        travel = f"within {self.stage.name}'s travel {lo:.3f}-{hi:.3f} m" if math.isfinite(hi) else "(no stage limits)"
        self.progress(ProgressEvent("message", text=f"plan checked: {len(todo)} stops to record {travel}; "
                                                    f"up to {size_text(disk_need_bytes(todo, shape, path, resume=resume))} "
                                                    f"of {size_text(free_bytes(path.parent))} free on disk"))

    @staticmethod
    def _refused(problems: list[str], path: Path, resume: bool, done: set[str]) -> str:
        """A plan that cannot finish: every problem, and that nothing was touched."""
        head = f"the plan cannot finish on this rig: {'; '.join(problems)}"
        if not resume:
            return f"{head}; nothing was recorded"
        kept = f" (it keeps {len(done)} recorded stop{'s' * (len(done) != 1)}, which must stay in the plan)" if done else ""
        return f"{head}; {path} is unchanged{kept}; correct the plan and resume again"

    @staticmethod
    def _saved_message(path: Path, recorded: list[str], skipped: list[str], n: int, created: bool) -> str:
        """Say what is kept. A new file with no completed stop is removed, so a re-run starts clean."""
        saved = len(recorded) + len(skipped)
        if saved == 0 and created:
            path.unlink(missing_ok=True)
            shutil.rmtree(journal_dir(path), ignore_errors=True)
            return "nothing was recorded"
        return saved_words(saved, n, path)

    def _configure(self, requested: CameraSettings) -> CameraSettings:
        got = self.camera.configure(requested)
        bad = settings_mismatch(requested, got)
        if bad and self.camera.plays_back:
            # a recording cannot be changed: take it as it was made and say so in every stop (as_recorded_note)
            self.progress(ProgressEvent("message", text=f"{self.camera.name} plays back a recording; its settings are "
                                                        f"as it was made: {', '.join(bad)}; recorded as such"))
            return got
        if bad:
            raise CameraError(f"{self.camera.name}: settings read back differ from the request: {', '.join(bad)}; "
                              "check that the camera supports them (and that nothing else controls it)")
        return got

    def _frames_checked(self, n: int, requested: CameraSettings, *, ir: bool, continuity: FrameContinuity | None = None):
        """Yield n frames whose metadata match the request; skip stale ones and duplicates, refuse the rest."""
        accepted = refused = stale = 0
        settled = False
        limit_refused = max(1, int(MAX_REFUSED_FRACTION * n))
        continuity = continuity or FrameContinuity()
        while accepted < n:
            for frame in self.camera.frames(n - accepted, ir=ir):
                if not continuity.check(frame.frame_number, frame.timestamp_ms):
                    continue  # the same frame again: no new sample
                # a recording's frames are as they were made: each keeps its own settings (its series records them)
                bad = [] if self.camera.plays_back else settings_mismatch(requested, frame.metadata)
                if bad and not settled and stale < MAX_STALE_FRAMES:
                    stale += 1
                    continue
                settled = True
                if bad:
                    refused += 1
                    if refused > limit_refused:
                        raise CameraError(f"{self.camera.name}: {refused} frames report {', '.join(bad)}; "
                                          "the camera is not holding the settings; check auto-exposure and the emitter control")
                    continue
                accepted += 1
                yield frame
            if stale >= MAX_STALE_FRAMES and not settled:
                raise CameraError(f"{self.camera.name}: after {MAX_STALE_FRAMES} frames the metadata still report "
                                  f"{', '.join(bad)}; the camera did not apply the settings")
        self.refused = refused

    def _capture(self, writer: RecordingWriter, step: Capture, index: int, n_stops: int, requested: CameraSettings,
                 commanded_m: float, measured_m: float, warm_up: dict[str, float] | None = None) -> None:
        info = self.camera.info()
        shape = (info.intrinsics.height, info.intrinsics.width)
        self.progress(ProgressEvent("stop_start", step.stop, index, n_stops, n_frames=step.n_frames,
                                    text=f"at {measured_m:.3f} m" if not math.isnan(measured_m) else ""))
        need = stop_bytes(shape, step.n_frames, keep_raw=step.keep_raw, ir=step.ir, ambient=step.ambient_frames > 0)
        free = free_bytes(writer.path.parent)
        if need + RESERVE_BYTES > free:
            raise _DiskFull(index, need + RESERVE_BYTES - free)
        g = writer.begin_stop(step.stop, index=index, commanded_position_m=commanded_m, measured_position_m=measured_m,
                              settings_requested=requested.to_dict(), settings_read_back=self.camera.read_settings().to_dict(),
                              keep_raw=step.keep_raw)
        try:
            self._stream(writer, g, step, index, n_stops, requested, shape, info, measured_m, warm_up or {})
        except BaseException as e:
            writer.abandon_stop()
            if isinstance(e, OSError) and is_disk_full(e):
                raise _DiskFull(index, need) from None
            raise

    def _stream(self, writer: RecordingWriter, g, step: Capture, index: int, n_stops: int, requested: CameraSettings,
                shape: tuple[int, int], info, measured_m: float, warm_up: dict[str, float]) -> None:
        raw = writer.raw_frames(g, step.n_frames, shape) if step.keep_raw else None
        acc = PixelMomentAccumulator(shape, info.depth_scale_m)
        ir_acc = MeanImageAccumulator(self.camera.ir_full_scale_dn)
        cy, cx = center_box(shape)
        series = {k: np.empty(step.n_frames, dtype) for k, dtype in (
            ("frame_number", np.int64), ("timestamp_ms", np.float64), ("center_mean_m", np.float64),
            ("inverse_range_offset_per_m", np.float64), ("valid_fraction", np.float32), ("exposure_us", np.float32), ("gain", np.float32), ("projector_on", np.bool_))}
        self.refused = 0
        scale = info.depth_scale_m
        continuity = FrameContinuity()
        size = shape[0] * shape[1]
        for j, frame in enumerate(self._frames_checked(step.n_frames, requested, ir=step.ir, continuity=continuity)):
            self.control.wait_if_paused()
            interruption.check()
            if self.control.abort.is_set():
                raise _Aborted()
            depth = frame.depth
            series["inverse_range_offset_per_m"][j] = acc.add(depth)
            if raw is not None:
                raw[j] = depth
            if step.ir and frame.ir is not None:
                ir_acc.add(frame.ir)
            center = depth[cy, cx]
            nz = center[center > 0]
            series["frame_number"][j] = frame.frame_number
            series["timestamp_ms"][j] = frame.timestamp_ms
            series["center_mean_m"][j] = nz.mean() * scale if nz.size else np.nan
            series["valid_fraction"][j] = acc.last_valid / size
            series["exposure_us"][j] = frame.metadata.exposure_us
            series["gain"][j] = frame.metadata.gain
            series["projector_on"][j] = frame.metadata.projector_on
            if j % 10 == 0 or j == step.n_frames - 1:
                self.progress(ProgressEvent("frame", step.stop, index, n_stops, frame=j + 1, n_frames=step.n_frames))
        refused = self.refused  # the ambient capture below counts its own
        ambient = None
        if step.ambient_frames > 0:
            ambient = self._ambient(requested, step.ambient_frames)
        stats = acc.result()
        measured_end = self.stage.position_m()
        fill = float(np.mean(stats.count)) / step.n_frames
        writer.end_stop(
            g, stats=stats, series=FrameSeries(**series), ir_mean=ir_acc.result(), ambient_ir_mean=ambient,
            ir_saturated=ir_acc.saturated, ir_full_scale_dn=ir_acc.full_scale_dn,
            extra_attrs={"frames_refused": refused, "frames_dropped": continuity.dropped,
                         "frames_duplicated": continuity.duplicated, "measured_position_end_m": measured_end,
                         **self._as_recorded(requested, series), **warm_up},
        )
        c = stats.count[cy, cx] > 1
        sigma_c = float(np.sqrt(np.mean(stats.variance_m2[cy, cx][c]))) if c.any() else float("nan")
        mean_c = float(np.mean(stats.mean_m[cy, cx][c])) if c.any() else float("nan")  # no valid centre: nan, no warning
        self.progress(ProgressEvent("stop_done", step.stop, index, n_stops, n_frames=step.n_frames,
                                    summary={"fill_rate": fill, "center_sigma_m": sigma_c,
                                             "center_mean_m": mean_c,
                                             "position_m": measured_m, "frames_dropped": continuity.dropped,
                                             "frames_duplicated": continuity.duplicated}))

    def _warm_up(self, step: WarmUp, requested: CameraSettings) -> dict[str, float]:
        """Stream frames with the run's settings until the camera is warm (`warm_up.wait_until_warm`); return the
        stop attributes saying how long it waited and the drift it ended with. A recording played back is as warm
        as it was made."""
        if self.camera.plays_back:
            self.progress(ProgressEvent("message", text=f"{self.camera.name} plays back a recording: no warm-up"))
            return {}

        def frames() -> Iterator[tuple[float, np.ndarray]]:
            continuity = FrameContinuity()
            while True:
                for frame in self._frames_checked(30, requested, ir=False, continuity=continuity):
                    self.control.wait_if_paused()
                    interruption.check()
                    if self.control.abort.is_set():
                        raise _Aborted()
                    yield frame.timestamp_ms / 1000.0, frame.depth

        def report(kind: str, text: str, summary: dict) -> None:
            self.progress(ProgressEvent(kind, text=text, summary=summary))

        waited, estimate = wait_until_warm(frames(), step, self.camera.info().depth_scale_m, self.camera.name, report)
        return {"warm_up_s": waited, "warm_up_drift_mm_per_min": estimate.drift_mm_per_min,
                "warm_up_drift_se_mm_per_min": estimate.se_mm_per_min}

    def _as_recorded(self, requested: CameraSettings, series: dict[str, np.ndarray]) -> dict[str, str]:
        """For a recording played back: how its settings differ from the request, as a stop attribute
        (`settings_as_recorded`, shown by Recording.notes); {} for a live camera or when nothing differs."""
        if not self.camera.plays_back:
            return {}
        got = self.camera.read_settings()
        said = settings_mismatch(requested, got)
        exposure = series["exposure_us"][np.isfinite(series["exposure_us"])]
        if got.auto_exposure and exposure.size:
            said = [s for s in said if not s.startswith("exposure ")]
            if not any(s.startswith("auto-exposure") for s in said):
                said.append("auto-exposure on")
            said.append(f"exposure per frame {exposure.min():g}-{exposure.max():g} us (the frames' metadata)")
        return {"settings_as_recorded": "; ".join(said)} if said else {}

    def _ambient(self, requested: CameraSettings, n: int) -> np.ndarray | None:
        """Mean IR image with the projector off: the ambient light level at this stop."""
        dark = CameraSettings(projector_on=False, exposure_us=requested.exposure_us, gain=requested.gain,
                              auto_exposure=requested.auto_exposure)
        self._configure(dark)
        acc = MeanImageAccumulator()
        for frame in self._frames_checked(n, dark, ir=True):
            if frame.ir is not None:
                acc.add(frame.ir)
        self._configure(requested)
        return acc.result()


class _Aborted(Exception):
    pass


class _DiskFull(Exception):
    def __init__(self, index: int, need: int):
        super().__init__(index, need)
        self.index, self.need = index, need
