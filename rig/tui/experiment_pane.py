"""Experiment: the protocol and its parameters, loaded from and saved to `rig run`'s TOML files.

The fields are the catalogue's (`form.form_fields`): a protocol registered in `protocols.catalogue` appears in
the Protocol list with its parameters' fields, each shown while a protocol that takes it is selected.

Every field is checked as it is typed, by the rules `rig run` applies (`form.field_problem`, which uses
`protocols.plan_check`): values in range, stops within the stage's travel when the Devices screen knows it,
the output writable, the disk big enough. The lines under the form say what the plan will do, or each
reason it would be refused.
"""

from __future__ import annotations

from typing import Callable

from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.widgets import Checkbox, Input, Label, Select

from protocols.catalogue import protocol_names
from protocols.experiment_file import ExperimentFileError
from protocols.plan_check import RigLimits

from .devices_service import device_words
from .fields import CheckedField, PasteField, RuleCheck
from .form import LIST_CHARACTERS, OUTPUT, ExperimentSettings, field_label, field_param, field_problem, field_takes, form_fields
from .widgets import StatusLine

#: at most this many problems are listed under the form
MAX_LINES = 4


class ExperimentPane(Vertical):
    """A form over `ExperimentSettings`; ctrl+l loads a TOML file, ctrl+s saves one."""

    def __init__(self, settings: ExperimentSettings | None = None, toml_path: str = "experiment.toml", *,
                 limits: Callable[[], RigLimits | None] = lambda: None,
                 devices: Callable[[], tuple[str, str]] = lambda: ("", ""), **kw) -> None:
        super().__init__(**kw)
        self._devices = devices  # the camera and stage strings a run would open (the Devices screen's)
        self._initial = settings or ExperimentSettings()
        self._toml = toml_path
        self._extra: dict = {}
        self._limits = limits
        self._fields = form_fields()  # the catalogue's, as it is when the screen is made
        self._refused = ""  # the refusal the status line shows, until the plan is fixed

    def compose(self) -> ComposeResult:
        with Horizontal(classes="field"):
            yield Label("Experiment file", classes="label")
            yield PasteField(self._toml, id="toml-path", compact=True)
        with Horizontal(classes="field", id="devices-row"):
            yield Label("Devices", classes="label")
            yield Label("", id="devices-line", markup=False)
        with Horizontal(classes="field"):
            yield Label("Protocol", classes="label")
            yield Select([(n, n) for n in protocol_names()], value=self._initial.protocol,
                         allow_blank=False, id="protocol", compact=True)
        for f in self._fields:
            with Horizontal(classes="field", id=f"row-{f.id}"):
                yield Label(field_label(self._initial.protocol, f.id), classes="label", markup=False)
                if f.kind == "checkbox":
                    yield Checkbox("on", True, id=f.id, compact=True)
                else:
                    yield CheckedField(id=f.id, type=f.kind, compact=True, validators=[RuleCheck(self._checker(f.id))],
                                       restrict=f.restrict, separator=", " if f.restrict == LIST_CHARACTERS else None)
        yield Label("", id="plan-line", markup=False)
        yield StatusLine("ctrl+l loads the experiment file, ctrl+s saves it, ctrl+r runs", id="experiment-status")

    def on_mount(self) -> None:
        self.show_settings(self._initial)
        self.show_devices()

    @property
    def status(self) -> StatusLine:
        return self.query_one("#experiment-status", StatusLine)

    @property
    def toml_path(self) -> str:
        return self.query_one("#toml-path", Input).value.strip()

    @property
    def protocol(self) -> str:
        return str(self.query_one("#protocol", Select).value)

    def show_settings(self, s: ExperimentSettings) -> None:
        self._extra = dict(s.extra)
        self.query_one("#protocol", Select).value = s.protocol
        for f in self._fields:
            if f.id == OUTPUT:
                self.query_one(f"#{f.id}", CheckedField).set_text(s.output)
                continue
            value = s.value(f.name)  # another protocol's field: that protocol's default
            if f.kind == "checkbox":
                self.query_one(f"#{f.id}", Checkbox).value = bool(value)
            else:
                protocol = s.protocol if s.protocol in f.protocols else f.protocols[0]
                self.query_one(f"#{f.id}", CheckedField).set_text(field_param(protocol, f.id).text(value))
        self._show_protocol(s.protocol)

    def settings(self) -> ExperimentSettings:
        """The form as settings; raises ExperimentFileError naming the first field that is wrong."""
        problems = self.field_problems()
        if problems:
            raise ExperimentFileError(problems[0])
        s = ExperimentSettings(protocol=self.protocol, extra=dict(self._extra))
        for f in self._shown():
            if f.id == OUTPUT:
                s.output = self.query_one(f"#{f.id}", CheckedField).value.strip()
            elif f.kind == "checkbox":
                s.values[f.name] = self.query_one(f"#{f.id}", Checkbox).value
            else:
                s.values[f.name] = field_param(self.protocol, f.id).parse(self.query_one(f"#{f.id}", CheckedField).value)
        return s

    def field_problems(self) -> list[str]:
        """Each shown field's problem: refused characters first, then values the rules refuse."""
        refusals, values = [], []
        for f in self._shown():
            if f.kind == "checkbox":
                continue
            w = self.query_one(f"#{f.id}", CheckedField)
            if w.refused:
                refusals.append(w.refusal(field_label(self.protocol, f.id), f"it takes {field_takes(self.protocol, f.id)}"))
            problem = field_problem(self.protocol, f.id, w.value, self._limits())
            if problem:
                values.append(problem)
        return refusals + values

    def problems(self) -> list[str]:
        """Everything that stops the plan from running on this rig, one line each."""
        problems = self.field_problems()
        if problems:
            return problems
        return self.settings().problems(self._limits())

    def checked_settings(self) -> ExperimentSettings | None:
        """The settings if `rig run` would accept them, else None with the reason on the status line."""
        problems = self.problems()
        if problems:
            self.status.show(problems[0], "error")
            self._refused = problems[0]
            return None
        return self.settings()

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
        try:
            s = self.settings()
        except ExperimentFileError as e:
            self.status.show(str(e), "error")
            return False
        try:
            path = s.save(self.toml_path, camera, stage)
        except (OSError, ExperimentFileError) as e:
            self.status.show(f"cannot save {self.toml_path}: {e}", "error")
            return False
        self.status.show(f"saved {path}; rig run {path} runs it", "ok")
        return True

    def show_devices(self) -> None:
        """Which camera and stage a run opens, and what they are (simulated, or the kind's words)."""
        camera, stage = self._devices()
        self.query_one("#devices-line", Label).update(f"camera {device_words('camera', camera)}; stage "
                                                      f"{device_words('stage', stage)} (set on screen 1)")

    def recheck(self) -> None:
        """Check every field and the plan again (the devices, and so the travel, may have changed)."""
        self.show_devices()
        for f in self._fields:
            if f.kind != "checkbox":
                w = self.query_one(f"#{f.id}", CheckedField)
                w.validate(w.value)
        self._update_plan_line()

    # -- keeping the form honest ------------------------------------------------------------
    def _checker(self, wid: str) -> Callable[[str], str | None]:
        return lambda text: field_problem(self.protocol, wid, text, self._limits())

    def on_select_changed(self, event: Select.Changed) -> None:
        self._show_protocol(str(event.value))
        self.recheck()

    def on_input_changed(self, event: Input.Changed) -> None:
        self._update_plan_line()

    def on_checked_field_refused(self, event: CheckedField.Refused) -> None:
        self._update_plan_line()

    def on_checkbox_changed(self, event: Checkbox.Changed) -> None:
        event.checkbox.label = "on" if event.value else "off"  # the state in words, not by colour alone
        self._update_plan_line()

    def _shown(self) -> list:
        return [f for f in self._fields if self.protocol in f.protocols]

    def _show_protocol(self, protocol: str) -> None:
        for f in self._fields:
            row = self.query_one(f"#row-{f.id}")
            row.display = protocol in f.protocols
            row.query_one(Label).update(field_label(protocol, f.id))

    def _update_plan_line(self) -> None:
        line = self.query_one("#plan-line", Label)
        problems = self.problems()
        if problems:
            more = len(problems) - MAX_LINES
            line.update("\n".join(f"! {p}" for p in problems[:MAX_LINES]) + (f"\n! ... {more} more" if more > 0 else ""))
            line.set_class(True, "-error")
            return
        if self._refused and self.status.text == self._refused:  # the refusal on show no longer holds
            self.status.show("the plan is accepted now: ctrl+r runs it", "ok")
        self._refused = ""
        s, limits = self.settings(), self._limits()
        travel = "" if limits is not None and limits.travel_m is not None else \
            "; stage travel not checked: connect on screen 1 (c)"
        disk = s.disk_text(limits)
        line.update(s.describe() + (f"; {disk}" if disk else "") + travel)
        line.set_class(False, "-error")
