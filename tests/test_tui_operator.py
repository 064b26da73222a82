"""`rig tui` as an operator meets it at 80x24 (issue 17): a focus that is seen, Tab counts that do not depend on
what came before, digits that stay in their field, fields that refuse bad characters visibly and check the plan
by `rig run`'s own rules, a results table that is readable, words for state, progress with a time left, and no
input that ends the app (a crash exits non-zero, with the message). Real app, driven by Textual's pilot."""

from __future__ import annotations

import math
import re
import os
import subprocess
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow


pytest.importorskip("textual", reason="rig tui needs textual (pip install -e .[test])")

from textual.binding import Binding  # noqa: E402
from textual.widgets import Checkbox, Input, Select  # noqa: E402

from rig.simulation.scenarios import hidden_scenario, record_scenario  # noqa: E402
from rig.tui.app import RigApp  # noqa: E402
from tui_pilot import TIMEOUT_S, run, screen_text, type_into, until  # noqa: E402
from rig.tui.fields import CheckedField  # noqa: E402
from rig.tui.launch import run_app  # noqa: E402
from rig.tui.widgets import EffectList, HeadlineChart  # noqa: E402

CAMERA = "fake:width=53,depth_unit_mm=0.05"


def plan_line(app) -> str:
    return str(app.query_one("#plan-line").render())


@pytest.fixture(scope="module")
def slant(tmp_path_factory) -> Path:
    return record_scenario(hidden_scenario(3, "slant_range", width=40, frames=12),
                           tmp_path_factory.mktemp("slant") / "slant.h5")


# -- focus and keys ---------------------------------------------------------------------------


def distance(a, b) -> float:
    return math.dist((a.r, a.g, a.b), (b.r, b.g, b.b))


def test_the_focused_field_stands_out():
    async def go():
        app = RigApp(CAMERA, "fake:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("2")
            for focused, other in (("#frames", "#gain"), ("#protocol", "#frames"), ("#projector", "#gain")):
                app.query_one(focused).focus()
                await pilot.pause()
                widget = app.query_one(focused)
                shown = widget.query_one("SelectCurrent") if isinstance(widget, Select) else widget
                bright, plain = shown.background_colors[1], app.query_one(other).background_colors[1]
                assert distance(bright, plain) > 80, (focused, bright, plain)  # not one shade of grey apart
                label = widget.parent.query_one(".label")
                unfocused_label = app.query_one(other).parent.query_one(".label")
                assert distance(label.background_colors[1], unfocused_label.background_colors[1]) > 80

    run(go())


def test_tab_order_does_not_depend_on_what_came_before():
    async def go():
        app = RigApp(CAMERA, "fake:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("tab")
            assert app.focused.id == "camera-string"  # the tab bar takes no focus
            await pilot.press("f2", "tab", "tab", "tab", "tab", "tab", "tab")
            assert app.focused.id == "gain"
            # wander: another field, other screens (F-keys work from inside a field), back
            app.query_one("#output").focus()
            await pilot.press("f3", "f1", "tab", "f4", "f2")
            assert app.focused.id == "toml-path"
            await pilot.press("tab", "tab", "tab", "tab", "tab", "tab")
            assert app.focused.id == "gain"

    run(go())


def test_digits_typed_in_a_field_never_switch_screens():
    async def go():
        app = RigApp(CAMERA, "fake:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("2")
            await type_into(pilot, "frames", "1234")
            assert app.tab == "experiment" and app.query_one("#frames", Input).value == "1234"
            for field in ("#projector", "#protocol"):  # not text, but part of the form: digits stay here too
                app.query_one(field).focus()
                await pilot.press("3", "4", "1")
                assert app.tab == "experiment", field
            assert isinstance(app.focused, (Checkbox, Select))
            await pilot.press("escape", "3")  # out of the form, a digit switches
            assert app.tab == "run"

    run(go())


# -- fields that refuse, and the plan's rules -------------------------------------------------


def test_a_file_name_typed_into_the_gain_field_is_refused_visibly(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)

    async def go():
        app = RigApp(CAMERA, "fake:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("2")
            await type_into(pilot, "gain", "run1605.h5")
            gain = app.query_one("#gain", CheckedField)
            assert gain.has_class("-refused") and gain.refused == ["r", "u", "n", "h"]
            line = plan_line(app)
            assert line.startswith("! Gain: refused 'r', 'u', 'n', 'h' (it takes a number)") and "ctrl+u" in line
            assert "Gain: refused" in screen_text(app)  # on the screen, not only in the widget
            assert app.experiment.checked_settings() is None
            await pilot.press("ctrl+r")  # refused: no run, and nothing written
            assert app.tab == "experiment" and not app.run_pane.running and not (tmp_path / "run.h5").exists()
            await pilot.press("end", "5")  # typing on does not make it right...
            assert gain.refused and "refused" in plan_line(app)
            await type_into(pilot, "gain", "32")  # ...emptying it and typing again does
            assert not gain.has_class("-refused") and not plan_line(app).startswith("!")
            assert app.experiment.checked_settings().values["gain"] == 32.0

    run(go())


def test_the_form_checks_the_plan_with_rig_runs_rules(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("")

    async def go():
        app = RigApp(CAMERA, "fake:min_m=0.3,max_m=2.0")
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.devices.limits is not None, "the devices' travel")
            await pilot.press("2")  # the default stops go to 3 m: the travel is checked as soon as it is known
            assert plan_line(app).startswith("! Stops [m]: 2.250 m, 2.500 m, 2.750 m, 3.000 m are outside the travel")
            await type_into(pilot, "stops", "0.5, 2.5, 3")
            assert app.query_one("#stops").has_class("-invalid")
            assert ("! Stops [m]: 2.500 m, 3.000 m are outside the travel of fake-stage, 0.300-2.000 m"
                    in plan_line(app))
            await type_into(pilot, "stops", "0.5, 300")  # the 300 m
            assert "stops_m = 300.0 is outside 0.05 to 100 m" in plan_line(app)
            await type_into(pilot, "frames", "1")
            await type_into(pilot, "output", "afile/run.h5")
            line = plan_line(app)
            assert "at least 2 frames are needed for a variance" in line and "afile is a file, not a folder" in line
            assert line.count("! ") == 3  # every problem, one line each
            await pilot.press("ctrl+r")
            assert app.tab == "experiment" and "Stops [m]" in app.experiment.status.text
            await type_into(pilot, "stops", "0.5, 1.5")
            await type_into(pilot, "frames", "5")
            await type_into(pilot, "output", "ok.h5")
            assert not plan_line(app).startswith("!") and "MB on disk" in plan_line(app)
            # another stage string: its travel is not known until it is connected
            app.query_one("#stage-string", Input).value = "fake:"
            await pilot.pause()
            assert "stage travel not checked: connect on screen 1" in plan_line(app)

    run(go())


@pytest.mark.skipif(os.geteuid() != 0, reason="mounting a small tmpfs needs root")
def test_the_form_refuses_a_plan_bigger_than_the_free_disk(tmp_path, monkeypatch):
    disk = tmp_path / "disk"
    disk.mkdir()
    assert subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1024k", "tmpfs", str(disk)]).returncode == 0
    monkeypatch.chdir(tmp_path)

    async def go():
        app = RigApp(CAMERA, "fake:")
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.devices.limits is not None, "the devices")
            await pilot.press("2")
            await type_into(pilot, "output", "disk/run.h5")
            return plan_line(app)

    try:
        line = run(go())
    finally:
        subprocess.run(["umount", "-l", str(disk)])
    assert line.startswith("! disk: the recording needs up to") and "11 stops of 53x30 px" in line, line


# -- results ----------------------------------------------------------------------------------


def test_results_are_readable_at_80x24_after_a_refit_and_say_their_state_in_words(slant):
    async def go():
        app = RigApp(connect=False, recording=str(slant))
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.results.session.diagnosis is not None and not app.results.busy,
                        "the diagnosis")
            effects = app.query_one(EffectList)
            text = screen_text(app)
            assert "[ ] slant_range" in text and "[x] slant_range" not in text
            for name in ("noise_floor", "incidence"):
                effects.select(name)
            effects.select("slant_range")
            await pilot.pause()
            assert "[x] slant_range" in screen_text(app) and "[ ] drift" in screen_text(app)
            await pilot.press("f")
            await until(pilot, lambda: len(app.results.session.history) == 2 and not app.results.busy, "the refit")
            text = screen_text(app)
            rows = app.results.session.fit_rows()
            assert len(rows) >= 5  # k, lambda, the noise floor's parameter, the power law's two
            for r in rows:
                assert f" {r.value} " in text and f" {r.se}" in text, (r, text)
            for h in app.results.session.history:
                assert f"{h.headline.error_pct:.2f} %" in text
            assert "[x] slant_range   in the model" in text  # words, not only a colour
            chart = app.query_one(HeadlineChart).plain
            assert all((" ok" in line) == h.headline.within_noise
                       for line, h in zip(chart.splitlines(), app.results.session.history))

    run(go())


def test_a_diagnosis_shows_progress_with_time_left_and_the_app_stays_responsive(slant):
    async def go():
        app = RigApp(connect=False, recording=str(slant))
        async with app.run_test(size=(80, 24)) as pilot:
            busy_when_switched: list[bool] = []
            switch = app.action_show_tab

            def spy(tab: str) -> None:  # the key is handled while the diagnosis works in its thread
                busy_when_switched.append(app.results.busy)
                switch(tab)

            app.action_show_tab = spy
            seen: list[str] = []
            show = app.results.status.show
            app.results.status.show = lambda text, level="info": (seen.append(text), show(text, level))
            deadline = time.monotonic() + TIMEOUT_S
            while not app.results.status.text.startswith("diagnosing") and time.monotonic() < deadline:
                await pilot.pause(0.01)
            await pilot.press("f2")  # (the path field has the focus: a 2 would be typed into it)
            assert app.tab == "experiment" and busy_when_switched == [True]
            await pilot.press("f4")  # (the experiment file's field has the focus: a 4 would be typed into it)
            await until(pilot, lambda: not app.results.busy, "the diagnosis")
            assert app.tab == "results" and not app.results.busy
            steps = sorted(set(s for s in seen if " step " in s), key=seen.index)
            assert len(steps) >= 3, steps
            assert all(s.startswith(f"diagnosing {slant}: ") and "%" in s and " of " in s for s in steps), steps
            assert any(re.search(r" so far, (about|at least) \d", s) for s in steps), steps

    run(go())


def test_a_one_stop_recording_opens_with_a_message_and_a_broken_file_is_one_line(tmp_path):
    from simrig import record_perpendicular

    one, _, _ = record_perpendicular(tmp_path / "one.h5", width=16, frames=6, stops_m=[1.0])
    junk = tmp_path / "junk.h5"
    junk.write_text("not a recording")

    async def go():
        app = RigApp(connect=False, recording=str(one))
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: not app.results.busy and app.results.session.diagnosis is not None, "opening")
            assert "note: one stop only" in app.results.status.text
            await type_into(pilot, "recording-path", str(junk))
            await pilot.press("enter")
            await until(pilot, lambda: not app.results.busy, "the refusal")
            status = app.results.status
            assert status.has_class("-error") and str(junk) in status.text and "\n" not in status.text

    run(go())


# -- nothing ends the app; a crash says so ----------------------------------------------------

NASTY = ["", "abc", "-1", "1e999", "nan", "0:0:0", "3:0.5:0.25", "0.5:3:-1", "/", "../..", "é€🙂", "9" * 40, " , , "]


async def paste_into(pilot, field: str, text: str, *, settle: bool = True) -> None:
    """Paste over a field's whole text (one event, as a terminal sends a paste; an empty text deletes it). With
    `settle` False the next paste follows before the app has handled this one, as from a script or a fast hand:
    the pastes then pile up in the field (this found Textual's number patterns freezing on 40 digits)."""
    from textual import events

    widget = pilot.app.query_one(f"#{field}", Input)
    widget.focus()
    widget.select_all()  # the paste replaces the whole text (when the app has caught up)
    widget.post_message(events.Paste(text) if text else events.Key("backspace", None))
    if settle:
        await pilot.pause()


def test_no_input_ends_the_app(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)

    async def go():
        app = RigApp(CAMERA, "fake:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("2")
            for field in ("toml-path", "stops", "frames", "exposure-us", "gain", "output"):
                for text in NASTY:
                    refusable = field in ("frames", "gain") and text == "abc"
                    await paste_into(pilot, field, text, settle=refusable or text == NASTY[-1])
                    if refusable:  # the paste is refused, visibly
                        assert app.query_one(f"#{field}", CheckedField).refused == ["abc"]
                        assert app.experiment.checked_settings() is None
                await pilot.press("ctrl+s", "ctrl+l", "escape")
            app.query_one("#protocol").value = "tilted"
            for text in NASTY:
                await paste_into(pilot, "tilt-deg", text, settle=False)
                await paste_into(pilot, "distance-m", text, settle=text == NASTY[-1])
            await pilot.press("ctrl+r", "escape", "4")
            for text in ("", str(tmp_path), "nothere.h5"):
                await paste_into(pilot, "recording-path", text)
                await pilot.press("enter")
                await until(pilot, lambda: not app.results.busy, "the results screen")
            await pilot.press("escape", "o", "f", "space", "1", "c", "t", "h", "x")
            await until(pilot, lambda: not app.devices.busy, "the devices screen")
            assert app.is_running

    run(go())  # run_test raises whatever ended the app


class CrashingApp(RigApp):
    BINDINGS = [Binding("k", "crash", "crash")]

    def action_crash(self) -> None:
        raise RuntimeError("boom at the keyboard")


def test_a_crash_exits_non_zero_and_says_what_happened(capsys):
    async def press_k(pilot):
        await pilot.pause()
        await pilot.press("k")

    code = run_app(CrashingApp(connect=False), headless=True, size=(80, 24), auto_pilot=press_k)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert err[-1].startswith("rig tui: error: the UI stopped on an unexpected error "
                              "(RuntimeError: boom at the keyboard)"), err[-3:]


# -- papercuts (issue 27) ----------------------------------------------------------------------


def test_typing_on_the_results_screen_goes_into_the_path_field_and_starts_nothing(slant):
    """A path set but nothing diagnosed: letters (o, f, u) typed there are the file's name, not commands; a
    diagnosis (the long work) starts on enter or ctrl+o only."""

    async def go():
        app = RigApp(connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            app.results.set_path(str(slant))
            await pilot.press("f4")
            await pilot.press("end", "o", "u", "f")
            await pilot.pause()
            assert app.query_one("#recording-path", Input).value == f"{slant}ouf"
            assert not app.results.busy and app.results.session.diagnosis is None

    run(go())


def test_a_refused_plan_message_goes_when_the_plan_is_fixed(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)

    async def go():
        app = RigApp(CAMERA, "fake:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("f2")
            await type_into(pilot, "frames", "1")
            await pilot.press("ctrl+r")  # refused: says why on the Experiment screen
            refusal = app.experiment.status.text
            assert app.tab == "experiment" and "Frames per stop" in refusal and app.experiment.status.has_class("-error")
            await type_into(pilot, "frames", "5")
            assert app.experiment.status.text != refusal and not app.experiment.status.has_class("-error")
            assert "accepted" in app.experiment.status.text

    run(go())
