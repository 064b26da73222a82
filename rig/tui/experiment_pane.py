"""Experiment: the protocol and its parameters, loaded from and saved to `rig run`'s TOML files."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.widgets import Checkbox, Input, Label, Select

from protocols.experiment_file import ExperimentFileError

from .form import ExperimentSettings, format_stops, parse_stops
from .widgets import StatusLine

FIELDS = (  # id, label, input type, which protocol shows it ("" = both)
    ("stops", "Stops [m]", "text", "perpendicular"),
    ("tilt", "Tilt [deg]", "number", "tilted"),
    ("distance", "Distance [m]", "number", "tilted"),
    ("frames", "Frames per stop", "integer", ""),
    ("exposure", "Exposure [us]", "number", ""),
    ("gain", "Gain", "number", ""),
    ("output", "Output file", "text", ""),
)


class ExperimentPane(Vertical):
    """A form over `ExperimentSettings`; ctrl+l loads a TOML file, ctrl+s saves one."""

    def __init__(self, settings: ExperimentSettings | None = None, toml_path: str = "experiment.toml", **kw) -> None:
        super().__init__(**kw)
        self._initial = settings or ExperimentSettings()
        self._toml = toml_path
        self._extra: dict = {}

    def compose(self) -> ComposeResult:
        with Horizontal(classes="field"):
            yield Label("Experiment file", classes="label")
            yield Input(self._toml, id="toml-path", compact=True)
        with Horizontal(classes="field"):
            yield Label("Protocol", classes="label")
            yield Select([("perpendicular", "perpendicular"), ("tilted", "tilted")], value="perpendicular",
                         allow_blank=False, id="protocol", compact=True)
        with Horizontal(classes="field"):
            yield Label("Projector", classes="label")
            yield Checkbox("on", True, id="projector", compact=True)
        for wid, label, kind, protocol in FIELDS:
            with Horizontal(classes=f"field {protocol}".strip(), id=f"row-{wid}"):
                yield Label(label, classes="label", markup=False)
                yield Input(id=wid, type=kind, compact=True)
        yield Label("", id="plan-line")
        yield StatusLine("ctrl+l loads the experiment file, ctrl+s saves it, ctrl+r runs", id="experiment-status")

    def on_mount(self) -> None:
        self.show_settings(self._initial)

    @property
    def status(self) -> StatusLine:
        return self.query_one("#experiment-status", StatusLine)

    @property
    def toml_path(self) -> str:
        return self.query_one("#toml-path", Input).value.strip()

    def show_settings(self, s: ExperimentSettings) -> None:
        self._extra = dict(s.extra)
        self.query_one("#protocol", Select).value = s.protocol
        self.query_one("#projector", Checkbox).value = s.projector_on
        values = {"stops": format_stops(s.stops_m), "tilt": f"{s.tilt_deg:g}", "distance": f"{s.distance_m:g}",
                  "frames": str(s.frames), "exposure": f"{s.exposure_us:g}", "gain": f"{s.gain:g}", "output": s.output}
        for wid, v in values.items():
            self.query_one(f"#{wid}", Input).value = v
        self._show_protocol(s.protocol)

    def settings(self) -> ExperimentSettings:
        """The form as settings; raises ExperimentFileError naming the field that is wrong."""
        def value(wid: str, typ, what: str):
            text = self.query_one(f"#{wid}", Input).value.strip()
            try:
                return typ(text)
            except ValueError:
                raise ExperimentFileError(f"{what}: {text!r} is not a {'whole ' if typ is int else ''}number") from None

        protocol = str(self.query_one("#protocol", Select).value)
        s = ExperimentSettings(protocol=protocol, projector_on=self.query_one("#projector", Checkbox).value,
                               extra=dict(self._extra))
        s.frames = value("frames", int, "frames per stop")
        s.exposure_us = value("exposure", float, "exposure")
        s.gain = value("gain", float, "gain")
        if protocol == "tilted":
            s.tilt_deg = value("tilt", float, "tilt")
            s.distance_m = value("distance", float, "distance")
        else:
            s.stops_m = parse_stops(self.query_one("#stops", Input).value)
        s.output = self.query_one("#output", Input).value.strip()
        if not s.output:
            raise ExperimentFileError("output file: give a file name, e.g. run.h5")
        return s

    def checked_settings(self) -> ExperimentSettings | None:
        """The settings if `rig run` would accept them, else None with the reason on the status line."""
        try:
            s = self.settings()
            s.plan()
        except ExperimentFileError as e:
            self.status.show(str(e), "error")
            return None
        return s

    def load(self) -> tuple[str, str] | None:
        """Load the experiment file; return its camera and stage strings."""
        try:
            s, camera, stage = ExperimentSettings.load(self.toml_path)
        except ExperimentFileError as e:
            self.status.show(str(e), "error")
            return None
        self.show_settings(s)
        self.status.show(f"loaded {self.toml_path}", "ok")
        return camera, stage

    def save(self, camera: str, stage: str) -> bool:
        s = self.checked_settings()
        if s is None:
            return False
        try:
            path = s.save(self.toml_path, camera, stage)
        except (OSError, ExperimentFileError) as e:
            self.status.show(f"cannot save {self.toml_path}: {e}", "error")
            return False
        self.status.show(f"saved {path}; rig run {path} runs it", "ok")
        return True

    # -- keeping the form honest ------------------------------------------------------------
    def on_select_changed(self, event: Select.Changed) -> None:
        self._show_protocol(str(event.value))
        self._update_plan_line()

    def on_input_changed(self, event: Input.Changed) -> None:
        self._update_plan_line()

    def on_checkbox_changed(self, event: Checkbox.Changed) -> None:
        self._update_plan_line()

    def _show_protocol(self, protocol: str) -> None:
        for wid, _, _, only in FIELDS:
            if only:
                self.query_one(f"#row-{wid}").display = only == protocol
        self.query_one("#row-frames Label", Label).update("Frames" if protocol == "tilted" else "Frames per stop")

    def _update_plan_line(self) -> None:
        line = self.query_one("#plan-line", Label)
        try:
            s = self.settings()
            s.plan()
        except ExperimentFileError as e:
            line.update(f"! {e}")
            line.set_class(True, "-error")
            return
        line.update(s.describe())
        line.set_class(False, "-error")
