"""`rig tui` does the whole job (issue 51): one experiment driven from the keyboard, from the devices through the
run to its results and what leaves the TUI. The real app, runner, recording and analysis, driven by Textual's pilot,
on the simulated camera at 16x9 px with a few frames a stop, so that the whole of it costs a few seconds of CPU."""

from __future__ import annotations

import json
import re
import webbrowser
from html.parser import HTMLParser
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

pytest.importorskip("textual", reason="rig tui needs textual (pip install -e .[test])")

from protocols.recording import Recording  # noqa: E402
from rig.tui.app import ACTION_TAB, RigApp  # noqa: E402
from cli_in_process import rig_in_process  # noqa: E402
from rig.tui.dialogs import AskPath, ConfirmQuit, HelpScreen, TextScreen  # noqa: E402
from rig.tui.form import ExperimentSettings  # noqa: E402
from rig.tui.launch import run_app  # noqa: E402
from rig.tui.widgets import EffectList  # noqa: E402
from simrig import record_perpendicular  # noqa: E402
from tui_pilot import run, screen_text, type_into, until  # noqa: E402

CAMERA = "fake:width=16,depth_unit_mm=0.05"
DOCS = Path(__file__).resolve().parents[1] / "docs" / "tui.md"


@pytest.fixture(scope="module")
def earlier(tmp_path_factory) -> Path:
    """A recording made before the experiment: the one the Results screen shows when the run starts."""
    path, _, _ = record_perpendicular(tmp_path_factory.mktemp("earlier") / "earlier.h5", width=16, frames=5,
                                      stops_m=[0.5, 1.0, 1.5], seed=7)
    return path


def diagnosed(app) -> bool:
    return app.results.session.diagnosis is not None and not app.results.busy


def test_a_whole_experiment_from_the_keyboard(tmp_path, monkeypatch, earlier):
    monkeypatch.chdir(tmp_path)

    async def go():
        app = RigApp(CAMERA, "fake:", recording=str(earlier))
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: diagnosed(app) and app.devices.session.connected, "the earlier recording")
            effects = app.query_one(EffectList)
            assert app.focused is effects and effects.option_count > 0  # enter would tick the earlier one's effect

            # a live look at the wall before recording: its fill and tilt (the simulated wall faces the camera)
            await pilot.press("f1", "v")
            preview = app.query_one("#preview-info")
            await until(pilot, lambda: "fill" in preview.plain, "the live preview")
            assert re.search(r"wall: 1\.0\d{3} m \+/- [\d.]+ mm on the axis, fill 100\.0 %", preview.plain), preview.plain
            tilt, se = (float(g) for g in re.search(r"tilt: ([-+][\d.]+) \+/- ([\d.]+) deg", preview.plain).groups())
            assert abs(tilt) <= 4 * max(se, 0.005)  # (0.005: the last digit shown)
            assert "bright" in app.query_one("#depth-image").plain

            # the experiment, set up and run from the keyboard (the preview stops for it)
            await pilot.press("f2")
            await type_into(pilot, "stops", "0.5, 1.0, 1.5")
            await type_into(pilot, "frames", "4")
            await type_into(pilot, "output", "new.h5")
            await pilot.press("ctrl+r")
            assert app.tab == "run" and not app.devices.previewing
            await until(pilot, lambda: app.run_pane.state.status == "done", "the run")
            assert "its results: screen 4" in app.run_pane.status.text

            # what just happened has the focus: the new recording, never the earlier one's effects
            assert app.results.session.path in (None, Path("new.h5"))
            assert app.results.session.path is not None or effects.option_count == 0
            await pilot.press("4")
            assert app.focused is effects if diagnosed(app) else app.focused.id == "recording-path"
            await until(pilot, lambda: diagnosed(app), "the new recording's diagnosis")
            assert app.results.session.path == Path("new.h5") and app.results.path == "new.h5"
            assert app.focused is effects
            shown = [effects.get_option_at_index(i).value for i in range(effects.option_count)]
            assert shown == [r.effect for r in app.results.session.candidate_rows()]
            assert "new.h5: headline error" in app.results.status.text
            status = app.results.status
            model = app.results.session.fit.model.name

            # export: the model on the screen, where and as `rig export` writes it
            await pilot.press("e")
            await until(pilot, lambda: not app.results.busy, "the export")
            assert status.text.startswith(f"model: new-noise-model.json ({model}; sigma valid for Z 0.")
            await pilot.press("e")  # the file is there: asked, not overwritten
            assert status.text == "new-noise-model.json exists: e again replaces it"

            # compare with the recording opened before, as `rig compare` compares
            await pilot.press("c")
            assert isinstance(app.screen, AskPath) and app.screen.query_one("#asked-path").value == str(earlier)
            await pilot.press("enter")
            await until(pilot, lambda: isinstance(app.screen, TextScreen), "the comparison")
            compared = app.screen.text
            await pilot.press("escape")
            assert status.text.startswith("new.h5 against earlier.h5: ")
            await pilot.press("c", "home", "ctrl+k", *"new.h5", "enter")  # itself: one line, nothing fitted
            await until(pilot, lambda: not app.results.busy, "the refusal")
            assert status.text == "new.h5 is the recording on the screen; give another to compare it with"

            # the report, and no browser where there is no display
            monkeypatch.delenv("DISPLAY", raising=False)
            monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
            await pilot.press("w")
            await until(pilot, lambda: not app.results.busy, "the report")
            assert status.text == f"report: {Path('new-report', 'fit.html')}; no display here: open it where there is one"
            assert not app.check_action("open_report", ())  # not offered: a console browser would take the terminal
            await pilot.press("b")
            assert status.text.startswith("report: ")
            # with a display, b opens it in the browser webbrowser finds ($BROWSER here: a command that notes the URL)
            monkeypatch.setenv("DISPLAY", ":99")
            monkeypatch.setenv("BROWSER", f"sh -c 'echo \"$0\" > {tmp_path / 'opened.txt'}' %s")
            monkeypatch.setattr(webbrowser, "_tryorder", None)  # (webbrowser reads $BROWSER again)
            app.refresh_bindings()
            await pilot.press("b")
            await until(pilot, lambda: (tmp_path / "opened.txt").exists(), "the browser")
            await until(pilot, lambda: status.text.startswith("opened "), "the status")
            return model, compared

    model, compared = run(go())
    # the file is rig export's, to the byte but for the time it was made, and of the published schema
    import jsonschema

    cli = rig_in_process("export", "new.h5", "--model", model, "-o", "by-rig-export.json")
    assert cli.returncode == 0, cli.stderr
    ours, theirs = (json.loads((tmp_path / f).read_text()) for f in ("new-noise-model.json", "by-rig-export.json"))
    jsonschema.validate(ours, json.loads((DOCS.parent / "noise-model.schema.json").read_text()))
    assert ours.pop("created_utc") and theirs.pop("created_utc")
    assert ours == theirs
    # the comparison is rig compare's text: both recordings, their set-up and a verdict on the pair
    assert compared.count("new.h5") >= 2 and "earlier.h5" in compared and "verdict: new.h5 against earlier.h5" in compared
    # the report: a page an HTML parser reads, naming the recording and the model, its plot beside it
    page = (tmp_path / "new-report" / "fit.html").read_text()
    words = Words()
    words.feed(page)
    assert "Range-error fit: new.h5" in words.text and f"{model}: headline error" in words.text
    assert (tmp_path / "new-report" / "fit-sigma.png").stat().st_size > 1000
    assert (tmp_path / "opened.txt").read_text().strip() == (tmp_path / "new-report" / "fit.html").as_uri()


class Words(HTMLParser):
    """The text of a page, as the standard library's parser reads it."""

    def __init__(self) -> None:
        super().__init__()
        self.text = ""

    def handle_data(self, data: str) -> None:
        self.text += data


def test_quitting_during_a_run_asks_first_then_aborts_keeping_the_completed_stops(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    settings = ExperimentSettings(values=dict(stops_m=[0.5, 1.0, 1.5], frames_per_stop=4), output="run.h5")
    app = RigApp(CAMERA, "fake:", experiment=settings, connect=False)
    seen: dict[str, object] = {}

    async def operator(pilot):
        live = app.run_pane.live
        seen["pane"] = app.run_pane
        # pause from the run's own thread as soon as the first stop is done: no race with the clock
        live.observers.append(lambda e: live.pause() if e.kind == "stop_done" and e.stop_index == 0 else None)
        await pilot.press("3", "r")
        await until(pilot, lambda: app.run_pane.state.status == "paused", "the pause")
        await pilot.press("ctrl+q")
        assert isinstance(app.screen, ConfirmQuit) and app.is_running
        seen["question"] = str(app.screen.query_one("#question").render())
        await pilot.press("a", "p", "1", "q")  # the screens' keys do not reach past the question
        assert isinstance(app.screen, ConfirmQuit) and app.run_pane.state.status == "paused" and app.tab == "run"
        await pilot.press("n")  # back to the run, as it was
        assert not isinstance(app.screen, ConfirmQuit) and app.run_pane.state.status == "paused"
        await pilot.press("ctrl+q", "y")
        await until(pilot, lambda: app.return_code is not None, "the app to end")

    code = run_app(app, headless=True, size=(80, 24), auto_pilot=operator)
    assert code == 0 and app.crash is None
    assert seen["question"].startswith("A run is going on: stop 2 of 3, recording run.h5. Quit?")
    assert "its completed stops (1 of 3) stay in run.h5" in seen["question"]
    assert seen["pane"].state.status == "aborted"
    with Recording(tmp_path / "run.h5") as rec:
        assert rec.stop_labels() == ["0.500m"]


def docs_key_table() -> dict[str, set[str]]:
    """docs/tui.md's table of keys: the first key of each row (`c` in "`c` (or `enter` in a device field)"), by screen."""
    keys: dict[str, set[str]] = {}
    screen = ""
    for line in DOCS.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[1].startswith("`"):
            screen = cells[0].lower() or screen
            keys.setdefault(screen, set()).add(re.match(r"`([^`]+)`", cells[1]).group(1))
    return keys


def test_the_help_lists_the_keys_as_bound_and_the_manual_lists_the_same():
    from textual.binding import BindingsMap
    from textual.keys import format_key

    async def go():
        app = RigApp(CAMERA, "fake:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("question_mark")
            help_screen = app.screen
            assert isinstance(help_screen, HelpScreen)
            shown = screen_text(app)
            await pilot.press("c")  # the screens' keys do not reach past the help
            assert app.screen is help_screen and not app.devices.busy
            await pilot.press("escape")
            assert not isinstance(app.screen, HelpScreen)
            app.query_one("#camera-string").focus()
            await pilot.press("question_mark")  # in a text field, ? is typed
            assert not isinstance(app.screen, HelpScreen) and app.devices.camera_string.endswith("?")
            return help_screen.rows, shown

    rows, shown = run(go())
    said = {(r.group, k): r.does for r in rows for k in r.keys}
    for key, b in BindingsMap(RigApp.BINDINGS):  # every key the app binds, with what it does, as Textual reads them
        where = ACTION_TAB.get(b.action.split("(")[0], "everywhere")
        assert b.description in said[(where, format_key(key))]
    assert said[("everywhere", "f1")] == "Devices screen" and ("everywhere", "1") in said
    assert said[("run", "p")] == "Pause / Continue" and said[("results: effect list", "space")] == "Tick effect"
    assert "c*" in shown and "Devices screen" in shown and "ctrl+l " in shown  # on the screen, not only in the widget
    # the manual's table and the bindings: the same keys on each screen
    table = docs_key_table()
    bound = {}
    for r in rows:
        screen = r.group.split(":")[0]
        if screen in table:
            bound.setdefault(screen, set()).update(r.keys)
    for screen, keys in table.items():
        assert keys <= bound[screen], (screen, keys - bound[screen])
    for screen, keys in bound.items():
        in_docs = [k for row in rows if row.group in (screen, f"{screen}: effect list") for k in row.keys[:1]]
        assert set(in_docs) <= table[screen], (screen, set(in_docs) - table[screen])
    text = DOCS.read_text()
    assert all(f"`{k}`" in text for k in ("?", "esc", "ctrl+q"))


def test_the_experiment_screen_says_which_devices_a_run_opens():
    async def go():
        app = RigApp(CAMERA, "fake:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("2")
            line = app.query_one("#devices-line")
            shown = [str(line.render())]
            for camera, stage in (("realsense:serial=123", "none:"), ("nosuchcam:", "grbl:///dev/ttyUSB0")):
                app.devices.set_strings(camera, stage)  # (as typed on screen 1, or loaded from a file)
                await pilot.pause()
                shown.append(str(line.render()))
            return shown, screen_text(app)

    (simulated, real, unknown), screen = run(go())
    assert simulated == f"camera {CAMERA} (simulated); stage fake: (simulated) (set on screen 1)"
    assert real.startswith("camera realsense:serial=123 (Intel RealSense") and \
        "stage none: (no stage: the distance is set by hand or fixed)" in real
    assert unknown.startswith("camera unknown camera kind 'nosuchcam' in 'nosuchcam:'; known kinds: ")
    assert "stage grbl:///dev/ttyUSB0 (a GRBL controller on a serial port)" in unknown
    assert "a GRBL controller on a serial port) (set on screen 1)" in " ".join(screen.split())  # all of it, at 80x24


def bracketed_paste(text: str):
    """The events a terminal's paste of `text` becomes, through Textual's own parser of what the terminal sends (a
    terminal and tmux send a line end in a paste as \\r)."""
    from textual._xterm_parser import XTermParser

    return list(XTermParser().feed("\x1b[200~" + text.replace("\n", "\r") + "\x1b[201~"))


def test_a_value_pasted_after_ctrl_u_is_kept(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    pasted = {  # field: (what was copied, what the field must hold)
        "gain": ("\n32 ", "32"),  # a line end before the value (the copy began at the end of the line above), a space
        "frames": ("  40\n", "40"),
        "stops": ("0.5\n1.0\n1.5\n", "0.5, 1.0, 1.5"),  # a column of a spreadsheet
        "exposure-us": ("\r\n9000\r\n", "9000"),
        "output": ("\n run2.h5\n", "run2.h5"),
        "toml-path": ("\nexp2.toml", "exp2.toml"),
    }

    async def paste(pilot, field: str, text: str) -> str:
        widget = pilot.app.screen.query_one(f"#{field}")
        widget.focus()
        await pilot.press("end", "ctrl+u")
        for event in bracketed_paste(text):
            widget.post_message(event)
        await pilot.pause()
        return widget.value

    async def go():
        app = RigApp(CAMERA, "fake:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("2")
            held = {field: await paste(pilot, field, text) for field, (text, _) in pasted.items()}
            await pilot.press("escape", "4")
            held["recording-path"] = await paste(pilot, "recording-path", "\n/data/run 7.h5 \n")
            await pilot.press("f2")
            gain = app.query_one("#gain")
            gain.focus()
            await pilot.press("end", "ctrl+u", "x")  # refused in an empty field...
            refused = "Gain: refused 'x'" in str(app.query_one("#plan-line").render())
            await pilot.press("ctrl+u")  # ...and cleared: the lines under the form say so at once
            return held, refused, str(app.query_one("#plan-line").render()), app.experiment.checked_settings()

    held, refused, line, settings = run(go())
    assert held == {**{f: want for f, (_, want) in pasted.items()}, "recording-path": "/data/run 7.h5"}
    assert refused and "refused" not in line and "Gain: give a number" in line
    assert settings is None  # (the gain is empty now)
