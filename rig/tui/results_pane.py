"""Results: a recording's fit, where the model fails, and which effects to add."""

from __future__ import annotations

from textual import work
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.message import Message
from textual.widgets import Input, Label, Static

from protocols.recording import RecordingError

from .results_service import ResultsSession
from .widgets import BinTable, EffectList, FitTable, HeadlineChart, ShapePlot, StatusLine


class ResultsPane(Vertical):
    """Open (o), check effects (space), refit (f); each refit adds a bar to the headline chart."""

    class Done(Message):
        def __init__(self, what: str, error: str = "") -> None:
            super().__init__()
            self.what, self.error = what, error

    def __init__(self, recording: str = "", **kw) -> None:
        super().__init__(**kw)
        self.session = ResultsSession()
        self._recording = recording
        self.busy = False

    def compose(self) -> ComposeResult:
        with Horizontal(classes="field"):
            yield Label("Recording", classes="label")
            yield Input(self._recording, id="recording-path", compact=True, placeholder="path to a recording (.h5)")
        with Horizontal(classes="field"):
            yield Label("Effects file", classes="label")
            yield Input("", id="effects-path", compact=True,
                        placeholder="optional: your effects (.py with @effect, docs/effects.md)")
        yield StatusLine("o opens the recording", id="results-status")
        with Horizontal(classes="columns"):
            with Vertical(classes="left"):
                yield FitTable(id="fit-table")
                yield BinTable(id="bin-table")
            with Vertical(classes="right"):
                yield Label("effect          dBIC (* significant)", id="effects-head", markup=False)
                yield EffectList(id="effects")
                yield HeadlineChart(id="headline-chart")
                yield ShapePlot(id="shape-plot")
                with VerticalScroll(id="summary-box"):
                    yield Static("", id="summary")

    @property
    def status(self) -> StatusLine:
        return self.query_one("#results-status", StatusLine)

    @property
    def path(self) -> str:
        return self.query_one("#recording-path", Input).value.strip()

    @property
    def effects_file(self) -> str:
        return self.query_one("#effects-path", Input).value.strip()

    def set_path(self, path: str) -> None:
        self.query_one("#recording-path", Input).value = path

    # -- actions ----------------------------------------------------------------------------
    def open(self) -> None:
        if not self.path:
            self.query_one("#recording-path", Input).focus()
            self.status.show("type the recording's path and press enter", "info")
            return
        self._start("open", f"fitting and diagnosing {self.path} ...")

    def refit(self) -> None:
        if self.session.diagnosis is None:
            self.status.show("open a recording first (o)", "error")
            return
        effects = self.query_one(EffectList).checked()
        if effects == self.session.effects:
            self.status.show("nothing changed: check an effect with space, then refit", "info")
            return
        self._start("refit", f"fitting {'+'.join([self.session.base.name if self.session.base else '', *effects])} ...",
                    effects)

    def _start(self, what: str, text: str, effects: list[str] | None = None) -> None:
        if self.busy:
            self.status.show("busy: wait for the fit to finish", "error")
            return
        self.busy = True
        self.status.show(text, "busy")
        self.app.refresh_bindings()
        self._work(what, self.path, effects or [], self.effects_file)

    @work(thread=True, exclusive=True, group="results")
    def _work(self, what: str, path: str, effects: list[str], effects_file: str) -> None:
        try:
            if what == "open":
                self.session.open(path, effects_file)
            else:
                self.session.refit(effects)
        except (RecordingError, ValueError, OSError) as e:
            self.post_message(self.Done(what, error=str(e)))
            return
        self.post_message(self.Done(what))

    def on_results_pane_done(self, m: Done) -> None:
        self.busy = False
        self.app.refresh_bindings()
        if m.error:
            self.status.show(m.error, "error")
            return
        s = self.session
        self.query_one(FitTable).show_rows(s.fit_rows())
        self.query_one(BinTable).show_rows(s.bin_rows())
        self.query_one(EffectList).show_rows(s.candidate_rows())
        self.query_one(HeadlineChart).show_history(s.history)
        self.query_one("#summary", Static).update(s.summary())
        self.query_one(ShapePlot).show_shape(s.shape())
        h = s.history[-1]
        if m.what == "open":
            name = s.path.name if s.path else ""
            text = f"{name}: headline error {h.headline.error_pct:.2f} % with {h.model}; space checks effects, f refits"
        else:
            before = s.history[-2].headline.error_pct
            text = f"{h.change}: headline error {before:.2f} % -> {h.headline.error_pct:.2f} %"
        self.status.show(text, "ok")
        self.query_one(EffectList).focus()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()
        self.open()
