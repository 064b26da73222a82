"""A new user's mistakes with rig fit, compare, diagnose and simulate: each is one line naming what to change, and
nothing is silently wrong (issue 27's papercuts of the analysis commands)."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from drivers.folder import MANIFEST_NAME
from protocols.folder_import import import_folder
from protocols.recording import Recording
from rig.cli import main
from rig.models import Catalogue, ModelData, Param, TermEffect, noise_floor

#: an illumination factor that does what a larger k does: degenerate with k
DEGENERATE = '''
from rig.models import Param, TermEffect, register

@register
class Gain(TermEffect):
    """A constant factor on the shot-noise variance: the same as a larger k."""

    name = "gain"
    stage = "illumination"
    params = (Param("gain", 1.0, 0.1, 10.0, "1", "a constant factor on the light"),)
    signature = "the error is larger everywhere by the same factor"

    def term(self, c, gain):
        return gain + 0 * c.z_m
'''


def one_line(capsys, *needles: str) -> str:
    out = capsys.readouterr()
    err = out.err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err and not out.out, (out.out, err)
    for needle in needles:
        assert needle in err, err
    return err


@pytest.fixture(scope="module")
def imported(tmp_path_factory) -> Path:
    """A live run of three stops (0.75, 1.25, 2.0 m; 24x14 px, 6 frames), its frames written as a folder (one .npy a
    stop, named stop_a, stop_b, stop_c) and imported with rig import."""
    from simrig import record_perpendicular

    root = tmp_path_factory.mktemp("imp")
    live, _, _ = record_perpendicular(root / "live.h5", width=24, frames=6, stops_m=[0.75, 1.25, 2.0], keep_raw=True)
    folder, distances = root / "frames", {}
    with h5py.File(live, "r") as f:
        for i, label in enumerate(sorted(f["stops"], key=lambda k: f["stops"][k].attrs["index"])):
            name = f"stop_{'abc'[i]}"
            distances[name] = float(f["stops"][label].attrs["commanded_position_m"])
            (folder / name).mkdir(parents=True)
            np.save(folder / name / "depth.npy", f["stops"][label]["raw_depth"][:])
    with Recording(live) as rec:
        c = rec.calibration
    lines = [f"fx = {c.fx!r}", f"fy = {c.fy!r}", f"cx = {c.cx!r}", f"cy = {c.cy!r}", f"baseline_m = {c.baseline_m!r}",
             f"depth_unit_m = {c.depth_scale_m!r}", "projector_on = true", "exposure_us = 8500.0", "gain = 16.0",
             "[stop_distance_m]", *(f'"{k}" = {v!r}' for k, v in distances.items())]
    (folder / MANIFEST_NAME).write_text("\n".join(lines) + "\n")
    return import_folder(folder, root / "imported.h5")


def test_fit_of_an_import_does_not_say_its_stops_are_missing(imported, capsys):
    with Recording(imported) as rec:
        assert rec.protocol == "import" and len(rec.stop_labels()) == 3
    for command in (["fit", str(imported)], ["fit", str(imported), "--model", "active", "--no-held-out"]):
        assert main(command) == 0
        out = capsys.readouterr().out
        assert "planned stops" not in out and "--resume" not in out, out


@pytest.mark.slow
def test_a_plot_file_matplotlib_cannot_write_is_refused_before_the_fit(small_recording, tmp_path, capsys):
    assert main(["fit", str(small_recording), "--plot", str(tmp_path / "fit.txt")]) == 2
    one_line(capsys, "--plot", "fit.txt", ".txt", ".png", ".pdf", ".svg")
    assert not (tmp_path / "fit.txt").exists()
    assert main(["fit", str(small_recording), "--plot", str(tmp_path / "fit")]) == 2
    one_line(capsys, "no suffix", ".png")
    assert main(["fit", str(small_recording), "--plot", str(tmp_path / "fit.svg")]) == 0
    assert (tmp_path / "fit.svg").read_text().lstrip().startswith("<?xml")


@pytest.mark.parametrize("text,needle", [
    ("active+", "a '+' with no effect after it"),
    ("active++noise_floor", "a '+' with no effect after it"),
    ("active+noise_floor+noise_floor", "names noise_floor twice"),
])
def test_a_model_with_a_dangling_or_repeated_effect_is_refused(small_recording, capsys, text, needle):
    assert main(["fit", str(small_recording), "--model", text, "--no-held-out"]) == 2
    one_line(capsys, repr(text), needle)


def test_two_effects_of_one_name_do_not_silently_compose():
    class OtherFloor(TermEffect):
        """Another noise floor."""

        name = "noise_floor"
        stage = "disparity"
        params = (Param("sigma_px", 0.01, 0.0, 5.0, "px", "a floor"),)
        signature = "short range"

        def term(self, c, sigma_px):
            return sigma_px**2 + 0 * c.z_m

    other_floor = OtherFloor()

    from rig.models import active

    assert (active + noise_floor) + noise_floor == active + noise_floor  # the same effect again changes nothing
    with pytest.raises(ValueError, match="has an effect noise_floor already .*NoiseFloor.*OtherFloor"):
        (active + noise_floor) + other_floor


def test_active_on_a_passive_recording_says_so_naming_passive(tmp_path, capsys):
    from simrig import record_perpendicular

    path, _, _ = record_perpendicular(tmp_path / "off.h5", width=24, frames=6, projector_on=False,
                                      stops_m=[0.75, 1.25, 2.0])
    assert main(["fit", str(path), "--model", "active", "--no-held-out"]) == 0
    out = capsys.readouterr().out
    note = next(line for line in out.splitlines() if line.startswith("note: "))
    assert "projector off" in note and "passive" in note and "--model passive" in note, out
    assert main(["fit", str(path), "--model", "active", "--no-held-out", "--json"]) == 0
    assert any("passive" in n for n in json.loads(capsys.readouterr().out)["notes"])
    assert main(["fit", str(path), "--model", "passive", "--no-held-out"]) == 0
    assert "note:" not in capsys.readouterr().out


def test_a_missing_standard_error_says_why(small_recording, tmp_path, capsys):
    fx = tmp_path / "gain.py"
    fx.write_text(textwrap.dedent(DEGENERATE))
    assert main(["fit", str(small_recording), "--effects", str(fx), "--model", "active+gain", "--no-held-out"]) == 0
    out = capsys.readouterr().out
    assert "k        " in out and "(no error: see below)" in out, out
    assert "no standard error for k, gain.gain: k and gain.gain trade off against each other" in out, out
    assert main(["fit", str(small_recording), "--effects", str(fx), "--model", "active+gain", "--no-held-out",
                 "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)["fits"][0]
    assert fit["errors"] == {"k": None, "gain.gain": None}
    assert set(fit["error_notes"]) == {"k", "gain.gain"} and "cannot tell them apart" in fit["error_notes"]["k"]


@pytest.mark.slow
def test_an_effect_the_data_do_not_show_sits_at_its_bound_and_says_so(tmp_path):
    from rig.simulation.scenarios import hidden_scenario, record_scenario

    path = record_scenario(hidden_scenario(3, "none", width=48, frames=40), tmp_path / "none.h5")
    f = Catalogue.builtin().parse("active+noise_floor+read_noise").fit(ModelData.from_recording(path))
    for n in ("noise_floor.sigma_px", "read_noise.ratio_at_1m"):  # the simulated camera has neither: both fit at 0
        assert f.values[n] < 1e-6 and not np.isfinite(f.errors[n]), (f.values, f.errors)
        assert f.error_notes[n].startswith(f"at its lower bound, 0: the data show none of {n.split('.')[0]}")
    assert not np.isfinite(f.errors["k"]) and f.error_notes["k"].startswith("its error is joint with that of")
    report = f.report()
    assert "+/- nan  (at bound)" in report and "no standard error for k: its error is joint with" in report, report


@pytest.mark.parametrize("window,needles", [
    (["--z-min", "500", "--z-max", "2000"], ["--z-min 500 --z-max 2000", "millimetres", "--z-min 0.5 --z-max 2"]),
    (["--z-min", "2", "--z-max", "1"], ["--z-min 2 --z-max 1", "inverted", "--z-min 1 --z-max 2"]),
    (["--z-max", "0.2"], ["--z-max 0.2", "span 0.", "overlaps"]),
])
@pytest.mark.parametrize("command", [["fit"], ["fit", "--model", "active", "--no-held-out"],
                                     ["compare", "--models", "active", "--no-held-out"]])
def test_a_window_that_keeps_no_pixel_is_named(small_recording, capsys, window, needles, command):
    assert main([command[0], str(small_recording), *command[1:], *window]) == 2
    one_line(capsys, *needles)


def test_a_negative_seed_names_the_option(tmp_path, capsys):
    assert main(["simulate", "--scenario", "hidden", "--seed", "-1", str(tmp_path / "x.h5")]) == 2
    one_line(capsys, "--seed -1", "0 or more")


@pytest.mark.parametrize("argv, words", [
    (["fit", "x.h5", "--jobs", "0"], "argument --jobs: 0 is not a count of processes; give 1 or more"),
    (["compare", "x.h5", "y.h5", "--jobs", "-1"], "argument --jobs: -1 is not a count of processes; give 1 or more"),
    (["validate-diagnosis", "--seeds", "0"], "argument --seeds: 0 is not a count of seeds; give 1 or more"),
    (["simulate", "--frames", "1", "s.h5"], "argument --frames: 1 is not a count of frames a stop; give 2 or more"),
    (["demo", "--frames", "two"], "argument --frames: 'two' is not a whole number; give frames a stop as 2 or more"),
])
def test_a_count_below_its_least_is_one_line_naming_the_least(argv, words, capsys, tmp_path, monkeypatch):
    """issue 51: --jobs 0 and -1 were accepted, --seeds 0 printed an empty table and exited 0, --frames 1 was a
    traceback from the statistics."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith(words), err
    assert not list(tmp_path.iterdir())  # nothing written


def test_simulate_refuses_a_folder_and_an_existing_recording(tmp_path, capsys):
    """issue 51: `rig simulate adir` was an IsADirectoryError traceback, and an existing recording was overwritten
    (rig run refuses)."""
    assert main(["simulate", "--seed", "1", str(tmp_path)]) == 2
    assert f"{tmp_path} is a folder; give the recording's file name" in capsys.readouterr().err
    old = tmp_path / "old.h5"
    old.write_bytes(b"a lab's recording")
    assert main(["simulate", "--seed", "1", str(old)]) == 2
    assert "exists; remove it or give another file name (rig simulate does not overwrite)" in capsys.readouterr().err
    assert old.read_bytes() == b"a lab's recording"


def test_mistakes_of_issue_51_are_one_line_naming_the_fix(small_recording, tmp_path, capsys):
    """issue 51: a file given twice was compared with itself ("alike"); a folder to rig fit was an HDF5 error with a
    buffer address; --z-min 5 was read as millimetres; an unknown scenario was a traceback from the pool;
    --sigma-map 500,1000 drew maps at 500 m."""
    r = str(small_recording)
    cases = [
        (["compare", r, f"{small_recording.parent}/./{small_recording.name}"], "is given twice (as"),
        (["repeatability", r, r, r], "is given twice (as"),
        (["fit", str(tmp_path)], "is a folder, not a recording; give one of its .h5 files"),
        (["fit", r, "--z-min", "5"], "give a window (in metres) that overlaps it"),
        (["validate-diagnosis", "--effects", "nosuch", "--seeds", "1"], "--effects: no scenario named nosuch; the"),
        (["export", r, "-o", str(tmp_path / "m.json"), "--sigma-map", "500,1000"],
         "500 m is beyond any stereo depth camera's range (50 m); give ranges in metres, e.g. --sigma-map 0.5,1"),
    ]
    for argv, words in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err, (argv, err)
        assert "millimetres" not in err and "Traceback" not in err
    assert not (tmp_path / "m.json").exists()


def test_the_tui_without_a_terminal_is_one_line_not_a_hang(tmp_path, capsys):
    """issue 51: `rig tui nothere.h5 > log` drew escape codes into the file until killed (240 s); under pytest
    standard output is captured, not a terminal."""
    assert main(["tui", str(tmp_path / "nothere.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rig tui: error: the terminal UI needs a terminal") and len(err.splitlines()) == 1



def test_the_tui_without_a_terminal_says_so_before_importing_the_app():
    """`rig tui nothere.h5 > log` imported the app (Textual, scipy, matplotlib: 3.7 s of CPU, 5 s on the clock) before
    it said it needs a terminal; it says so first (0.15 s). A new interpreter: what it imported is the question."""
    import subprocess
    import sys

    code = ("import sys; from rig.cli import main; status = main(['tui', 'nothere.h5']); "
            "print(status, [m for m in ('rig.tui.app', 'textual', 'matplotlib', 'scipy') if m in sys.modules])")
    r = subprocess.run([sys.executable, "-c", code], stdin=subprocess.DEVNULL, capture_output=True, text=True,
                       timeout=60)
    assert r.stdout.strip() == "2 []" and r.stderr.startswith("rig tui: error: the terminal UI needs a terminal"), r

def test_export_of_a_recording_that_does_not_determine_lambda_says_so_and_exits_3(tmp_path, capsys):
    """issue 51: rig export of a one-stop recording exited 0 with lambda at its bound, "NOT DETERMINED" only inside
    the JSON. It still writes the file (a model with lambda fixed would be the fix), and says so, exit 3 as rig fit."""
    one = tmp_path / "one.h5"
    assert main(["run", "--protocol", "perpendicular", "--stops", "1.0", "--camera", "fake:width=16,height=9,seed=3",
                 "--stage", "fake:", "-o", str(one), "--frames", "10", "-q"]) == 0
    capsys.readouterr()
    assert main(["export", str(one), "-o", str(tmp_path / "m.json")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("warning: the file is written, but lambda is not determined: the fitted pixels lie at one")
    assert "--model active" in err[-1] and (tmp_path / "m.json").exists()


def test_an_output_named_as_another_kind_of_file_is_refused(small_recording, tmp_path, capsys, monkeypatch):
    """issue 51: `-o out.png` wrote HDF5 (or JSON) into a .png."""
    monkeypatch.chdir(tmp_path)
    for argv, words in [(["run", "--protocol", "perpendicular", "-o", "out.png"], "-o out.png: a .png name for a "
                         "recording (HDF5), which is .h5; name it out.h5"),
                        (["simulate", "s.csv"], "OUTPUT s.csv: a .csv name for a recording (HDF5), which is .h5"),
                        (["export", str(small_recording), "-o", "m.png"], "a .png name for a noise model (JSON), which "
                         "is .json; name it m.json")]:
        assert main(argv) == 2, argv
        assert words in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_a_recording_too_small_to_judge_says_so_and_claims_nothing(tmp_path, capsys):
    """issue 51: a tiny recording was diagnosed as "headline error nan % ... every statistic within noise", with
    numpy's "Mean of empty slice" warnings: no bin held enough pixels, and nothing was judged."""
    import warnings

    tiny = tmp_path / "tiny.h5"
    assert main(["run", "--protocol", "perpendicular", "--camera", "fake:width=4,height=2,seed=3", "--stage", "fake:",
                 "-o", str(tiny), "--frames", "20", "-q"]) == 0
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "Mean of empty slice"
        assert main(["diagnose", str(tiny), "--out", str(tmp_path / "d"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["fits"][0]["headline"]["state"] == "not judged" and doc["diagnosis"]["added"] == []
    assert doc["diagnosis"]["summary"].startswith("Nothing can be judged on these data: no range-and-radius bin holds")
    assert "within noise" not in doc["diagnosis"]["summary"]


def test_missing_files_empty_maps_and_a_file_for_a_folder_are_one_line(small_recording, tmp_path, capsys):
    """issue 51: `rig compare a.h5 nothere.h5` put its error in a row of the table and drew the plot; `--sigma-map ''`
    exited 0 without a map; `rig paper-windows --out FILE` was a FileExistsError traceback."""
    afile = tmp_path / "fit.png"
    afile.write_bytes(b"a plot")
    for argv, words in [(["compare", str(small_recording), str(tmp_path / "nothere.h5")], "nothere.h5 does not exist"),
                        (["export", str(small_recording), "-o", str(tmp_path / "m.json"), "--sigma-map", ""],
                         "--sigma-map '': give ranges in metres"),
                        (["paper-windows", "--out", str(afile)], "is a file; --out is the folder the recordings go to")]:
        assert main(argv) == 2, argv
        err = capsys.readouterr()
        assert words in err.err and len(err.err.strip().splitlines()) == 1 and not err.out, (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit.png"]


def test_an_empty_import_folder_and_empty_models_are_named_as_such(small_recording, tmp_path, capsys):
    """issue 51: an empty folder to import asked for intrinsics; `--models ''` was told to give --models."""
    (tmp_path / "empty").mkdir()
    assert main(["import", str(tmp_path / "empty"), "-o", str(tmp_path / "e.h5")]) == 2
    assert "holds no stop folders of depth frames and no bags" in capsys.readouterr().err
    for given in ("", ","):
        assert main(["compare", str(small_recording), "--models", given]) == 2
        assert f"--models {given!r} names no model; give them comma-separated" in capsys.readouterr().err
    assert not (tmp_path / "e.h5").exists()


def test_a_file_name_with_an_undecodable_byte_is_shown_as_ls_shows_it(small_recording, tmp_path, capsys):
    """Linux file names are bytes: b'caf\\xe9.h5' (Latin-1) reaches rig as a lone surrogate, which neither UTF-8 nor
    matplotlib takes. diagnose, fit --report and compare --report write it as \\xe9 in their text, pages and plots."""
    import os
    import shutil

    name = os.fsdecode(b"caf\xe9.h5")
    copy = tmp_path / name
    other = tmp_path / os.fsdecode(b"b\xe9.h5")
    shutil.copy(small_recording, copy)
    shutil.copy(small_recording, other)
    capsys.readouterr()
    assert main(["diagnose", str(copy), "--out", str(tmp_path / "d")]) == 0
    assert "caf\\xe9" in capsys.readouterr().out
    assert "caf\\xe9.h5" in (tmp_path / "d" / "diagnosis.html").read_text(encoding="utf-8")
    assert main(["fit", str(copy), "--report", str(tmp_path / "f")]) == 0
    assert "caf\\xe9.h5" in (tmp_path / "f" / "fit.html").read_text(encoding="utf-8")
    assert main(["compare", str(copy), str(other), "--report", str(tmp_path / "c"),
                 "--plot", str(tmp_path / "c.png")]) == 0
    assert (tmp_path / "c.png").stat().st_size > 1000 and not list(tmp_path.glob(".*.writing"))


def test_a_user_effect_that_fails_mid_fit_names_itself_its_file_and_the_values(small_recording, tmp_path, capsys):
    effect = tmp_path / "touchy.py"
    effect.write_text(textwrap.dedent('''
        from rig.models import Param, TermEffect, register

        @register
        class Touchy(TermEffect):
            """A fall-off the function cannot compute below n = 0.8 (the data show none: the fit goes there)."""

            name = "touchy"
            stage = "illumination"
            params = (Param("n", 1.0, 0.0, 12.0, "1", "an exponent"),)
            signature = "none"

            def term(self, c, n):
                if n < 0.8:
                    raise ValueError("n too small")
                return c.cos_off_axis ** -n
        '''))
    assert main(["fit", str(small_recording), "--effects", str(effect), "--model", "active+touchy"]) == 2
    one_line(capsys, "effect touchy (in ", "touchy.py", "term(n=", "ValueError: n too small", "n in [0, 12]",
             "narrow the range")


def test_a_stageless_run_of_several_stops_asks_at_a_terminal_and_is_refused_elsewhere(monkeypatch, capsys):
    """`--stage none:` means a person moves the camera: rig asks before each stop, and without a terminal to ask at
    refuses the plan in one line. (A simulated camera's wall follows the plan, so rig run with fake: never asks.)"""
    import io

    from drivers.stage import NoStage
    from protocols.perpendicular import perpendicular
    from rig.cli.acquire import _ask_to_move
    from rig.cli.usage import UsageError

    plan = perpendicular([0.5, 1.0, 1.5])
    with pytest.raises(UsageError, match=r"--stage none: with 3 stops needs someone to move the camera"):
        _ask_to_move(NoStage(), plan, "none:")

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr("sys.stdin", Terminal("\n\n"))
    stage = NoStage()
    _ask_to_move(stage, plan, "none:")
    assert stage.move_to(0.5) == 0.5 and stage.move_to(1.0) == 1.0
    err = capsys.readouterr().err
    assert "place the camera 0.500 m from the wall, then press Enter" in err and "1.000 m" in err
    with pytest.raises(KeyboardInterrupt):  # the terminal closed: stopped as Ctrl-C stops, completed stops kept
        stage.move_to(1.5)
    one_stop = NoStage()
    _ask_to_move(one_stop, perpendicular([0.5]), "none:")
    assert one_stop.ask is None  # a plan of one stop is set up beforehand: nobody is asked


def test_calibration_week_states_the_interval_the_verdict_prints():
    """docs/calibration-week.md gives the ratio's interval for five runs: chi^2 with 4 degrees of freedom at the
    verdicts' level (rig.recordings.comparison.ALPHA), computed here from scipy."""
    import math

    from scipy.stats import chi2

    from rig.recordings.comparison import ALPHA

    low, high = (math.sqrt(4 / chi2.ppf(q, 4)) for q in (1 - ALPHA / 2, ALPHA / 2))
    text = " ".join((Path(__file__).resolve().parents[1] / "docs" / "calibration-week.md").read_text().split())
    assert f"{100 * (1 - ALPHA):.0f} % interval" in text and f"{low:.2f} to {high:.2f} times" in text


def test_asking_whether_an_output_can_be_written_creates_nothing(tmp_path):
    """Issue 52: a killed `rig export` left its writability probe `.rig-write-test-XXXX` behind. The check now asks
    the file system (access(2), statvfs) and creates nothing: the folder's modification time, which any create or
    unlink moves, does not move."""
    import os
    import time

    from rig.reports.writable import output_problem

    before = os.stat(tmp_path).st_mtime_ns
    time.sleep(0.01)
    assert output_problem(tmp_path / "m.json") is None and output_problem(tmp_path / "new" / "deeper", folder=True) is None
    assert os.stat(tmp_path).st_mtime_ns == before and list(tmp_path.iterdir()) == []
    (tmp_path / "file").write_text("x")
    assert "is a file" in output_problem(tmp_path / "file" / "m.json")


def test_compare_with_a_report_writes_nothing_beside_its_inputs(small_recording, tmp_path, capsys):
    """Issue 52: `rig compare a.h5 b.h5 --report cmp` also wrote a-compare.png beside the input (left there stray when
    the disk filled). With --report and no --plot the plot is the report's own."""
    import shutil

    inputs = tmp_path / "in"
    inputs.mkdir()
    a, b = inputs / "a.h5", inputs / "b.h5"
    shutil.copy(small_recording, a)
    shutil.copy(small_recording, b)
    assert main(["compare", str(a), str(b), "--report", str(tmp_path / "cmp")]) == 0
    assert f"plot: {tmp_path / 'cmp' / 'compare-overlay.png'}" in capsys.readouterr().out
    assert sorted(p.name for p in inputs.iterdir()) == ["a.h5", "b.h5"]
    assert sorted(p.name for p in (tmp_path / "cmp").iterdir()) == ["compare-overlay.png", "compare.html"]



def test_a_full_disk_under_the_standard_output_does_not_say_run_again(tmp_path, capsys, monkeypatch):
    """Issue 52: a bag import whose last line to stdout hit a full disk said "disk full ... run the command again",
    though its file was complete (and the re-run then said it already exists). rig run, import and simulate end with
    that line: when it is lost, the one line says the file is complete."""
    import errno
    import io

    class FullDisk(io.StringIO):
        def write(self, text: str) -> int:
            raise OSError(errno.ENOSPC, "No space left on device")

    out = tmp_path / "r.h5"
    monkeypatch.setattr("sys.stdout", FullDisk())
    assert main(["run", "--protocol", "perpendicular", "--camera", "fake:width=16,height=9", "--stops", "0.5,1.0",
                 "--frames", "4", "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"disk full writing the standard output: {out} is complete" in err, err
    assert "run the command again" not in err
    with Recording(out) as rec:
        assert rec.stop_labels() == ["0.500m", "1.000m"] and rec.assembled
