"""Number fields refuse what cannot be a number at once, however long the text: rig.tui.fields.NUMERIC_SHAPES
against Textual's own patterns (the reference for what a number field accepts) and in a running app."""

from __future__ import annotations

import itertools
import json
import re
import subprocess
import sys

import pytest
from textual.widgets._input import _RESTRICT_TYPES

from rig.tui.fields import NUMERIC_SHAPES


@pytest.mark.parametrize("kind", ["integer", "number"])
def test_the_shapes_accept_exactly_what_textuals_patterns_accept(kind):
    # every string of up to 6 characters over digits, the separators and a letter (37,449 of them); Textual's
    # pattern is exponential only in the length of a digit run, harmless at 6
    alphabet = "12_.e-+x"
    differ = [s for n in range(7) for s in map("".join, itertools.product(alphabet, repeat=n))
              if (re.fullmatch(_RESTRICT_TYPES[kind], s) is None) != (re.fullmatch(NUMERIC_SHAPES[kind], s) is None)]
    assert differ == []


TYPE_AFTER_FORTY_DIGITS = """
import asyncio, json, sys
from textual import events
from textual.app import App
from rig.tui.fields import CheckedField

class TwoFields(App):
    def compose(self):
        yield CheckedField(id="frames", type="integer")
        yield CheckedField(id="distance", type="number")

async def go(field):
    app = TwoFields()
    async with app.run_test() as pilot:
        box = app.query_one("#" + field, CheckedField)
        box.focus()
        await pilot.pause()
        box.post_message(events.Paste("9" * 40))
        await pilot.pause()
        await pilot.press("x", "1")
        return [box.value, box.refused, box.has_class("-refused")]

print(json.dumps(asyncio.run(go(sys.argv[1]))))
"""


@pytest.mark.parametrize("field", ["frames", "distance"])
def test_a_letter_after_forty_digits_is_refused_at_once(field):
    """In a process of its own, with a deadline: with Textual's own pattern the letter keeps the app busy for hours
    (exponential backtracking inside the re module, which holds the interpreter: no in-process timeout can end it)."""
    try:
        p = subprocess.run([sys.executable, "-c", TYPE_AFTER_FORTY_DIGITS, field], capture_output=True, text=True,
                           timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail("a letter typed after 40 digits kept the field busy for 60 s")
    assert p.returncode == 0, p.stderr[-2000:]
    value, refused, shown = json.loads(p.stdout)
    assert value == "9" * 40 + "1" and refused == ["x"] and shown  # refused, shown, and typing goes on
