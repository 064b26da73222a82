"""`rig tui`: the lab operator's terminal UI over the runner, the recording and the analysis.

Four screens as tabs (keys 1-4, or F1-F4 which work everywhere): Devices, Experiment, Run, Results.
Every action has a key in the footer; the footer shows only the actions of the screen in front, and
hides single-letter keys while a form field has the focus (esc leaves the field). Digits typed while a
form field has the focus never switch screens. Work that takes long (a diagnosis) is never on a plain
letter: typing cannot start it. Switching to a screen always puts the focus in the same place
(`_focus_for`), and the tab bar takes no focus, so a number of Tab presses always reaches the same field.
"""

from __future__ import annotations

import time
from pathlib import Path

from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.css.query import NoMatches
from textual.widgets import Checkbox, Footer, Input, Select, TabbedContent, TabPane, Tabs

from drivers.camera import CameraSettings
from protocols.region_of_interest import Region

from .devices_pane import DevicesPane
from .dialogs import AskPath, ConfirmQuit, HelpScreen, TextScreen
from .key_list import KeyRow, action_name, bindings_of, key_rows
from .experiment_pane import ExperimentPane
from .form import DEFAULT_CAMERA, DEFAULT_STAGE, ExperimentSettings
from .live import Clock
from .results_outputs import display_available
from .results_pane import ResultsPane
from .run_pane import RunPane
from .widgets import EffectList

TABS = ("devices", "experiment", "run", "results")

#: the screen each action belongs to; actions not listed work everywhere
ACTION_TAB = {
    "connect": "devices", "disconnect": "devices", "test_capture": "devices", "home": "devices", "preview": "devices",
    "load_experiment": "experiment", "save_experiment": "experiment", "run_from_form": "experiment",
    "start_run": "run", "pause": "run", "unpause": "run", "abort": "run", "resume_run": "run",
    "open_recording": "results", "refit": "results", "export_model": "results", "compare": "results",
    "write_report": "results", "open_report": "results",
}
#: actions on plain letter and digit keys: off while a form field has the focus (the field takes the key)
LETTER_ACTIONS = {"connect", "disconnect", "test_capture", "home", "preview", "start_run", "pause", "unpause", "abort",
                  "resume_run", "refit", "export_model", "compare", "write_report", "open_report", "digit_tab"}
#: the widgets of a form: while one has the focus, keys are for it
FORM_FIELDS = (Input, Select, Checkbox)


class RigApp(App):
    """The operator's UI. `camera`/`stage` are device strings; `recording` opens on Results."""

    CSS_PATH = Path(__file__).with_name("rig.tcss")  # absolute: subclasses elsewhere find it too
    TITLE = "rig"
    ENABLE_COMMAND_PALETTE = False
    #: the focus goes where `_focus_for` puts it: Textual's first focusable widget would be a field on a hidden
    #: screen, and focusing it would switch to that screen
    AUTO_FOCUS = None
    BINDINGS = [
        Binding("f1", "show_tab('devices')", "Devices screen", show=False),
        Binding("f2", "show_tab('experiment')", "Experiment screen", show=False),
        Binding("f3", "show_tab('run')", "Run screen", show=False),
        Binding("f4", "show_tab('results')", "Results screen", show=False),
        Binding("1", "digit_tab('devices')", "Devices screen", show=False),
        Binding("2", "digit_tab('experiment')", "Experiment screen", show=False),
        Binding("3", "digit_tab('run')", "Run screen", show=False),
        Binding("4", "digit_tab('results')", "Results screen", show=False),
        Binding("question_mark", "help", "Help"),  # (early: the footer keeps it when it has no room for all)
        Binding("c", "connect", "Connect"),
        Binding("x", "disconnect", "Disconnect"),
        Binding("t", "test_capture", "Test capture"),
        Binding("h", "home", "Home stage"),
        Binding("v", "preview", "Preview"),
        Binding("ctrl+l", "load_experiment", "Load"),
        Binding("ctrl+s", "save_experiment", "Save"),
        Binding("ctrl+r", "run_from_form", "Run"),
        Binding("r", "start_run", "Run"),
        Binding("p", "pause", "Pause"),
        Binding("p", "unpause", "Continue"),
        Binding("a", "abort", "Abort"),
        Binding("u", "resume_run", "Resume file"),
        Binding("ctrl+o", "open_recording", "Open"),  # a diagnosis (a minute): not a letter a file name contains
        Binding("f", "refit", "Refit"),
        Binding("e", "export_model", "Export"),
        Binding("c", "compare", "Compare"),
        Binding("w", "write_report", "Report"),
        Binding("b", "open_report", "Browser"),
        Binding("escape", "leave_field", "Leave field"),
        Binding("ctrl+q", "quit", "Quit", priority=True),
    ]

    def __init__(self, camera: str = DEFAULT_CAMERA, stage: str = DEFAULT_STAGE, *, recording: str | None = None,
                 experiment: ExperimentSettings | None = None, experiment_file: str = "experiment.toml",
                 connect: bool = True, clock: Clock = time.monotonic) -> None:
        super().__init__()
        self._camera, self._stage = camera, stage
        self._recording = recording
        self._experiment = experiment
        self._experiment_file = experiment_file
        self._connect = connect
        self._clock = clock
        self.crash: BaseException | None = None  # what ended the app, if something did (`launch.run_app`)
        self._quitting = False  # quitting was confirmed during a run: the app ends when the run's thread does

    def compose(self) -> ComposeResult:
        with TabbedContent(initial="results" if self._recording else "devices", id="tabs"):
            with TabPane("1 Devices", id="devices"):
                yield DevicesPane(self._camera, self._stage, id="devices-pane")
            with TabPane("2 Experiment", id="experiment"):
                yield ExperimentPane(self._experiment, self._experiment_file, id="experiment-pane",
                                     limits=lambda: self.devices.limits,
                                     devices=lambda: (self.devices.camera_string, self.devices.stage_string))
            with TabPane("3 Run", id="run"):
                yield RunPane(self._clock, id="run-pane")
            with TabPane("4 Results", id="results"):
                yield ResultsPane(self._recording or "", clock=self._clock, id="results-pane")
        yield Footer(compact=True, show_command_palette=False)

    def on_mount(self) -> None:
        self.query_one(TabbedContent).query_one(Tabs).can_focus = False  # screens switch by key; Tab goes to fields
        if self._connect:
            self.devices.connect()
        if self._recording:
            self.results.open()
        self._focus_for(self.tab)

    # -- the panes --------------------------------------------------------------------------
    @property
    def devices(self) -> DevicesPane:
        return self.query_one(DevicesPane)

    @property
    def experiment(self) -> ExperimentPane:
        return self.query_one(ExperimentPane)

    @property
    def run_pane(self) -> RunPane:
        return self.query_one(RunPane)

    @property
    def results(self) -> ResultsPane:
        return self.query_one(ResultsPane)

    @property
    def tab(self) -> str:
        """The screen in front ("" while the app is being taken down)."""
        try:
            return self.query_one(TabbedContent).active
        except NoMatches:
            return ""

    # -- which keys are live ----------------------------------------------------------------
    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        try:
            return self._check_action(action)
        except NoMatches:  # asked before the screens are mounted
            return True

    def _check_action(self, action: str) -> bool | None:
        typing = isinstance(self.focused, FORM_FIELDS)
        if action == "leave_field":
            return typing
        if action in LETTER_ACTIONS and typing:
            return False
        tab = ACTION_TAB.get(action)
        if tab is not None and tab != self.tab:
            return False
        run = self.run_pane.state
        if action == "pause":
            return run.status == "running"
        if action == "unpause":
            return run.status == "paused"
        if action == "abort":
            return run.active
        if action in ("start_run", "run_from_form"):
            return None if run.active else True
        if action == "resume_run":
            return False if run.active or not self.run_pane.can_resume(self._output()) else True
        if action in ("connect", "disconnect", "home", "test_capture", "preview"):
            if self.devices.busy or run.active:
                return None
            if action in ("disconnect", "home", "test_capture", "preview"):
                return True if self.devices.session.connected else None
        if action == "open_report":  # offered only where a browser can open a window, once there is a report
            return self.results.report is not None and display_available()
        if action in ("open_recording", "refit", "export_model", "compare", "write_report"):
            if self.results.busy:
                return None
            if action != "open_recording":
                return True if self.results.session.diagnosis is not None else None
        return True

    def on_tabbed_content_tab_activated(self, event: TabbedContent.TabActivated) -> None:
        if event.pane.id == self.tab:  # a later switch may have overtaken this one; focusing would undo it
            self._focus_for(self.tab)
        self.refresh_bindings()

    def _focus_for(self, tab: str) -> None:
        if tab == "experiment":
            self.query_one("#toml-path", Input).focus()
        elif tab == "results" and self.results.session.diagnosis is None:  # whatever it holds: typing goes there
            self.query_one("#recording-path", Input).focus()
        elif tab == "results" and self.results.session.diagnosis is not None:
            self.results.query_one("#effects").focus()
        else:
            self.set_focus(None)

    # -- actions ----------------------------------------------------------------------------
    def action_show_tab(self, tab: str) -> None:
        self.query_one(TabbedContent).active = tab

    def action_digit_tab(self, tab: str) -> None:
        self.action_show_tab(tab)

    def action_leave_field(self) -> None:
        self.set_focus(None)
        self.refresh_bindings()

    def action_connect(self) -> None:
        if self.run_pane.running:
            self.devices.status.show("a run has the devices; wait for it to end", "error")
            return
        self.devices.connect()

    def action_disconnect(self) -> None:
        self.devices.disconnect()

    def action_home(self) -> None:
        self.devices.home()

    def action_test_capture(self) -> None:
        settings = self._camera_settings()
        if settings is not None:
            self.devices.test_capture(settings)

    def action_preview(self) -> None:
        if self.devices.previewing:
            self.devices.stop_preview()
            self.devices.status.show("preview stopped", "info")
            return
        settings = self._camera_settings()
        if settings is not None:
            self.devices.start_preview(settings, Region.of(self.experiment.settings().value("region_px")))

    def _camera_settings(self) -> CameraSettings | None:
        """The experiment's projector, exposure and gain (None, said on the Devices screen, if they are refused)."""
        s = self.experiment.checked_settings()
        if s is None:
            self.devices.status.show("the experiment's settings are refused; see the Experiment screen", "error")
            return None
        return CameraSettings(projector_on=s.value("projector_on"), exposure_us=s.value("exposure_us"),
                              gain=s.value("gain"))

    def action_load_experiment(self) -> None:
        devices = self.experiment.load()
        if devices is not None:
            self.devices.set_strings(*devices)

    def action_save_experiment(self) -> None:
        self.experiment.save(self.devices.camera_string, self.devices.stage_string)

    def action_run_from_form(self) -> None:
        if self._start(resume=False):
            self.action_show_tab("run")

    def action_start_run(self) -> None:
        self._start(resume=False)

    def action_resume_run(self) -> None:
        self._start(resume=True)

    def action_pause(self) -> None:
        self.run_pane.toggle_pause()

    def action_unpause(self) -> None:
        self.run_pane.toggle_pause()

    def action_abort(self) -> None:
        self.run_pane.abort()

    def action_help(self) -> None:
        if not isinstance(self.screen, HelpScreen):
            self.push_screen(HelpScreen(self.key_help()))

    def key_help(self) -> list[KeyRow]:
        """Every key the app and its own widgets bind, by where it works (`ACTION_TAB`): what `?` shows."""
        bound = [(ACTION_TAB.get(action_name(b), "everywhere"), b) for b in bindings_of(type(self))]
        bound += [(where, b) for where, cls in (("results: effect list", EffectList), ("results: compare with", AskPath),
                                                ("results: comparison", TextScreen),
                                                ("quit question", ConfirmQuit), ("this help", HelpScreen))
                  for b in bindings_of(cls)]
        return key_rows(bound, frozenset(LETTER_ACTIONS | {"help"}))  # (a text field takes ? too; a list does not)

    def action_open_recording(self) -> None:
        self.results.open()

    def action_refit(self) -> None:
        self.results.refit()

    def action_export_model(self) -> None:
        self.results.export()

    def action_write_report(self) -> None:
        self.results.write_report()

    def action_open_report(self) -> None:
        self.results.open_report()

    def action_compare(self) -> None:
        name = self.results.session.path.name if self.results.session.path else "the recording"

        def answered(other: str | None) -> None:
            if other is not None:
                self.results.compare(other)

        self.push_screen(AskPath(f"Compare {name} with (its model fitted to both, as rig compare does):",
                                 self.results.other_recording()), answered)

    async def action_quit(self) -> None:
        """Quit; during a run, only once the operator confirms (`ConfirmQuit`): the run is then aborted, keeping its
        completed stops, and the app ends when the run's thread has closed the file."""
        if not self.run_pane.running:
            self.exit()
        elif isinstance(self.screen, ConfirmQuit):  # ctrl+q twice
            self.screen.dismiss(True)
        elif not self._quitting:
            s = self.run_pane.state
            self.push_screen(ConfirmQuit(
                f"A run is going on: stop {s.stops_done + 1} of {s.n_stops}, recording {s.output}. Quit? The run is "
                f"aborted after the current frame; its completed stops ({s.stops_done} of {s.n_stops}) stay in {s.output} "
                "(u on the Run screen records the rest later)."), self._quit_answered)

    def _quit_answered(self, quit: bool | None) -> None:
        if not quit:
            return
        if not self.run_pane.running:  # it ended while the question was up
            self.exit()
            return
        self._quitting = True
        self.run_pane.abort()

    # -- glue -------------------------------------------------------------------------------
    def _output(self) -> str:
        try:
            return self.experiment.settings().output
        except Exception:
            return ""

    def _start(self, *, resume: bool) -> bool:
        s = self.experiment.checked_settings()
        if s is None:
            self.run_pane.status.show("the experiment is not valid; see the Experiment screen (2)", "error")
            return False
        if self.devices.busy:
            self.run_pane.status.show("a device operation is under way; try again when it is done", "error")
            return False
        if self.devices.previewing:
            self.devices.stop_preview()  # (it lets go of the camera before the run closes it)
        if self.devices.session.connected:
            self.devices.released("the run opens the devices itself")
        self.run_pane.start(s, self.devices.camera_string, self.devices.stage_string, self.devices.session, resume=resume)
        return True

    def on_devices_pane_limits_changed(self, m: DevicesPane.LimitsChanged) -> None:
        self.experiment.recheck()

    def _handle_exception(self, error: Exception) -> None:
        """Remember what ended the app, so that `rig tui` can say it and exit non-zero (Textual prints the
        traceback and ends the app)."""
        if self.crash is None:
            self.crash = error
        try:
            if self.run_pane.running:
                self.run_pane.live.abort()  # completed stops stay in the file; the run's thread ends at the next frame
        except Exception:  # noqa: BLE001 - no screens (yet, or any more): no run to stop
            pass
        super()._handle_exception(error)

    def on_run_pane_finished(self, m: RunPane.Finished) -> None:
        """What just happened is the new recording: the Results screen drops the previous one's results (its effect
        list would take the next enter) and diagnoses a finished run at once (an aborted one opens on enter)."""
        s = m.state
        if self._quitting:
            self.exit()
            return
        if s.status in ("done", "aborted") and Path(s.output).exists() and not self.results.busy:
            self.results.show_recording(s.output, open_now=s.status == "done")
            if s.status == "done":
                self.run_pane.status.show(f"{s.message}; its results: screen 4", "ok")
            if self.tab == "results":
                self._focus_for("results")
        self.refresh_bindings()
