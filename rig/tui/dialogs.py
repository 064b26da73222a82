"""Screens over the app (Textual's `ModalScreen`): while one is up, only its own keys and ctrl+q work."""

from __future__ import annotations

import re
import textwrap

from rich.table import Table
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import ScrollableContainer, Vertical, VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Input, Static

from .fields import PasteField
from .key_list import KeyRow


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


class HelpScreen(ModalScreen[None]):
    """The keys, as `key_list.key_rows` makes them from the bindings, by where they work."""

    BINDINGS = [Binding("escape,question_mark,q", "close", "Close this help")]

    def __init__(self, rows: list[KeyRow]) -> None:
        super().__init__()
        self.rows = rows

    def compose(self) -> ComposeResult:
        with VerticalScroll(classes="dialog", id="help"):
            yield Static(self.table(), id="help-keys")
            yield Static("* not while a text field has the focus (it takes the key; esc leaves it). esc, ? or q closes "
                         "this help; up and down scroll it", classes="dialog-keys", markup=False)

    def table(self) -> Table:
        t = Table.grid(padding=(0, 2))
        t.add_column(no_wrap=True, style="bold")
        t.add_column()
        group = None
        for r in self.rows:
            if r.group != group:
                group = r.group
                t.add_row(Text(group.capitalize(), style="underline"), "")
            t.add_row(r.keys_text(), r.does)
        return t

    @property
    def plain(self) -> str:
        """The help as text: a line a row, "group: keys: what they do"."""
        return "\n".join(f"{r.group}: {r.keys_text()}: {r.does}" for r in self.rows)

    def action_close(self) -> None:
        self.dismiss(None)


class AskPath(ModalScreen["str | None"]):
    """One path asked for (enter gives it, esc gives up): the recording to compare with."""

    BINDINGS = [Binding("escape", "give_up", "Give up")]

    def __init__(self, question: str, value: str = "") -> None:
        super().__init__()
        self.question, self.value = question, value

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog"):
            yield Static(self.question, markup=False)
            yield PasteField(self.value, id="asked-path", compact=True, placeholder="path to a recording (.h5)")
            yield Static("enter compares; esc goes back", classes="dialog-keys", markup=False)

    def on_mount(self) -> None:
        self.query_one(Input).focus()  # (the app focuses nothing by itself: AUTO_FOCUS)

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()
        self.dismiss(event.value.strip())

    def action_give_up(self) -> None:
        self.dismiss(None)


class TextScreen(ModalScreen[None]):
    """A report to read (a comparison's): its tables keep their columns and scroll sideways; its sentences (the lines
    that start with a word and a colon: "verdict: ...") are wrapped to the screen. Arrows scroll; esc or q closes."""

    BINDINGS = [Binding("escape,q", "close", "Close")]

    def __init__(self, title: str, text: str, width: int = 72) -> None:
        super().__init__()
        self.title_text = title
        self.text = "\n".join(textwrap.fill(line, width, subsequent_indent="  ") if re.match(r"[a-z-]+: ", line) else line
                              for line in text.splitlines())

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog wide"):
            yield Static(self.title_text, classes="dialog-title", markup=False)
            with ScrollableContainer(id="text-scroll"):
                yield Static(Text(self.text, no_wrap=True), id="text-body")
            yield Static("arrows scroll; esc or q closes", classes="dialog-keys", markup=False)

    def on_mount(self) -> None:
        self.query_one("#text-scroll").focus()

    def action_close(self) -> None:
        self.dismiss(None)
