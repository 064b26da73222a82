"""Run: progress, live numbers and the sigma-vs-range plot of the experiment being recorded."""

from __future__ import annotations

import time
from pathlib import Path

from textual import work
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.message import Message

from .devices_service import DeviceSession
from .form import ExperimentSettings
from .live import Clock, LiveRun, RunState
from .widgets import LiveStats, RunProgress, SigmaPlot, StatusLine


class RunPane(Vertical):
    """Starts, pauses, aborts and resumes runs; shows each `RunState` the run reports."""

    class Updated(Message):
        def __init__(self, state: RunState) -> None:
            super().__init__()
            self.state = state

    class Finished(Message):
        """The run ended (done, aborted or failed); the app refreshes what depends on it."""

        def __init__(self, state: RunState) -> None:
            super().__init__()
            self.state = state

    def __init__(self, clock: Clock = time.monotonic, **kw) -> None:
        super().__init__(**kw)
        self.live = LiveRun(clock=clock, on_update=lambda s: self.post_message(self.Updated(s)))
        self.state = RunState()
        self.last_output: str = ""

    def compose(self) -> ComposeResult:
        with Horizontal(classes="columns"):
            with Vertical(classes="left"):
                yield RunProgress(id="run-progress")
                yield LiveStats(id="live-stats")
            yield SigmaPlot(id="sigma-plot", classes="right")
        yield StatusLine("r runs the experiment set on the Experiment screen", id="run-status")

    def on_mount(self) -> None:
        self._show(self.state)

    @property
    def status(self) -> StatusLine:
        return self.query_one("#run-status", StatusLine)

    @property
    def running(self) -> bool:
        return self.state.active

    def can_resume(self, output: str) -> bool:
        return bool(output) and Path(output).exists()

    # -- actions ----------------------------------------------------------------------------
    def start(self, settings: ExperimentSettings, camera: str, stage: str, devices: DeviceSession, *,
              resume: bool = False) -> None:
        if self.running:
            self.status.show("a run is going on; pause (p) or abort (a) it first", "error")
            return
        self.last_output = settings.output
        self.state = RunState(status="running", output=settings.output, message="starting")
        self._show(self.state)
        self.app.refresh_bindings()
        self._run(settings, camera, stage, devices, resume)

    def toggle_pause(self) -> None:
        if self.state.status == "running":
            self.live.pause()
        elif self.state.status == "paused":
            self.live.unpause()

    def abort(self) -> None:
        if self.running:
            self.status.show("aborting after the current frame; completed stops are kept", "busy")
            self.live.abort()

    @work(thread=True, exclusive=True, group="run")
    def _run(self, settings: ExperimentSettings, camera: str, stage: str, devices: DeviceSession, resume: bool) -> None:
        if devices.connected:
            devices.disconnect()  # the run opens the devices itself, as `rig run` does
        self.live.run(settings, camera, stage, resume=resume)
        self.post_message(self.Finished(self.live.snapshot()))

    # -- what the run reports ---------------------------------------------------------------
    def on_run_pane_updated(self, m: Updated) -> None:
        if m.state.status != self.state.status:
            self.app.refresh_bindings()
        self.state = m.state
        self._show(m.state)

    def on_run_pane_finished(self, m: Finished) -> None:
        self.state = m.state
        self._show(m.state)
        self.app.refresh_bindings()

    def _show(self, s: RunState) -> None:
        self.query_one(RunProgress).show_state(s)
        self.query_one(LiveStats).show_state(s)
        plot = self.query_one(SigmaPlot)
        if len(plot.points) != len(s.points):
            plot.show_points(s.points)
        level = {"done": "ok", "failed": "error", "aborted": "error", "running": "busy", "paused": "busy"}.get(s.status, "info")
        text = s.message
        if s.status == "paused":
            text = f"paused at stop {s.stop} frame {s.frame}; p continues, a aborts"
        if s.message:
            self.status.show(text, level)
