"""What the TUI tests share: run a pilot coroutine, wait for the app with a deadline, read the screen, type."""

from __future__ import annotations

import asyncio
import time

from textual.widgets import Input

#: how long a pilot waits for the app to reach a state before the test fails (a diagnosis inside takes longest)
TIMEOUT_S = 60.0


def run(coro):
    return asyncio.run(coro)


async def until(pilot, condition, what: str, timeout_s: float = TIMEOUT_S) -> None:
    """Let the app work until `condition()` holds; fail (not hang) if it never does."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        await pilot.pause(0.05)
    await pilot.pause()


def screen_text(app) -> str:
    """What the terminal shows, as text (each line as the compositor draws it)."""
    return "\n".join(strip.text for strip in app.screen._compositor.render_strips())


async def type_into(pilot, field: str, text: str) -> None:
    """Replace the text of the Input with id `field`."""
    pilot.app.query_one(f"#{field}", Input).focus()
    await pilot.press("home", "ctrl+k", *text)
    await pilot.pause()
