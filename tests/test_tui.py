"""`rig tui`: driven with Textual's pilot, pinned with snapshots at 80x24, and run in a real terminal (tmux).

Nothing here waits on wall-clock time: workers are awaited by polling a condition with a timeout.
"""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow


pytest.importorskip("textual", reason="rig tui needs textual (pip install -e .[test])")
pytest.importorskip("textual_plotext", reason="rig tui needs textual-plotext")

from textual.widgets import Input  # noqa: E402

from protocols.experiment_file import load_experiment  # noqa: E402
from protocols.recording import Recording  # noqa: E402
from rig.diagnosis import Headline  # noqa: E402
from rig.simulation.scenarios import hidden_scenario, record_scenario  # noqa: E402
from rig.tui.app import RigApp  # noqa: E402
from tui_pilot import TIMEOUT_S, run, type_into, until  # noqa: E402
from rig.tui.form import ExperimentSettings  # noqa: E402
from rig.tui.live import RunState  # noqa: E402
from rig.tui.results_service import BinRow, CandidateRow, FitRow, HistoryEntry, ResultsSession  # noqa: E402
from rig.tui.widgets import EffectList, HeadlineChart, ShapePlot, SigmaPlot  # noqa: E402

try:
    import pytest_textual_snapshot  # noqa: F401  (provides the snap_compare fixture)
except ImportError:
    @pytest.fixture
    def snap_compare():
        pytest.skip("the snapshot tests need pytest-textual-snapshot (pip install -e .[test])")

ROOT = Path(__file__).resolve().parents[1]
CAMERA = "fake:width=53,depth_unit_mm=0.05"
SMALL = dict(values=dict(stops_m=[0.5, 1.0, 1.5], frames_per_stop=5), output="run.h5")


@pytest.fixture(scope="module")
def slant_recording(tmp_path_factory) -> Path:
    """A small simulated perpendicular run hiding the slant-range effect."""
    out = tmp_path_factory.mktemp("slant") / "slant.h5"
    return record_scenario(hidden_scenario(3, "slant_range", width=40, frames=12), out)


# -- a full simulated run ------------------------------------------------------------------


def test_full_run_from_the_keyboard(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)

    async def go():
        app = RigApp(CAMERA, "fake:")
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.devices.session.connected, "the devices to connect")
            await pilot.press("2")
            assert app.tab == "experiment"
            await type_into(pilot, "stops", "0.5, 1.0, 1.5")
            await type_into(pilot, "frames", "5")
            await type_into(pilot, "output", "first.h5")
            assert "3 stops" in str(app.query_one("#plan-line").render())
            await pilot.press("ctrl+r")
            assert app.tab == "run"
            await until(pilot, lambda: app.run_pane.state.status == "done", "the run to finish")
            s = app.run_pane.state
            assert (s.stops_done, s.n_stops, s.frame, s.n_frames) == (3, 3, 5, 5)
            assert len(s.points) == 3 and s.points[0][1] < s.points[1][1] < s.points[2][1]  # sigma grows with Z
            assert len(app.query_one(SigmaPlot).points) == 3
            assert s.dropped == 0 and s.refused == 0 and s.remaining_s == 0
            assert "run complete: 3 stops recorded" in app.run_pane.status.text
            assert "disconnected" in app.devices.status.text  # the run took the devices
            assert app.results.path == "first.h5"  # ready to open on the Results screen
        with Recording(tmp_path / "first.h5") as rec:
            assert rec.stop_labels() == ["0.500m", "1.000m", "1.500m"]

    run(go())


def test_pause_abort_keeps_completed_stops_then_resume_finishes(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)

    async def go():
        app = RigApp(CAMERA, "fake:", experiment=ExperimentSettings(**SMALL), connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            live = app.run_pane.live
            # pause from the run's own thread as soon as the first stop is done: no race with the clock
            live.observers.append(lambda e: live.pause() if e.kind == "stop_done" and e.stop_index == 0 else None)
            await pilot.press("3", "r")
            await until(pilot, lambda: app.run_pane.state.status == "paused", "the pause")
            assert app.check_action("unpause", ()) and not app.check_action("pause", ())
            live.observers.clear()
            await pilot.press("a")
            await until(pilot, lambda: app.run_pane.state.status == "aborted", "the abort")
            assert "1 of 3 stops are saved" in app.run_pane.status.text
            with Recording(tmp_path / "run.h5") as rec:
                assert rec.stop_labels() == ["0.500m"]
            await pilot.press("r")  # a new run refuses to overwrite the file...
            await until(pilot, lambda: app.run_pane.state.status == "failed", "the refusal")
            assert "already exists; choose another output file or press u to resume it" in app.run_pane.status.text
            assert "--resume" not in app.run_pane.status.text  # the keys of this screen, not the flags of rig run
            await pilot.press("u")  # ...resume records the rest
            await until(pilot, lambda: app.run_pane.state.status == "done", "the resumed run")
            assert (app.run_pane.state.recorded, app.run_pane.state.skipped) == (2, 1)
        with Recording(tmp_path / "run.h5") as rec:
            assert rec.stop_labels() == ["0.500m", "1.000m", "1.500m"]

    run(go())


# -- results --------------------------------------------------------------------------------


def test_adding_the_missing_effect_lowers_the_headline_error(slant_recording, monkeypatch):
    import rig.tui.results_service as service

    diagnoses = []  # a refit is one fit of the model, not another diagnosis
    real = service.diagnose
    monkeypatch.setattr(service, "diagnose", lambda *a, **k: (diagnoses.append(1), real(*a, **k))[1])

    async def go():
        app = RigApp(connect=False, recording=str(slant_recording))
        async with app.run_test(size=(80, 24)) as pilot:
            assert app.tab == "results"
            await until(pilot, lambda: app.results.session.diagnosis is not None and not app.results.busy,
                        "the diagnosis")
            rows = app.results.session.candidate_rows()
            assert rows[0].effect == "slant_range" and rows[0].significant
            assert "slant_range" in str(app.query_one("#summary").render())
            assert [r.name for r in app.results.session.fit_rows()][:2] == ["k", "lambda"]
            effects = app.query_one(EffectList)
            assert app.focused is effects and effects.highlighted == 0
            await pilot.press("space", "f")
            await until(pilot, lambda: len(app.results.session.history) == 2 and not app.results.busy, "the refit")
            assert len(diagnoses) == 1, "f refitted by diagnosing again"
            before, after = (h.headline for h in app.results.session.history)
            assert after.error_pct < before.error_pct / 5, (before, after)
            assert app.results.session.effects == ["slant_range"]
            assert "+ slant_range" in app.query_one(HeadlineChart).plain
            assert "->" in app.results.status.text
            # nothing checked anew: f says so instead of refitting
            await pilot.press("f")
            assert "nothing changed" in app.results.status.text

    run(go())


@pytest.fixture(scope="module")
def beam_recording(tmp_path_factory) -> Path:
    """A small simulated run hiding a cos^n beam fall-off, which the catalogue lacks."""
    out = tmp_path_factory.mktemp("beam") / "beam.h5"
    return record_scenario(hidden_scenario(3, "beam_falloff", width=40, frames=30), out)


def test_not_explained_shows_its_shape_then_the_users_effect_explains_it(beam_recording):
    root = Path(__file__).resolve().parents[1]

    async def go():
        app = RigApp(connect=False, recording=str(beam_recording))
        async with app.run_test(size=(100, 40)) as pilot:
            await until(pilot, lambda: app.results.session.diagnosis is not None and not app.results.busy,
                        "the diagnosis", timeout_s=4 * TIMEOUT_S)
            summary = str(app.query_one("#summary").render())
            assert "Not explained by the catalogue" in summary and "radius" in summary, summary
            plot = app.query_one(ShapePlot)
            assert plot.display and "radius" in plot.title
            # the operator types the effects file and opens the recording again
            await type_into(pilot, "effects-path", str(root / "examples" / "beam_falloff.py"))
            await pilot.press("enter")
            await until(pilot, lambda: not app.results.busy and app.results.session.effects_file != "",
                        "the diagnosis with the user's effect", timeout_s=4 * TIMEOUT_S)
            rows = app.results.session.candidate_rows()
            assert rows[0].effect == "beam_falloff" and rows[0].significant, rows[:3]
            assert "beam_falloff" in str(app.query_one("#summary").render())
            assert not plot.display  # nothing left unexplained, so no shape
            # a broken effects file is one line in the status, and the app goes on
            await type_into(pilot, "effects-path", str(root / "missing_effects.py"))
            await pilot.press("enter")
            await until(pilot, lambda: not app.results.busy, "the error")
            assert "does not exist" in app.results.status.text

    run(go())


def test_a_bad_recording_path_is_one_line(tmp_path):
    async def go():
        app = RigApp(connect=False, recording=str(tmp_path / "missing.h5"))
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: not app.results.busy, "the attempt")
            assert "does not exist" in app.results.status.text and app.results.status.has_class("-error")

    run(go())


# -- devices --------------------------------------------------------------------------------


def test_devices_read_back_test_capture_and_home():
    async def go():
        app = RigApp(CAMERA, "fake:")
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.devices.session.connected and not app.devices.busy, "the devices")
            text = app.query_one("#camera-info").plain
            assert "Fake D435" in text and "53 x 30 px" in text and "8500 us" in text
            assert "no: press h to home" in app.query_one("#stage-info").plain
            await pilot.press("t")
            await until(pilot, lambda: not app.devices.busy, "the test capture")
            capture = app.query_one("#capture-info").plain
            assert "fill rate" in capture and "100.0 %" in capture and "1.00" in capture
            await pilot.press("h")
            await until(pilot, lambda: not app.devices.busy, "homing")
            assert "yes" in app.query_one("#stage-info").plain
            await pilot.press("x")
            await until(pilot, lambda: not app.devices.session.connected and not app.devices.busy, "disconnect")
            assert app.check_action("test_capture", ()) is None  # shown, greyed out

    run(go())


@pytest.mark.parametrize("camera, expect", [
    ("nosuchcam:", "unknown camera kind 'nosuchcam'"),
    ("fake:width", "is not KEY=VALUE"),
])
def test_a_device_string_that_fails_says_so_in_one_line(camera, expect):
    async def go():
        app = RigApp(camera, "fake:")
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: not app.devices.busy, "the connection attempt")
            status = app.devices.status
            assert expect in status.text and "fake:" in status.text and "\n" not in status.text
            assert status.has_class("-error") and not app.devices.session.connected

    run(go())


# -- experiment files -----------------------------------------------------------------------


def test_experiment_saved_is_what_rig_run_loads_and_loads_back(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)

    async def go():
        app = RigApp("fake:width=53", "none:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("2")
            await type_into(pilot, "toml-path", "e/t.toml")
            app.query_one("#protocol").value = "tilted"
            await pilot.pause()
            assert not app.query_one("#row-stops").display and app.query_one("#row-tilt-deg").display
            await type_into(pilot, "tilt-deg", "25")
            await type_into(pilot, "frames", "40")
            await type_into(pilot, "output", "o/t.h5")
            await pilot.press("ctrl+s")
            assert "saved" in app.experiment.status.text
            exp = load_experiment(tmp_path / "e/t.toml")  # what `rig run e/t.toml` reads
            assert exp.plan.name == "tilted" and exp.plan.params["tilt_deg"] == 25 and exp.plan.params["frames_per_stop"] == 40
            assert (exp.camera, exp.stage) == ("fake:width=53", "none:")
            assert exp.output.resolve() == tmp_path / "o" / "t.h5"  # the operator typed it relative to here
            await type_into(pilot, "frames", "1")  # refused by the protocol: the plan line says why
            assert "at least 2 frames" in str(app.query_one("#plan-line").render())
            app.devices.set_strings("fake:", "fake:")
            await pilot.press("ctrl+l")
            assert app.query_one("#frames", Input).value == "40"
            assert app.query_one("#output", Input).value == "o/t.h5"
            assert (app.devices.camera_string, app.devices.stage_string) == ("fake:width=53", "none:")
            await type_into(pilot, "toml-path", "no.toml")
            await pilot.press("ctrl+l")
            assert "does not exist" in app.experiment.status.text

    run(go())


def test_example_experiment_file_loads(tmp_path):
    s, camera, stage = ExperimentSettings.load(ROOT / "examples" / "perpendicular-active.toml")
    assert s.protocol == "perpendicular" and len(s.values["stops_m"]) == 11 and s.values["frames_per_stop"] == 300
    assert s.extra == {}  # settle_s = 1.0 is the default
    again = tmp_path / "again.toml"
    s.save(again, camera, stage)
    assert load_experiment(again).plan.params == load_experiment(ROOT / "examples" / "perpendicular-active.toml").plan.params


# -- snapshots at 80x24 ---------------------------------------------------------------------
# The snapshots pin the layout. Numbers that come from the fake camera's physics or from the
# analysis are canned here (the tests above check the real ones), so that a change to the
# physics or the models does not look like a change of the screens.

CANNED_STATE = RunState(
    status="done", output="run.h5", stop="1.500m", stop_index=4, n_stops=5, stops_done=5, frame=300, n_frames=300,
    fill_rate=0.998, centre_sigma_m=0.00712, centre_mean_m=1.5003,
    points=[(0.5003, 0.000264), (0.7502, 0.00089), (1.0001, 0.00211), (1.2502, 0.00412), (1.5003, 0.00712)],
    elapsed_s=83.0, remaining_s=0.0, dropped=2, refused=1, recorded=5, skipped=0,
    message="run complete: 5 stops recorded in run.h5")


def _headline(error_pct: float, noise_pct: float, within: bool) -> Headline:
    return Headline(error_pct, noise_pct, 30.0 if within else 6026.0, 32, 0.5 if within else 0.0, 33)


class CannedResults(ResultsSession):
    """What a slant-range recording's Results screen shows after adding slant_range, fixed."""

    def __init__(self) -> None:
        super().__init__()
        self.path = Path("slant.h5")
        self.diagnosis = object()  # type: ignore[assignment]
        self.history = [HistoryEntry("active", "active", _headline(11.36, 1.48, False)),
                        HistoryEntry("+ slant_range", "active+slant_range", _headline(1.10, 1.48, True))]

    @property
    def effects(self) -> list[str]:
        return ["slant_range"]

    def fit_rows(self) -> list[FitRow]:
        return [FitRow("k", "0.0020179", "4.3e-06", "m^(1-lambda)"), FitRow("lambda", "3", "fixed", ""),
                FitRow("power law: k", "0.0024267", "6.6e-06", ""), FitRow("power law: lambda", "2.9946", "0.0039", "")]

    def bin_rows(self) -> list[BinRow]:
        radius = [BinRow("radius", f"rho {a:.2f}-{a + 0.22:.2f}", r, 0.01, abs(r - 1) > 0.012)
                  for a, r in zip((0.0, 0.22, 0.45, 0.67, 0.89), (1.019, 1.002, 1.002, 0.985, 0.998))]
        ranges = [BinRow("range", f"{z - 0.125:.3f}-{z + 0.125:.3f} m", 1.0 + 0.004 * ((i % 3) - 1), 0.014, False)
                  for i, z in enumerate(0.5 + 0.25 * np.arange(11))]
        return radius + ranges

    def candidate_rows(self) -> list[CandidateRow]:
        rows = [CandidateRow("slant_range", None, False, True)]
        return rows + [CandidateRow(e, v, False, False) for e, v in (
            ("quantization", -0.3), ("ambient", 0.0), ("noise_floor", 8.2), ("censoring", 9.0), ("read_noise", 9.2),
            ("drift", 18.1), ("outliers", 18.4), ("incidence", 668.8))]

    def shape(self):
        return None  # everything explained: no shape to draw

    def summary(self) -> str:
        return ("Nothing significant is missing from active+slant_range: no effect lowers BIC by more than 10; "
                "the headline error is 1.10 % (noise alone: 1.48 %; within noise, chi2 30/32).")



def test_a_headline_where_nothing_was_judged_is_said_not_drawn():
    """issue 51: a 2x1-px recording's headline error is nan (no bin holds enough pixels to compare sigma in); the
    chart drew its bar with int(nan), and the Results screen said "cannot convert float NaN to integer"."""
    nothing = Headline(float("nan"), float("nan"), 0.0, 0, 1.0, 0)
    chart = HeadlineChart()
    chart.show_history([HistoryEntry("active", "active", nothing), HistoryEntry("+ drift", "active+drift", nothing)])
    assert chart.plain == "active: not judged\n+ drift: not judged"
    chart.show_history([HistoryEntry("active", "active", _headline(11.36, 1.48, False)),
                        HistoryEntry("+ slant_range", "active+slant_range", _headline(1.10, 1.48, True))])
    assert chart.plain == "active: 11.36 %\n+ slant_range: 1.10 % ok"

def test_snapshot_devices(snap_compare):
    from rig.tui.devices_pane import DevicesPane
    from rig.tui.devices_service import TestCapture

    async def before(pilot):
        app = pilot.app
        await until(pilot, lambda: app.devices.session.connected and not app.devices.busy, "the devices")
        report = app.devices.session.report()
        app.devices.post_message(DevicesPane.Done("capture", report=report, capture=TestCapture(10, 0.9987, 1.0002, 0.002094)))
        await pilot.pause()

    assert snap_compare(RigApp(CAMERA, "fake:"), terminal_size=(80, 24), run_before=before)


def test_snapshot_experiment(snap_compare):
    assert snap_compare(RigApp(CAMERA, "fake:", connect=False), press=["2", "escape"], terminal_size=(80, 24))


def test_snapshot_run_done(snap_compare):
    from rig.tui.run_pane import RunPane

    async def before(pilot):
        await pilot.press("3")
        pilot.app.run_pane.post_message(RunPane.Finished(CANNED_STATE))
        await pilot.pause()

    assert snap_compare(RigApp(CAMERA, "fake:", connect=False), terminal_size=(80, 24), run_before=before)


def test_snapshot_results_after_adding_an_effect(snap_compare):
    from rig.tui.results_pane import ResultsPane

    async def before(pilot):
        app = pilot.app
        await pilot.press("4")
        app.results.session = CannedResults()
        app.results.set_path("slant.h5")
        app.results.post_message(ResultsPane.Done("refit"))
        await pilot.pause()

    assert snap_compare(RigApp(connect=False), terminal_size=(80, 24), run_before=before)


# -- a real terminal ------------------------------------------------------------------------


@pytest.mark.skipif(shutil.which("tmux") is None, reason="needs tmux (apt-get install tmux)")
def test_runs_an_experiment_in_a_real_terminal(tmp_path):
    (tmp_path / "experiment.toml").write_text(
        "[experiment]\nprotocol = \"perpendicular\"\n"
        f"camera = \"{CAMERA}\"\nstage = \"fake:\"\noutput = \"tmux-run.h5\"\n\n"
        "[parameters]\nstops_m = [0.5, 1.0]\nframes_per_stop = 5\n")
    tmux = ["tmux", "-S", str(tmp_path / "tmux.sock"), "-f", "/dev/null"]  # a server of our own, gone with tmp_path
    env = f"PYTHONPATH={shlex.quote(str(ROOT))} TERM=xterm-256color"
    command = f"cd {shlex.quote(str(tmp_path))} && {env} {shlex.quote(sys.executable)} -m rig.tui; echo TUI-EXIT=$?; sleep 60"

    def screen() -> str:
        return subprocess.run([*tmux, "capture-pane", "-p", "-t", "rig"], capture_output=True, text=True).stdout

    def wait_for(text: str) -> str:
        deadline = time.monotonic() + TIMEOUT_S
        while time.monotonic() < deadline:
            shown = screen()
            if text in shown:
                return shown
            time.sleep(0.1)
        raise AssertionError(f"{text!r} never appeared; the screen shows:\n{screen()}")

    def keys(*k: str) -> None:
        subprocess.run([*tmux, "send-keys", "-t", "rig", *k], check=True)

    subprocess.run([*tmux, "new-session", "-d", "-s", "rig", "-x", "80", "-y", "24", command], check=True)
    try:
        wait_for("connected: fake:")
        keys("2")  # Experiment: the file field has the focus and says experiment.toml
        wait_for("Experiment file")
        keys("C-l")  # load it
        wait_for("loaded experiment.toml")
        keys("C-r")  # run it
        shown = wait_for("run complete: 2 stops recorded in tmux-run.h5")
        assert "stops 2/2" in shown
        with Recording(tmp_path / "tmux-run.h5") as rec:
            assert rec.stop_labels() == ["0.500m", "1.000m"]
        keys("C-q")
        wait_for("TUI-EXIT=0")
    finally:
        subprocess.run([*tmux, "kill-server"], capture_output=True)


# -- the pieces without a screen --------------------------------------------------------------


def test_stops_accept_a_list_or_a_range():
    from protocols.perpendicular import PERPENDICULAR

    stops = PERPENDICULAR.param("stops_m")  # the one parser: rig run --stops and the form's field
    assert stops.parse("0.5, 1.0,1.5") == [0.5, 1.0, 1.5]
    assert stops.parse("0.5:3.0:0.25") == [0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0]
    with pytest.raises(ValueError, match="START:STOP:STEP"):
        stops.parse("0.5:abc")


def test_frame_tap_counts_dropped_and_refused_frames_and_passes_them_on():

    from drivers.camera import CameraInfo, CameraSettings, DepthCamera, Frame, FrameMetadata, Intrinsics
    from rig.tui.live import FrameTap

    asked = CameraSettings(projector_on=True, exposure_us=8500, gain=16)

    class Stub(DepthCamera):
        name = "stub"

        def open(self): ...
        def close(self): ...
        def info(self):
            return CameraInfo("stub", "1", "0", Intrinsics(20, 10, 10, 10, 9.5, 4.5), 0.05, 0.001)
        def configure(self, settings):
            return settings
        def read_settings(self):
            return asked
        def frames(self, n, *, ir=False):
            for number, gain in ((0, 16), (1, 16), (4, 16), (5, 99)):  # frames 2 and 3 lost; frame 5 at the wrong gain
                yield Frame(np.full((10, 20), 1000, np.uint16), number, 0.0, FrameMetadata(8500, gain, True))

    tap = FrameTap(Stub())
    tap.configure(asked)
    tap.begin_stop()
    frames = list(tap.frames(4))
    assert [f.frame_number for f in frames] == [0, 1, 4, 5]
    assert (tap.dropped, tap.refused, tap.live.frames) == (2, 1, 3)
    assert tap.live.fill_rate == 1.0 and tap.live.centre() == (1.0, 0.0)
