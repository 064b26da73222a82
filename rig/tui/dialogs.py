"""Screens over the app (Textual's `ModalScreen`): while one is up, only its own keys and ctrl+q work."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Static


class ConfirmQuit(ModalScreen[bool]):
    """Quitting while a run goes on: y (or ctrl+q again) quits, aborting the run; n or esc goes back to it."""

    BINDINGS = [Binding("y", "answer(True)", "Quit, abort the run"), Binding("n,escape", "answer(False)", "Go on")]

    def __init__(self, question: str) -> None:
        super().__init__()
        self.question = question

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog"):
            yield Static(self.question, id="question", markup=False)
            yield Static("y quits (ctrl+q too); n or esc goes back to the run", classes="dialog-keys", markup=False)

    def action_answer(self, yes: bool) -> None:
        self.dismiss(yes)
