"""A protocol is described once (protocols/protocol_spec.py) and everything else is made from the catalogue.

`mine`, defined in this file and registered at run time, runs from `rig run --protocol mine`, from an
experiment file and through the TUI's form, without a line of rig changed. The frames parameter has one name
in every protocol, and recordings and experiment files that use the old one still work. Papercuts of issue 27:
`rig run --stops` takes the range the TUI takes; Ctrl-C during `rig run` exits 130, as `rig --help` says.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import h5py
import pytest

from protocols.catalogue import (PROTOCOLS, catalogue_params, current_params, protocol_names, protocol_spec,
                                 register_protocol, unregister_protocol)
from protocols.experiment_file import load_experiment
from protocols.plan import Configure, Home, Move, Settle
from protocols.plan_values import ProtocolParam, distance_m, whole_between
from protocols.protocol_spec import FRAMES_PER_STOP, ProtocolError, ProtocolSpec
from protocols.recording import Recording
from rig.cli import main

RIG = Path(sys.executable).parent / "rig"
CAMERA = "fake:width=16,height=9"


def repeat_steps(settings, *, distance_m, repeats, frames_per_stop):
    """One distance, captured `repeats` times (a drift check)."""
    yield Home()
    yield Configure(settings.camera())
    yield Move(distance_m)
    for i in range(repeats):
        yield Settle(settings.settle_s)
        yield settings.capture(f"repeat-{i + 1}", frames_per_stop)


MINE = ProtocolSpec(
    "mine", repeat_steps,
    params=(ProtocolParam("distance_m", float, 1.0, "m", "Distance [m]", "camera to wall", distance_m),
            ProtocolParam("repeats", int, 2, "", "Repeats", "captures at the one distance", whole_between(1, 50))),
    stops_param="distance_m", frames_per_stop=3, default_stage="fake:", summary="the same stop, again and again")


@pytest.fixture
def mine():
    register_protocol(MINE, "tests/test_protocol_catalogue.py")
    yield MINE
    unregister_protocol(MINE.name)


def stops_of(path: Path) -> tuple[str, list[str], dict]:
    with Recording(path) as rec:
        return rec.protocol, rec.stop_labels(), rec.protocol_params


# -- a new protocol, everywhere --------------------------------------------------------------------------


def test_a_protocol_registered_at_run_time_runs_from_rig_run(mine, tmp_path, capsys):
    out = tmp_path / "mine.h5"
    assert main(["-q", "run", "--protocol", "mine", "--repeats", "3", "--distance-m", "1.5", "--frames", "4",
                 "--camera", CAMERA, "--stage", "fake:", "-o", str(out)]) == 0, capsys.readouterr().err
    protocol, labels, params = stops_of(out)
    assert (protocol, labels) == ("mine", ["repeat-1", "repeat-2", "repeat-3"])
    assert params["repeats"] == 3 and params["distance_m"] == 1.5 and params[FRAMES_PER_STOP] == 4
    assert main(["run", "--protocol", "mine", "--repeats", "0", "-o", str(tmp_path / "no.h5")]) == 2
    assert "mine: repeats = 0 is outside 1 to 50" in capsys.readouterr().err
    assert main(["run", "--protocol", "mine", "--stops", "1,2", "-o", str(tmp_path / "no.h5")]) == 2
    assert "--stops is not a parameter of mine; mine takes --distance-m, --repeats, --frames" in capsys.readouterr().err


def test_without_registering_it_rig_run_does_not_know_it(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["run", "--protocol", "mine", "-o", str(tmp_path / "x.h5")])
    assert "invalid choice: 'mine'" in capsys.readouterr().err


def test_the_help_lists_its_options(mine, capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = capsys.readouterr().out
    assert "{perpendicular,tilted,mine}" in text and "--repeats N" in text and "captures at the one distance" in text
    assert "[distance_m; tilted, mine; default 0.8 (tilted), 1 (mine)]" in " ".join(text.split())


def test_a_protocol_registered_at_run_time_runs_from_an_experiment_file(mine, tmp_path, capsys):
    toml = tmp_path / "mine.toml"
    toml.write_text(f'[experiment]\nprotocol = "mine"\ncamera = "{CAMERA}"\noutput = "m.h5"\n\n'
                    '[parameters]\ndistance_m = 0.9\nrepeats = 2\nframes = 3  # the old name of frames_per_stop\n')
    exp = load_experiment(toml)
    assert exp.stage == "fake:" and exp.plan.params[FRAMES_PER_STOP] == 3 and "frames" not in exp.plan.params
    assert main(["-q", "run", str(toml), "--repeats", "3"]) == 0, capsys.readouterr().err
    protocol, labels, params = stops_of(tmp_path / "m.h5")
    assert protocol == "mine" and len(labels) == 3 and params["distance_m"] == 0.9


def test_a_protocol_registered_at_run_time_is_on_the_tuis_form(mine, tmp_path, monkeypatch):
    from rig.tui.form import ExperimentSettings, field_label, field_problem, form_fields

    monkeypatch.chdir(tmp_path)
    fields = {f.id: f for f in form_fields()}
    assert fields["repeats"].protocols == ("mine",) and fields["repeats"].kind == "integer"
    assert fields["distance-m"].protocols == ("tilted", "mine") and "mine" in fields["frames"].protocols
    assert field_label("mine", "repeats") == "Repeats"
    assert field_problem("mine", "repeats", "0") == "Repeats: repeats = 0 is outside 1 to 50"
    assert field_problem("mine", "repeats", "2") is None and field_problem("perpendicular", "repeats", "x") is None
    s = ExperimentSettings(protocol="mine", values={"repeats": 3, FRAMES_PER_STOP: 4}, output="m.h5")
    assert s.describe() == "mine: 3 stops at 1.00 m x 4 frames = 12 frames, projector on; repeats 3"
    assert s.device_geometry() == {}
    s.save("mine.toml", CAMERA, "fake:")
    again, camera, stage = ExperimentSettings.load("mine.toml")
    assert (again.protocol, again.values["repeats"], camera) == ("mine", 3, CAMERA)
    assert load_experiment("mine.toml").plan.params == s.plan().params


@pytest.mark.slow
def test_the_tui_runs_a_protocol_registered_at_run_time(mine, tmp_path, monkeypatch):
    pytest.importorskip("textual", reason="rig tui needs textual (pip install -e .[test])")
    from textual.widgets import Label, Select

    from rig.tui.app import RigApp
    from tui_pilot import run, type_into, until

    monkeypatch.chdir(tmp_path)

    async def go():
        app = RigApp(CAMERA, "fake:", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await pilot.press("2")
            assert ("mine", "mine") in app.query_one("#protocol", Select)._options
            app.query_one("#protocol", Select).value = "mine"
            await pilot.pause()
            assert app.query_one("#row-repeats").display and not app.query_one("#row-stops").display
            assert str(app.query_one("#row-repeats", expect_type=None).query_one(Label).render()) == "Repeats"
            await type_into(pilot, "repeats", "3")
            await type_into(pilot, "distance-m", "1.5")  # the field tilted has too
            await type_into(pilot, "frames", "4")
            await type_into(pilot, "output", "tui-mine.h5")
            assert "mine: 3 stops at 1.50 m x 4 frames" in str(app.query_one("#plan-line").render())
            await pilot.press("ctrl+r")
            await until(pilot, lambda: app.run_pane.state.status in ("done", "failed"), "the run to end")
            assert app.run_pane.state.status == "done", app.run_pane.status.text
        protocol, labels, params = stops_of(tmp_path / "tui-mine.h5")
        assert protocol == "mine" and labels == ["repeat-1", "repeat-2", "repeat-3"] and params[FRAMES_PER_STOP] == 4

    run(go())


# -- the catalogue keeps one meaning per name --------------------------------------------------------------


def test_a_spec_that_cannot_work_is_refused_when_registered(mine):
    def spec(**kw):
        return ProtocolSpec(**{"name": "other", "steps": repeat_steps, "params": MINE.params,
                               "stops_param": "distance_m", **kw})

    cases = [
        (spec(name="mine"), "the name is taken"),
        (spec(name="two words"), "must be letters, digits"),
        (spec(params=(ProtocolParam("distance_m", list, [1.0]), MINE.params[1])), "parameter distance_m is list (--distance-m) here but float (--distance-m) in tilted"),
        (spec(params=(*MINE.params, ProtocolParam("frames", int, 3))), "old name(s) ['frames'] are parameters now"),
        (spec(params=(*MINE.params, ProtocolParam("gain", float, 3.0))), "every protocol takes already"),
        (spec(params=(*MINE.params, ProtocolParam("n", int, 3, option="--repeats"))), "option --repeats is repeats's"),
        (spec(stops_param="stops_m"), "stops_param 'stops_m' is not one of its parameters"),
        (spec(frames_per_stop=1), "its defaults are refused (other: frames_per_stop = 1 is outside 2 to"),
        (spec(wall={"height_m": "distance_m"}), "wall 'height_m'"),
    ]
    for bad, why in cases:
        with pytest.raises(ProtocolError, match="cannot be registered") as e:
            register_protocol(bad)
        assert why in str(e.value) and "\n" not in str(e.value), (why, str(e.value))
    assert protocol_names() == ["perpendicular", "tilted", "mine"]


def test_an_installed_plugin_adds_a_protocol_and_a_broken_one_is_named(monkeypatch):
    import protocols.catalogue as catalogue

    class EntryPoint:
        def __init__(self, name, value, load):
            self.name, self.value, self.load = name, value, load

    def broken():
        raise ImportError("no module named mine_protocols")

    eps = [EntryPoint("mine", "mine_protocols:MINE", lambda: MINE), EntryPoint("bad", "bad:SPEC", broken)]
    monkeypatch.setattr(catalogue, "entry_points", lambda group: eps if group == catalogue.ENTRY_POINT_GROUP else [])
    monkeypatch.setattr(catalogue, "_plugins_loaded", False)
    monkeypatch.setattr(catalogue, "_plugin_problems", [])
    try:
        assert "mine" in PROTOCOLS and PROTOCOLS["mine"](repeats=4).params["repeats"] == 4
        with pytest.raises(ProtocolError, match=r"unknown protocol 'nosuch'; .*the protocol plugin bad \(bad:SPEC\) "
                                                r"failed to load \(ImportError: no module named mine_protocols\)"):
            protocol_spec("nosuch")
    finally:
        unregister_protocol("mine")


# -- one name for the frames ------------------------------------------------------------------------


def test_every_protocol_names_its_frames_frames_per_stop():
    assert all(FRAMES_PER_STOP in spec.names() for spec in map(protocol_spec, protocol_names()))
    assert [s.name for s, _ in catalogue_params()[FRAMES_PER_STOP]] == protocol_names()
    assert current_params({"frames": 600, "tilt_deg": 31.0}) == {"tilt_deg": 31.0, FRAMES_PER_STOP: 600}


def test_an_old_tilted_experiment_file_still_loads(tmp_path):
    toml = tmp_path / "old.toml"
    toml.write_text('[experiment]\nprotocol = "tilted"\n[parameters]\ntilt_deg = 20.0\nframes = 40\n')
    plan = load_experiment(toml).plan
    assert plan.params[FRAMES_PER_STOP] == 40 and plan.captures()[0].n_frames == 40
    toml.write_text('[experiment]\nprotocol = "tilted"\n[parameters]\nframes = 40\nframes_per_stop = 40\n')
    with pytest.raises(ValueError, match="tilted: frames is the old name of frames_per_stop; give frames_per_stop only"):
        load_experiment(toml)


def test_a_recording_made_under_the_old_name_resumes(tmp_path, capsys):
    """A tilted recording made before the rename stores `frames`; --resume compares it with frames_per_stop."""
    out = tmp_path / "old.h5"
    run = ["run", "--protocol", "tilted", "--frames", "3", "--camera", CAMERA, "-o", str(out)]
    assert main(["-q", *run]) == 0
    with h5py.File(out, "a") as f:
        params = json.loads(f.attrs["protocol_params"])
        params["frames"] = params.pop(FRAMES_PER_STOP)
        f.attrs["protocol_params"] = json.dumps(params)
    capsys.readouterr()
    assert main([*run, "--resume"]) == 0, capsys.readouterr().err
    captured = capsys.readouterr()
    assert "recorded 0 stops (1 already there)" in captured.out and "changed plan" not in captured.err
    assert main([*run[:4], "4", *run[5:], "--resume"]) == 2  # a real change is still refused
    assert "plan frames_per_stop 3 in the file, 4 now" in capsys.readouterr().err


# -- papercuts -----------------------------------------------------------------------------------------


def test_rig_run_takes_a_range_of_stops_as_the_tui_does(tmp_path, capsys):
    out = tmp_path / "range.h5"
    assert main(["-q", "run", "--protocol", "perpendicular", "--stops", "0.5:1.0:0.25", "--frames", "2",
                 "--camera", CAMERA, "-o", str(out)]) == 0, capsys.readouterr().err
    assert stops_of(out)[1] == ["0.500m", "0.750m", "1.000m"]
    assert main(["run", "--protocol", "perpendicular", "--stops", "0.5:x", "-o", str(tmp_path / "x.h5")]) == 2
    assert "--stops '0.5:x': write distances in m separated by commas (0.5, 1.0, 1.5) or a range START:STOP:STEP" \
        in capsys.readouterr().err


@pytest.mark.slow
def test_ctrl_c_during_rig_run_exits_130_as_the_help_says(tmp_path):
    assert "130 interrupted" in " ".join(subprocess.run([str(RIG), "--help"], capture_output=True, text=True).stdout.split())
    out = tmp_path / "r.h5"
    proc = subprocess.Popen([str(RIG), "run", "--protocol", "perpendicular", "--camera", "fake:width=32",
                             "--frames", "40", "-o", str(out)], stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # as a terminal's Ctrl-C
    try:
        for line in proc.stderr:  # the progress: interrupt once the first stop is done
            if "done:" in line:
                proc.send_signal(signal.SIGINT)
                break
        rest = proc.stderr.read()
        assert proc.wait(timeout=60) == 130, rest
    finally:
        proc.kill()
    assert "rig: error: run interrupted;" in rest and "Traceback" not in rest, rest  # what was saved, in words
