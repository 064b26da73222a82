"""Form fields that say what is wrong with what is typed in them.

`CheckedField` is Textual's `Input` with its own rules: `restrict` (or `type="number"`/`"integer"`) refuses
characters that cannot be part of the value, and `validators` check the value as a whole. Textual only rings
the bell when it refuses a character, so a file name typed into a number field silently became its digits
("run1605.h5" -> 1605.5). Here a refused character marks the field: it shows as refused (`-refused`), says
what it refused, and counts as wrong until it is emptied (ctrl+u) or its whole text is selected and typed
over, since what is left is not what was typed; typing on after a refusal does not clear it. `RuleCheck` turns a function that returns a problem (or None) into a
Textual validator, so the form's rules stay in one place (`form.field_problem`, `protocols.plan_check`).
"""

from __future__ import annotations

import re
from typing import Callable

from textual import events
from textual.message import Message
from textual.validation import Integer, Number, ValidationResult, Validator
from textual.widgets import Input


class RuleCheck(Validator):
    """A validator from a function: text -> a one-line problem, or None when the text is fine."""

    def __init__(self, problem: Callable[[str], str | None]) -> None:
        super().__init__()
        self.problem = problem

    def validate(self, value: str) -> ValidationResult:
        text = self.problem(value)
        return self.success() if text is None else self.failure(text)


#: what a number field accepts while it is typed: the language of Textual's own `type="integer"` and `"number"` patterns
#: (textual/widgets/_input.py, _RESTRICT_TYPES), written without a quantifier nested in a quantifier. Textual's
#: `(?:\d*|\d+_)*` backtracks exponentially when a run of digits is followed by a character it refuses: 24 digits
#: then a letter kept an integer field busy 2.7 s, 20 digits a number field 25 s, and 40 froze the app (found by
#: pasting quickly in tests/test_tui_operator.py). These possessive patterns take 0.2 ms for 10,000 digits;
#: tests/test_tui_fields.py checks they accept exactly the strings Textual's accept.
_DIGITS = r"(?:\d++_)*+\d*+"  # digits, an underscore only after a digit
NUMERIC_SHAPES = {"integer": rf"[-+]?{_DIGITS}",
                  "number": rf"[-+]?{_DIGITS}(?:\.{_DIGITS})?+(?:(?<=\d)(?:[eE][-+]?|[-+]){_DIGITS})?+"}


def pasted_text(text: str, separator: str | None = None) -> str:
    """What a paste puts into a one-line field: its lines, less the blank ones and the spaces around each; the first,
    or with `separator` all of them joined, the cells of a copied row too (a spreadsheet's column or row of stops
    into a list field). Textual's own Input takes the first line as it is: a copy that began with a line end (as a
    terminal gives the line end before a selection, \\r in a paste) put nothing in the field, and one with a space
    around a number was refused whole."""
    lines = [part.strip() for part in re.split(r"[\r\n\t]+" if separator else r"[\r\n]+", text)]
    lines = [line for line in lines if line]
    if not lines:
        return ""
    return separator.join(lines) if separator else lines[0]


class PasteField(Input):
    """Textual's Input with `pasted_text`'s rule for a paste: the value pasted is not lost to a line end before it,
    nor refused for the spaces around it."""

    def __init__(self, *args, separator: str | None = None, **kw) -> None:
        super().__init__(*args, **kw)
        self.separator = separator

    def _on_paste(self, event: events.Paste) -> None:
        event.prevent_default()  # (Input's own handler would paste again, by its rule)
        event.stop()
        text = pasted_text(event.text, self.separator)
        if not text:
            return
        if self.selection.is_empty:
            self.insert_text_at_cursor(text)
        else:
            self.replace(text, *self.selection)


class CheckedField(PasteField):
    """An input whose refused characters are shown, not only rung on the bell."""

    class Refused(Message):
        """Characters were refused, or a refusal was cleared: the form says so."""

        def __init__(self, field: "CheckedField") -> None:
            super().__init__()
            self.field = field

    def __init__(self, *args, type: str = "text", validators=None, **kw) -> None:
        # a number field is a text field with NUMERIC_SHAPES' pattern, and Textual's validator when no other is given
        self._shape = NUMERIC_SHAPES.get(type)
        if self._shape is not None and not validators:
            validators = [Integer() if type == "integer" else Number()]
        super().__init__(*args, type="text" if self._shape else type, validators=validators, **kw)
        self.refused: list[str] = []  # what was refused (typed characters, pasted text) since the field was emptied
        self._typing = ""

    def replace(self, text: str, start: int, end: int) -> None:
        before = self.value
        self._typing = text
        if self._shape is not None:  # checked here, as Input.replace checks its own type's pattern
            lo, hi = sorted((max(0, start), min(len(before), end)))
            if re.fullmatch(self._shape, f"{before[:lo]}{text}{before[hi:]}") is None:
                self.restricted()
                return
        whole = bool(before) and start <= 0 and end >= len(before)  # all the text selected and typed over
        super().replace(text, start, end)
        if self.refused and ((not text and not self.value) or (whole and text and self.value != before)):
            self.refused = []
            self.set_class(False, "-refused")
            if self.value == before:  # (ctrl+u in a field already empty: no change of value tells the form)
                self.post_message(self.Refused(self))

    def restricted(self) -> None:
        if self._typing not in self.refused:
            self.refused.append(self._typing)
        self.set_class(True, "-refused")
        self.post_message(self.Refused(self))
        super().restricted()

    def set_text(self, text: str) -> None:
        """Set the value from the program (a loaded file): nothing is refused in it."""
        self.refused = []
        self.set_class(False, "-refused")
        self.value = text

    def refusal(self, label: str, what: str) -> str:
        """The problem a refusal makes, in words ("" if nothing was refused)."""
        if not self.refused:
            return ""
        chars = ", ".join(repr(c) for c in self.refused[:6]) + (", ..." if len(self.refused) > 6 else "")
        return (f"{label}: refused {chars} ({what}); what is left may not be what you meant: "
                "clear the field (ctrl+u) and type it again")
