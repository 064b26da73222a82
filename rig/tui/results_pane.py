"""Results: a recording's fit, where the model fails, and which effects to add."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable

from textual import work
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.message import Message
from textual.widgets import Input, Label, Static
from textual.worker import get_current_worker

from protocols.recording import RecordingError

from rig.models.fitting.progress import WorkProgress

from .dialogs import TextScreen
from .fields import PasteField
from .results_outputs import (Written, compare, display_available, export_model, model_file, open_in_browser,
                              report_folder, write_report)
from .results_service import ProgressText, ResultsSession
from .widgets import BinTable, EffectList, FitTable, HeadlineChart, ShapePlot, StatusLine, headline_words


class Cancelled(Exception):
    """The work was cancelled (the app is going down): it stops at its next step."""


class ResultsPane(Vertical):
    """Open (enter in the path field, or ctrl+o: a diagnosis, the long work), check effects (space), refit (f: one
    fit); each refit adds a bar to the headline chart. Typing is never a command here: the path field has the focus
    until a recording is diagnosed, opening takes enter or ctrl+o, and a diagnosis that ends while the operator types
    in a field leaves the focus there."""

    class Done(Message):
        def __init__(self, what: str, error: str = "", result: Any = None) -> None:
            super().__init__()
            self.what, self.error, self.result = what, error, result

    class Progress(Message):
        """The diagnosis in the worker thread reached a step (posted from that thread)."""

        def __init__(self, text: str) -> None:
            super().__init__()
            self.text = text

    def __init__(self, recording: str = "", clock=time.monotonic, **kw) -> None:
        super().__init__(**kw)
        self.clock = clock  # for the time left of a diagnosis
        self.session = ResultsSession()
        self._recording = recording
        self.busy = False
        self._typed = False  # a field's text changed while the work went on: its end leaves the focus there
        self.opened: list[str] = []  # the recordings diagnosed here, the latest last (c offers the one before)
        self.report: Path | None = None  # the fit report last written (b opens it)
        self._replace: Path | None = None  # a file that exists, which the same key pressed again replaces

    def compose(self) -> ComposeResult:
        with Horizontal(classes="field"):
            yield Label("Recording", classes="label")
            yield PasteField(self._recording, id="recording-path", compact=True, placeholder="path to a recording (.h5)")
        with Horizontal(classes="field"):
            yield Label("Effects file", classes="label")
            yield PasteField("", id="effects-path", compact=True,
                        placeholder="optional: your effects (a .py file, docs/effects.md)")
        yield StatusLine("enter (or ctrl+o) opens the recording", id="results-status")
        with Horizontal(classes="columns"):
            with Vertical(classes="left"):
                with VerticalScroll(id="fit-box"):
                    yield FitTable(id="fit-table")
                yield BinTable(id="bin-table")
            with Vertical(classes="right"):
                yield Label("[x] in next fit    dBIC (* signif.)", id="effects-head", markup=False)
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

    def show_recording(self, path: str, *, open_now: bool) -> None:
        """A recording that just came (a run's): the previous one's results go from the screen, so that nothing
        shown, and no key, is about another file; with `open_now`, it is diagnosed at once."""
        self.session = ResultsSession()
        self.report, self._replace = None, None
        for table in (self.query_one(FitTable), self.query_one(BinTable), self.query_one(EffectList)):
            table.show_rows([])
        self.query_one(HeadlineChart).show_history([])
        self.query_one("#summary", Static).update("")
        self.query_one(ShapePlot).show_shape(None)
        self.set_path(path)
        if open_now:
            self.open()
        else:
            self.status.show(f"{path} was just recorded: enter (or ctrl+o) opens it", "info")

    # -- actions ----------------------------------------------------------------------------
    def open(self) -> None:
        if not self.path:
            self.query_one("#recording-path", Input).focus()
            self.status.show("type the recording's path and press enter", "info")
            return
        self._start("open", f"reading {self.path} ...")

    def refit(self) -> None:
        if self.session.diagnosis is None:
            self.status.show("open a recording first (enter in its path field, or ctrl+o)", "error")
            return
        effects = self.query_one(EffectList).checked()
        if set(effects) == set(self.session.effects):
            self.status.show("nothing changed: check an effect with space, then refit", "info")
            return
        self._start("refit", f"fitting {'+'.join([self.session.base.name if self.session.base else '', *effects])} ...",
                    effects)

    # -- what leaves the screen -------------------------------------------------------------
    def export(self) -> None:
        """e: the model on the screen as `rig export` writes it, to where it writes by default."""
        out = model_file(self.session)
        if self._exists(out, "e"):
            return
        self._output("export", f"writing {out} ...", lambda: export_model(self.session, out))

    def write_report(self) -> None:
        """w: fit.html of the model on the screen, as `rig fit --report` writes it, in RECORDING-report/."""
        folder = report_folder(self.session)
        if self._exists(folder / "fit.html", "w"):
            return
        self._output("report", f"writing {folder / 'fit.html'} ...", lambda: write_report(self.session, folder))

    def compare(self, other: str) -> None:
        """The recording on the screen against `other`, as `rig compare` compares them, with the model on the screen."""
        name = self.session.path.name if self.session.path else ""
        self._output("compare", f"fitting {self.session.fit.model.name if self.session.fit else ''} to {name} and "
                                f"{other} ...", lambda: (other, *compare(self.session, other)))

    def other_recording(self) -> str:
        """The recording diagnosed here before the one on the screen ("" if none): what c offers to compare with."""
        here = self.session.path.resolve() if self.session.path else None
        return next((p for p in reversed(self.opened) if Path(p).resolve() != here), "")

    def open_report(self) -> None:
        """b: the report in a browser (the app offers it only where there is a display)."""
        if self.report is not None:
            self._browse(self.report)

    def _exists(self, out: Path, key: str) -> bool:
        """True, and the question on the status line, when `out` exists and `key` was not pressed again for it."""
        if out.exists() and self._replace != out:
            self._replace = out
            self.status.show(f"{out} exists: {key} again replaces it", "info")
            return True
        self._replace = None
        return False

    def _output(self, what: str, text: str, make: Callable[[], Any]) -> None:
        if self.busy:
            self.status.show("busy: wait for the fit to finish", "error")
            return
        self.busy = True
        self.status.show(text, "busy")
        self.app.refresh_bindings()
        self._output_work(what, make)

    @work(thread=True, exclusive=True, group="results")
    def _output_work(self, what: str, make: Callable[[], Any]) -> None:
        try:
            self.post_message(self.Done(what, result=make()))
        except (RecordingError, ValueError, OSError) as e:
            self.post_message(self.Done(what, error=str(e)))
        except Exception as e:  # noqa: BLE001 - one line on the screen, and the UI goes on
            self.post_message(self.Done(what, error=f"could not {what} {self.path}: {type(e).__name__}: {e}"))

    @work(thread=True, group="browser")
    def _browse(self, page: Path) -> None:  # (a browser given by $BROWSER is waited for: never in the UI's thread)
        problem = open_in_browser(page)
        self.post_message(self.Done("browse", error=problem, result=page))

    def _show_output(self, m: Done) -> None:
        if m.what == "export":
            w: Written = m.result
            self.status.show(w.line + (f"; {w.warning}" if w.warning else ""), "error" if w.warning else "ok")
        elif m.what == "report":
            self.report = m.result
            offer = "b opens it in a browser" if display_available() else "no display here: open it where there is one"
            self.status.show(f"report: {m.result}; {offer}", "ok")
        elif m.what == "compare":
            other, text, verdicts = m.result
            name = self.session.path.name if self.session.path else ""
            self.status.show("; ".join(verdicts) or f"compared {name} with {other}", "ok")
            self.app.push_screen(TextScreen(f"rig compare {name} {other} --model {self.session.fit.model.name}", text))
        elif m.what == "browse":
            self.status.show(f"opened {m.result} in the browser", "ok")

    def _start(self, what: str, text: str, effects: list[str] | None = None) -> None:
        if self.busy:
            self.status.show("busy: wait for the fit to finish", "error")
            return
        self.busy, self._typed = True, False
        self.status.show(text, "busy")
        self.app.refresh_bindings()
        self._work(what, self.path, effects or [], self.effects_file)

    @work(thread=True, exclusive=True, group="results")
    def _work(self, what: str, path: str, effects: list[str], effects_file: str) -> None:
        words = ProgressText(f"diagnosing {path}" if what == "open" else "refitting", self.clock)

        worker = get_current_worker()

        def progress(p: WorkProgress) -> None:
            if worker.is_cancelled:
                raise Cancelled  # (ctrl+q waits for this thread: a diagnosis stops at its next step, not its end)
            if not p.finished:
                self.post_message(self.Progress(words.text(p)))

        try:
            if what == "open":
                self.session.open(path, effects_file, progress=progress)
            else:
                self.session.refit(effects, progress=progress)
        except Cancelled:
            return
        except (RecordingError, ValueError, OSError) as e:
            self.post_message(self.Done(what, error=str(e)))
            return
        except Exception as e:  # noqa: BLE001 - whatever the file holds, one line on the screen, and the UI goes on
            self.post_message(self.Done(what, error=f"could not {'open' if what == 'open' else 'refit'} {path}: "
                                                    f"{type(e).__name__}: {e}"))
            return
        self.post_message(self.Done(what))


    def on_results_pane_progress(self, m: Progress) -> None:
        if self.busy:
            self.status.show(m.text, "busy")

    def on_results_pane_done(self, m: Done) -> None:
        if m.what != "browse":
            self.busy = False
        self.app.refresh_bindings()
        if m.error:
            self.status.show(m.error, "error")
            return
        if m.what not in ("open", "refit"):
            self._show_output(m)
            return
        try:
            self._show_results(m.what)
        except Exception as e:  # noqa: BLE001 - a result the widgets cannot draw is said, not a crash
            self.status.show(f"could not show the results of {self.path}: {type(e).__name__}: {e}", "error")

    def _show_results(self, what: str) -> None:
        s = self.session
        self.query_one(FitTable).show_rows(s.fit_rows())
        self.query_one(BinTable).show_rows(s.bin_rows())
        self.query_one(EffectList).show_rows(s.candidate_rows())
        self.query_one(HeadlineChart).show_history(s.history)
        self.query_one("#summary", Static).update(s.summary())
        self.query_one(ShapePlot).show_shape(s.shape())
        h = s.history[-1]
        if what == "open":
            if s.path is not None:
                self.opened = [p for p in self.opened if Path(p).resolve() != s.path.resolve()] + [str(s.path)]
            self.report, self._replace = None, None
            name = s.path.name if s.path else ""
            if h.headline.judged:
                text = (f"{name}: headline error {h.headline.error_pct:.2f} % with {h.model}; space checks effects, "
                        "f refits")
            else:
                text = f"{name}: {h.model} not judged: {h.headline.verdict().removeprefix('NOT JUDGED: ')}"
            if s.notes:
                text += "; note: " + "; ".join(s.notes)
        else:
            before = headline_words(s.history[-2].headline).removesuffix(" ok")
            text = f"{h.change}: headline error {before} -> {headline_words(h.headline).removesuffix(' ok')}"
        self.status.show(text, "ok" if h.headline.judged else "info")
        shown = all(node.display for node in self.ancestors_with_self if hasattr(node, "display"))
        if shown and not self._typed:  # (not while another screen is in front: focusing would switch to this one)
            self.query_one(EffectList).focus()

    def on_input_changed(self, event: Input.Changed) -> None:
        if self.busy:
            self._typed = True

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()
        self.open()
