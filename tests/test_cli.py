"""The `rig` command line: run, fit, demo, experiment files, and its one-line errors."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from rig.cli import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_console_script_is_installed_and_runs():
    rig = Path(sys.executable).parent / "rig"
    assert rig.exists(), "install rig (python3 dev.py test does) so the console script exists"
    out = subprocess.run([str(rig), "--help"], capture_output=True, text=True, check=True).stdout
    for cmd in ("demo", "run", "fit"):
        assert cmd in out


def test_the_rig_program_sets_the_collector_and_leaves_it_frozen_also_after_an_error(monkeypatch, capsys):
    """`rig.cli.entry` (what the console script runs) collects the first generation every YOUNG_THRESHOLD objects
    and freezes every object when `main` ends, however it ends (argparse's exit here), so the interpreter's shutdown
    collections pass over none (rig/runtime/process_gc.py)."""
    import gc

    from rig.cli import entry
    from rig.runtime.process_gc import YOUNG_THRESHOLD

    monkeypatch.setattr(sys, "argv", ["rig", "fit"])
    before = gc.get_threshold()
    gc.set_threshold(700, *before[1:])  # Python's own, which the test session has changed
    gc.unfreeze()
    try:
        with pytest.raises(SystemExit):
            entry()
        assert gc.get_freeze_count() > 1000 and gc.get_threshold()[0] == YOUNG_THRESHOLD
    finally:
        gc.unfreeze()
        gc.set_threshold(*before)
    assert "rig fit: error: the following arguments are required: recording" in capsys.readouterr().err


@pytest.mark.slow
def test_run_then_fit(tmp_path, capsys):
    out = tmp_path / "a.h5"
    assert main(["run", "--protocol", "perpendicular", "--frames", "20", "--camera", "fake:width=48,depth_unit_mm=0.05",
                 "-o", str(out)]) == 0
    assert out.exists()
    capsys.readouterr()
    assert main(["fit", str(out), "--plot", str(tmp_path / "p.png")]) == 0
    text = capsys.readouterr().out
    assert "perpendicular, projector on" in text and "lambda = " in text
    assert (tmp_path / "p.png").stat().st_size > 10_000
    assert main(["fit", str(out), "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)["fits"][0]
    assert abs(fit["values"]["lambda"] - 3.0) < 3 * fit["errors"]["lambda"]
    assert fit["n_samples"] == 11 * 20 * 48 * 27


def test_experiment_file_with_overrides(tmp_path, capsys):
    toml = tmp_path / "e.toml"
    toml.write_text((ROOT / "examples" / "perpendicular-active.toml").read_text()
                    .replace('output = "perpendicular-active.h5"', 'output = "out/active.h5"'))
    assert main(["run", str(toml), "--frames", "4", "--stops", "0.5,1.0", "--camera", "fake:width=16"]) == 0
    from protocols.recording import Recording

    with Recording(tmp_path / "out" / "active.h5") as rec:
        assert rec.stop_labels() == ["0.500m", "1.000m"]
        assert rec.protocol_params["frames_per_stop"] == 4


@pytest.mark.parametrize("args,message", [
    (["run", "--protocol", "perpendicular", "--camera", "nosuch:", "-o", "{tmp}/x.h5"], "unknown camera kind 'nosuch'"),
    (["run", "--protocol", "perpendicular", "--camera", "fake:widht=3", "-o", "{tmp}/x.h5"], "unknown option 'widht' in 'fake:widht=3'; did you mean width?"),
    (["run", "--protocol", "perpendicular"], "no output file; pass -o FILE.h5"),
    (["run", "--protocol", "perpendicular", "--frames", "1", "-o", "{tmp}/x.h5"], "at least 2 frames"),
    (["run", "{tmp}/missing.toml"], "does not exist; see examples/*.toml"),
    (["fit", "{tmp}/missing.h5"], "does not exist"),
])
def test_bad_input_gives_one_line_error(tmp_path, capsys, args, message):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rig: error: ") and message in err
    assert "\n" not in err
    assert not (tmp_path / "x.h5").exists()


def test_experiment_file_errors_name_the_key(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[experiment]\nprotocol = "perpendicular"\n[parameters]\nframe = 3\n')
    assert main(["run", str(bad), "-o", str(tmp_path / "y.h5")]) == 2
    err = capsys.readouterr().err
    assert "perpendicular has no parameter(s) ['frame']" in err


@pytest.mark.slow
def test_demo_small(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--frames", "10", "--width", "64"]) == 0
    text = capsys.readouterr().out
    assert "perpendicular active" in text and "perpendicular passive" in text
    # accuracy beside precision: the simulated camera is calibrated, so no bias is found
    assert text.count("accuracy against the stage measured distance: within") == 2, text
    assert text.count("no calibration bias beyond noise") == 2, text
    assert (tmp_path / "sigma-vs-range.png").stat().st_size > 20_000
    assert (tmp_path / "perpendicular-active.h5").exists() and (tmp_path / "perpendicular-passive.h5").exists()


def test_saved_experiment_file_loads_back_to_the_same_plan(tmp_path, monkeypatch):
    from protocols.experiment_file import load_experiment, save_experiment

    monkeypatch.chdir(tmp_path)
    params = {"stops_m": [0.5, 1.25], "frames_per_stop": 7, "projector_on": False, "exposure_us": 3300.0, "gain": 32.0}
    path = save_experiment("sub/e.toml", "perpendicular", params, "fake:width=16,effects=noise_floor", "none:", "out/r.h5")
    exp = load_experiment(path)
    assert exp.plan.name == "perpendicular"
    assert {k: exp.plan.params[k] for k in params} == params
    assert exp.camera == "fake:width=16,effects=noise_floor" and exp.stage == "none:"
    assert exp.output.resolve() == (tmp_path / "out" / "r.h5").resolve()
    assert 'output = "../out/r.h5"' in path.read_text()  # relative to the file, so the folder can move
    absolute = save_experiment("e2.toml", "tilted", {"frames": 3}, "fake:", "none:", tmp_path / "t.h5")
    assert load_experiment(absolute).output == tmp_path / "t.h5"
