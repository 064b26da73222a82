"""Issue 51's thirty mistakes, replayed as the tester typed them: each gives its one line or the right behaviour.

A tester tried rig as a new user and met 30 mistakes without a clear one-line error (or the right behaviour): 8
tracebacks, 12 silent wrong results, 9 misleading messages and a hang. Each case below types the tester's command
line in a fresh folder (the current directory) holding what the mistake needs: small simulated recordings made once
for the module (16x9 px, 5 frames a stop, 3 stops; one of a single stop; one of the projector off; one 2x1 px), an
existing file, a folder of frames. A refused command exits 2 with one line `rig: error: ...` naming the problem and
the fix (argparse's own refusals, `rig CMD: error: argument ...`, follow its usage synopsis); a command that now does
the right thing is checked for it (a file kept, nothing judged, a warning and exit 3).

Each command runs in this process (`cli_in_process`: a new interpreter would cost ~1.5 s of CPU each) but two: the
hang, which is about a real process's standard streams, and the TUI, an app driven headless by Textual's pilot.
Where each fix is tested in depth: tests/test_analysis_papercuts.py, test_import.py, test_device_options.py, test_export.py,
test_recordings_compared.py, test_tui.py.

The file takes 5.3-5.8 s of CPU in its tests (--cpu-table; 6.1-6.5 s for the whole pytest process), bytecode
cached as dev.py has it, most of it importing and drawing for the three reports and the TUI: slow.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from cli_in_process import rig_in_process as rig

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
RIG = Path(sys.executable).parent / "rig"
#: a RealSense recording played back: a camera that, unlike the simulated one, does not follow the plan's moves
BAG = ROOT / "tests" / "vendor" / "real" / "realsense" / "single_depth_color_640x480.bag"
SMALL = ["--protocol", "perpendicular", "--camera", "fake:width=16,height=9", "--frames", "5"]

CASES = []


def case(fn):
    """One of the thirty: fn(made) replays it in the current directory; `made` holds the module's recordings."""
    CASES.append(fn)
    return fn


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> Path:
    """r.h5 (projector on) and off.h5 (off): 0.5, 1.0, 1.5 m; one.h5: 1.0 m alone; w2.h5: `rig simulate --width 2`,
    2x1 px at 11 stops. Made with rig run and rig simulate as the tester would."""
    root = tmp_path_factory.mktemp("made")
    for name, extra in (("r.h5", []), ("off.h5", ["--projector", "off"]), ("one.h5", ["--stops", "1.0"])):
        stops = [] if "--stops" in extra else ["--stops", "0.5,1.0,1.5"]
        r = rig("run", *SMALL, *stops, *extra, "-o", root / name, "-q")
        assert r.returncode == 0, r.stderr
    r = rig("simulate", "--seed", "1", "--width", "2", "--frames", "5", root / "w2.h5", "-q")
    assert r.returncode == 0, r.stderr
    return root


@pytest.fixture
def here(tmp_path, monkeypatch) -> Path:
    """A fresh folder as the current directory, and standard input a file (not a terminal), as under a script."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.stdin", io.StringIO())
    return tmp_path


def bring(made: Path, *names: str) -> None:
    for name in names:
        shutil.copy(made / name, name)


def refused(r: subprocess.CompletedProcess, *words: str, prefix: str = "rig: error: ") -> str:
    """Exit 2, nothing on stdout, and on stderr one line that starts with `prefix` and holds each of `words`."""
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and not r.stdout and len(lines) == 1, (r.returncode, r.stdout, r.stderr)
    line = lines[0]
    assert line.startswith(prefix) and "Traceback" not in line, line
    assert all(w in line for w in words), (words, line)
    return line


def refused_by_argparse(r: subprocess.CompletedProcess, command: str, *words: str) -> str:
    """argparse's refusal: exit 2, its usage synopsis of `rig COMMAND`, then one line `rig COMMAND: error: ...`."""
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and not r.stdout, (r.returncode, r.stdout, r.stderr)
    assert lines[0].startswith(f"usage: rig {command} ") and all(s.startswith(" ") for s in lines[1:-1]), lines
    line = lines[-1]
    assert line.startswith(f"rig {command}: error: argument ") and all(w in line for w in words), (words, line)
    return line


def frames_folder() -> Path:
    """frames/: three stops of 3 depth frames (16x9 px, uint16 in 1 mm) and a manifest with everything rig needs."""
    src = Path("frames")
    rng = np.random.default_rng(1)
    for z_m in (0.5, 1.0, 1.5):
        stop = src / f"{z_m:.3f}m"
        stop.mkdir(parents=True)
        np.save(stop / "depth.npy", (z_m * 1000 + rng.normal(0, 2, (3, 9, 16))).astype(np.uint16))
    (src / "rig-import.toml").write_text(textwrap.dedent("""\
        fx = 12.0
        fy = 12.0
        cx = 7.5
        cy = 4.0
        baseline_m = 0.05
        depth_unit_m = 0.001
        projector_on = true
        stop_distance_from_name = "(?P<m>[0-9.]+)m"
        """))
    return src


# -- tracebacks ------------------------------------------------------------------------------------------------


@case
def simulate_into_a_folder(made):
    """`rig simulate --seed 1 adir` (a folder): an IsADirectoryError traceback."""
    Path("adir").mkdir()
    refused(rig("simulate", "--seed", "1", "adir"), "adir is a folder; give the recording's file name, e.g. adir/")
    assert not list(Path("adir").iterdir())


@case
def simulate_one_frame_a_stop(made):
    """`rig simulate --seed 1 --frames 1 s.h5`: a ValueError traceback from the statistics."""
    refused_by_argparse(rig("simulate", "--seed", "1", "--frames", "1", "s.h5"), "simulate",
                        "--frames: 1 is not a count of frames a stop; give 2 or more")
    assert not Path("s.h5").exists()


@case
def paper_windows_out_an_existing_file(made):
    """`rig paper-windows --out fit.png` on an existing file: a FileExistsError traceback."""
    Path("fit.png").write_bytes(b"a plot")
    refused(rig("paper-windows", "--out", "fit.png"), "--out fit.png is a file; --out is the folder the recordings go "
            "to: give a folder")
    assert Path("fit.png").read_bytes() == b"a plot"


@case
def validate_diagnosis_of_an_unknown_effect(made):
    """`rig validate-diagnosis --effects nosuch --seeds 1`: a _RemoteTraceback from the pool."""
    refused(rig("validate-diagnosis", "--effects", "nosuch", "--seeds", "1"),
            "--effects: no scenario named nosuch; the scenarios are none, noise_floor,")


LATIN_1 = os.fsdecode(b"caf\xe9.h5")  # a name with a byte that is not UTF-8: Python's argv holds it as a surrogate


@case
def diagnose_a_file_named_in_latin_1(made):
    """`rig diagnose caf\\xe9.h5`: a UnicodeEncodeError traceback. The name is written as ls writes it."""
    shutil.copy(made / "r.h5", LATIN_1)
    r = rig("diagnose", LATIN_1)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert r.stdout.startswith("Diagnosis of caf\\xe9.h5: ")
    report = Path(os.fsdecode(b"caf\xe9-diagnosis"), "diagnosis.html")  # the default, RECORDING-diagnosis/
    assert "caf\\xe9.h5" in report.read_text(encoding="utf-8")


@case
def fit_report_of_a_file_named_in_latin_1(made):
    """`rig fit caf\\xe9.h5 --report f`: a TypeError in matplotlib."""
    shutil.copy(made / "r.h5", LATIN_1)
    r = rig("fit", LATIN_1, "--report", "f")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert r.stdout.startswith("caf\\xe9.h5: perpendicular, projector on")
    assert "caf\\xe9.h5" in Path("f", "fit.html").read_text(encoding="utf-8")


@case
def compare_report_of_a_file_named_in_latin_1(made):
    """`rig compare caf\\xe9.h5 b\\xe9.h5 --report c`: a TypeError in matplotlib."""
    other = os.fsdecode(b"b\xe9.h5")
    shutil.copy(made / "r.h5", LATIN_1)
    shutil.copy(made / "off.h5", other)
    r = rig("compare", LATIN_1, other, "--report", "c")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    page = Path("c", "compare.html").read_text(encoding="utf-8")
    assert "caf\\xe9.h5" in page and "b\\xe9.h5" in page and Path("c", "compare-overlay.png").stat().st_size > 1000


@case
def tui_opening_a_2x1_pixel_recording(made):
    """`rig tui w2.h5` of a 2x1-px recording: "cannot convert float NaN to integer". No bin holds enough pixels to
    judge a headline error: the Results screen says so, with the fix. (Headless, devices not connected.)"""
    pytest.importorskip("textual", reason="rig tui needs textual (pip install -e .[test])")
    from rig.tui.app import RigApp
    from rig.tui.widgets import HeadlineChart
    from tui_pilot import run, screen_text, until

    bring(made, "w2.h5")
    seen = {}

    async def go():
        app = RigApp(recording="w2.h5", connect=False)
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.results.session.diagnosis is not None and not app.results.busy,
                        "the diagnosis")
            seen.update(status=app.results.status.text, chart=app.query_one(HeadlineChart).plain,
                        screen=screen_text(app), crash=app.crash)

    run(go())
    assert seen["crash"] is None
    assert seen["status"] == ("w2.h5: active not judged: no range-and-radius bin holds 20 pixels to compare sigma in; "
                              "record a larger image or more frames a stop"), seen["status"]
    assert seen["chart"] == "active: not judged" and "NaN" not in seen["screen"] and "could not" not in seen["screen"]


# -- silent -------------------------------------------------------------------------------------------------------


@case
def simulate_over_an_existing_recording(made):
    """`rig simulate --seed 1 r.h5` overwrote an existing recording (rig run refuses)."""
    bring(made, "r.h5")
    before = Path("r.h5").read_bytes()
    refused(rig("simulate", "--seed", "1", "r.h5"),
            "r.h5 exists; remove it or give another file name (rig simulate does not overwrite)")
    assert Path("r.h5").read_bytes() == before


@case
def diagnose_a_2_pixel_wide_recording(made):
    """`rig diagnose w2.h5` said "headline error nan % ... every statistic within noise". Now: nothing is judged."""
    bring(made, "w2.h5")
    r = rig("diagnose", "w2.h5")
    assert r.returncode == 0, r.stderr
    assert ("\nNothing can be judged on these data: no range-and-radius bin holds 20 pixels to compare sigma in; "
            "record a larger image or more frames a stop") in r.stdout
    final = r.stdout.split("\nFinal: ", 1)[1].splitlines()[0]
    assert final.startswith("active: ") and "NOT JUDGED: no range-and-radius bin holds 20 pixels" in final, final
    assert "\n  The path stopped: nothing can be judged: no range-and-radius bin holds enough pixels." in r.stdout
    assert "within noise" not in r.stdout
    for line in r.stdout.splitlines():  # a statistic with no bin to compare is marked not judged, never "ok"
        if "no bin to compare" in line:
            assert line.startswith("  --  "), line


@case
def export_a_one_stop_recording(made):
    """`rig export one.h5` exited 0 with lambda -2.0 +/- 1.2 at its bound, "NOT DETERMINED" only inside the JSON."""
    bring(made, "one.h5")
    r = rig("export", "one.h5")
    assert r.returncode == 3, (r.returncode, r.stderr)  # as rig fit: written, but lambda not determined
    assert r.stderr.strip().splitlines() == [r.stderr.strip()] and r.stderr.startswith(
        "warning: the file is written, but lambda is not determined: the fitted pixels lie at one range (1.000 m)")
    assert "--model active (projector on)" in r.stderr and Path("one-noise-model.json").exists()


@case
def sigma_map_in_millimetres(made):
    """`rig export r.h5 --sigma-map 500,1000` (mm typed as m) drew maps at 500 m."""
    bring(made, "r.h5")
    refused(rig("export", "r.h5", "--sigma-map", "500,1000"), "500 m is beyond any stereo depth camera's range (50 m); "
            "give ranges in metres, e.g. --sigma-map 0.5,1")
    assert sorted(os.listdir()) == ["r.h5"]


@case
def import_a_baseline_in_millimetres(made):
    """`rig import frames -o x.h5 --baseline-m 50` was accepted."""
    frames_folder()
    refused(rig("import", "frames", "-o", "x.h5", "--baseline-m", "50"), "--baseline-m 50: 50 m is more than a stereo "
            "camera's 1 m; give it in metres (a D435's is 0.050: 0.05 if that was mm)")
    assert not Path("x.h5").exists()


@case
def several_stops_without_a_stage(made):
    """`--stage none:` with several stops recorded them without asking anyone to move the camera. At a terminal rig
    asks before each stop; here (no terminal) it refuses. The camera is a RealSense recording played back: the
    simulated camera's wall follows the plan, so nobody needs asking there."""
    refused(rig("run", "--protocol", "perpendicular", "--camera", f"realsense:file={BAG}", "--stage", "none:",
                "--stops", "0.5,1.0", "-o", "n.h5"),
            "--stage none: with 2 stops needs someone to move the camera between them, and rig is not at a terminal "
            "to ask; run it at a terminal")
    assert not Path("n.h5").exists()


@case
def compare_a_recording_with_itself(made):
    """`rig compare r.h5 r.h5` said "alike"."""
    bring(made, "r.h5")
    refused(rig("compare", "r.h5", "r.h5"), "r.h5 is given twice (as r.h5 too); give each recording once")


@case
def repeatability_of_one_file_given_thrice(made):
    """`rig repeatability r.h5 r.h5 r.h5` judged the errors, never noticing one file given three times."""
    bring(made, "r.h5")
    refused(rig("repeatability", "r.h5", "r.h5", "r.h5"), "r.h5 is given twice (as r.h5 too); give each recording once")


@case
def outputs_named_png(made):
    """`-o out.png` wrote HDF5 (rig run) or JSON (rig export) into a .png."""
    bring(made, "r.h5")
    refused(rig("run", *SMALL, "-o", "out.png"),
            "-o out.png: a .png name for a recording (HDF5), which is .h5; name it out.h5")
    refused(rig("export", "r.h5", "-o", "out.png"),
            "--out out.png: a .png name for a noise model (JSON), which is .json; name it out.json")
    assert sorted(os.listdir()) == ["r.h5"]


@case
def jobs_0(made):
    """`rig fit r.h5 --jobs 0` was accepted."""
    refused_by_argparse(rig("fit", "r.h5", "--jobs", "0"), "fit", "--jobs: 0 is not a count of processes; give 1 or more")


@case
def jobs_minus_1(made):
    """`rig fit r.h5 --jobs -1` was accepted."""
    refused_by_argparse(rig("fit", "r.h5", "--jobs", "-1"), "fit",
                        "--jobs: -1 is not a count of processes; give 1 or more")


@case
def validate_diagnosis_of_no_seeds(made):
    """`rig validate-diagnosis --seeds 0` printed an empty table and exited 0."""
    refused_by_argparse(rig("validate-diagnosis", "--seeds", "0"), "validate-diagnosis",
                        "--seeds: 0 is not a count of seeds; give 1 or more")


# -- misleading ---------------------------------------------------------------------------------------------------


@case
def a_port_without_its_slashes(made):
    """`--stage 'grbl:/dev/pts/0'` was "is not KEY=VALUE; write e.g. 'fake:width=424'"."""
    line = refused(rig("run", "--protocol", "perpendicular", "--stage", "grbl:/dev/pts/0", "-o", "g.h5"),
                   "'/dev/pts/0' looks like a port; write it after '//', as 'grbl:///dev/pts/0'")
    assert "KEY=VALUE" not in line and not Path("g.h5").exists()


@case
def fit_a_folder(made):
    """`rig fit adir` was an HDF5 error with a buffer address, no hint of --many."""
    Path("adir").mkdir()
    line = refused(rig("fit", "adir"), "adir is a folder, not a recording; give one of its .h5 files", "--many")
    assert "0x" not in line


@case
def a_window_in_metres_read_as_millimetres(made):
    """`rig fit r.h5 --z-min 5` said "this looks like millimetres: --z-min 0.005"."""
    bring(made, "r.h5")
    line = refused(rig("fit", "r.h5", "--z-min", "5"), "no pixel in the window --z-min 5: the recording's pixels span ",
                   "give a window (in metres) that overlaps it")
    assert "millimetres" not in line and "0.005" not in line


TOUCHY = '''\
from rig.models import Param, TermEffect, register


@register
class Touchy(TermEffect):
    """sigma grows off axis as cos^-n (a beam's fall-off); its author's function cannot compute beyond n = 1.2."""

    name = "touchy"
    stage = "illumination"
    params = (Param("n", 1.0, 0.0, 12.0, "1", "an exponent"),)
    signature = "the error grows off axis"

    def term(self, c, n):
        if n > 1.2:
            raise ValueError("n too big")
        return c.cos_off_axis ** -n
'''


@case
def a_user_effect_that_fails(made):
    """`rig fit r.h5 --effects touchy.py --model active+touchy`, the effect failing mid-fit, said "n too big" without
    the effect or its file."""
    bring(made, "r.h5")
    Path("touchy.py").write_text(TOUCHY)
    refused(rig("fit", "r.h5", "--effects", "touchy.py", "--model", "active+touchy"),
            "effect touchy (in ", "touchy.py", "term(n=", "failed (ValueError: n too big)", "n in [0, 12]",
            "narrow the range")


@case
def repeatability_of_projector_on_and_off(made):
    """`rig repeatability r.h5 off.h5` (projector on, then off) blamed "gain, exposure, or warm-up"."""
    bring(made, "r.h5", "off.h5")
    r = rig("repeatability", "r.h5", "off.h5")
    assert r.returncode == 0, r.stderr
    verdict = r.stdout.split("verdict: ", 1)[1]
    assert verdict.startswith("The runs are not of one set-up, so their scatter is not only the noise's: projector on "
                              "in r.h5 against off in off.h5"), verdict
    assert "the set-up differs in projector" in verdict and "warm-up" not in verdict and "exposure" not in verdict


@case
def models_given_empty(made):
    """`rig compare r.h5 --models ''`: --models given, yet "give --models"."""
    bring(made, "r.h5")
    line = refused(rig("compare", "r.h5", "--models", ""), "--models '' names no model; give them comma-separated")
    assert "give --models" not in line


@case
def a_newer_model_file(made):
    """`rig sigma-bag m.json BAG` of a rig.noise-model/2 file said "export the model with rig export"; the fix is a
    newer evaluator."""
    Path("m.json").write_text(json.dumps({"schema": "rig.noise-model/2"}))
    line = refused(rig("sigma-bag", "m.json", BAG, "-o", "s.bag"), "m.json is a rig.noise-model/2 file, newer than "
                   "this evaluator's rig.noise-model/1; update rig")
    assert "rig export" not in line and not Path("s.bag").exists()


@case
def import_an_empty_folder(made):
    """`rig import empty -o e.h5` asked for intrinsics."""
    Path("empty").mkdir()
    line = refused(rig("import", "empty", "-o", "e.h5"), "empty holds no stop folders of depth frames and no bags")
    assert "fx" not in line and not Path("e.h5").exists()


@case
def import_into_a_read_only_folder(made):
    """`rig import frames -o ro/x.h5`, ro read-only, said "the disk failed writing ... check the disk (dmesg)". Root
    writes anywhere but on a read-only file system, so as root ro is one (a tmpfs mounted ro), else a folder 0500."""
    frames_folder()
    ro = Path("ro")
    ro.mkdir()
    mounted = os.geteuid() == 0
    if mounted:
        assert subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)]).returncode == 0
    else:
        ro.chmod(0o500)
    try:
        line = refused(rig("import", "frames", "-o", "ro/x.h5"), "cannot write -o ro/x.h5: no file can be created "
                       "in ro (", "give -o a file you can write to")
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(ro)], check=True)
        else:
            ro.chmod(0o700)
    assert "disk failed" not in line and "dmesg" not in line


# -- hang ---------------------------------------------------------------------------------------------------------


@case
def tui_with_its_output_to_a_file(made):
    """`rig tui nothere.h5 > log` at a terminal drew escape codes into log until killed (240 s). A real process: its
    standard input a terminal (a pseudo-terminal), its output the file."""
    terminal, tty = os.openpty()
    try:
        with open("log", "wb") as log:
            r = subprocess.run([RIG, "tui", "nothere.h5"], stdin=tty, stdout=log, stderr=subprocess.PIPE, text=True,
                               timeout=60)
    finally:
        os.close(terminal)
        os.close(tty)
    refused(r, "the terminal UI needs a terminal, and standard input or output is a file or a pipe; run it in a "
            "terminal", prefix="rig tui: error: ")
    assert Path("log").read_bytes() == b""


assert len(CASES) == 30


@pytest.mark.parametrize("replay", CASES, ids=[c.__name__ for c in CASES])
def test_each_mistake_gives_its_line_or_behaviour(replay, made, here):
    replay(made)
