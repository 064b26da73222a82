"""Progress of long commands on a real terminal: `rig diagnose` with its stderr on a pseudo-terminal shows one
updating line (what, how far, the time left) and erases it; piped, or with -q, it writes nothing there."""

import fcntl
import io
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest

from rig.models.fitting.progress import WorkProgress
from rig.reports.work_progress import WorkProgressLine

pytestmark = pytest.mark.slow


RIG = str(Path(sys.executable).parent / "rig")


@pytest.fixture
def recording(small_recording) -> Path:
    return small_recording


def run_with_stderr_on_a_terminal(args: list[str], columns: int = 100) -> tuple[int, str, str]:
    """Run `args` with stderr on a pseudo-terminal `columns` wide (stdout piped); (status, stdout, stderr as read)."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, columns, 0, 0))
    proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=slave)
    os.close(slave)
    err = b""
    while True:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # EIO: the child closed the terminal
                chunk = b""
            if not chunk:
                break
            err += chunk
        elif proc.poll() is not None:
            break
    os.close(master)
    out = proc.stdout.read().decode()
    return proc.wait(), out, err.decode()


def test_diagnose_shows_one_updating_line_on_a_terminal(recording, tmp_path):
    status, out, err = run_with_stderr_on_a_terminal([RIG, "diagnose", str(recording), "--out", str(tmp_path / "d")])
    assert status == 0, err
    assert "Report:" in out and (tmp_path / "d" / "diagnosis.html").exists()
    assert "\n" not in err  # one line, redrawn in place
    frames = [f.removesuffix("\x1b[K") for f in err.split("\r") if f and f != "\x1b[K"]
    assert len(frames) >= 5
    shapes = [re.fullmatch(r"rig diagnose \[[#.]{14}\] (\d+)/(\d+) \d+:\d\d(, (?:about|at least) \d+:\d\d left)?: (.+)", f) for f in frames]
    assert all(shapes), frames
    tasks = [m.group(4) for m in shapes]
    assert tasks[0] == "reading the recording" and "fitting active" in tasks
    assert tasks[-1] == "writing the plots and the report"
    assert any(m.group(3) for m in shapes)  # a time left, once a step is done
    done = [int(m.group(1)) for m in shapes]
    assert done == sorted(done) and done[-1] == int(shapes[-1].group(2)) - 1
    assert all(len(f) <= 99 for f in frames)  # never wider than the terminal, so never wrapped
    assert err.endswith("\r\x1b[K")  # erased before the result is printed


def test_piped_or_quiet_diagnose_writes_nothing_on_stderr(recording, tmp_path):
    piped = subprocess.run([RIG, "diagnose", str(recording), "--out", str(tmp_path / "a")], capture_output=True, text=True)
    assert piped.returncode == 0 and piped.stderr == "" and "Report:" in piped.stdout
    status, out, err = run_with_stderr_on_a_terminal([RIG, "fit", str(recording), "-q"])
    assert status == 0 and err == "" and "lambda = " in out


def test_fit_shows_its_phases_and_verbose_lists_them_with_times(recording):
    status, out, err = run_with_stderr_on_a_terminal([RIG, "fit", str(recording)])
    assert status == 0 and "lambda = " in out
    for phase in ("reading the recording", "fitting k and lambda", "headline error"):
        assert phase in err
    verbose = subprocess.run([RIG, "-v", "fit", str(recording)], capture_output=True, text=True)
    lines = verbose.stderr.splitlines()
    assert [re.sub(r" \(\d+\.\d s\)$", "", ln) for ln in lines[:2]] == ["rig fit: reading the recording",
                                                                        "rig fit: fitting k and lambda"]
    assert re.fullmatch(r"rig fit: done after \d+\.\d s", lines[-1]) and len(lines) == 4


def test_time_left_is_the_time_per_finished_step_times_the_steps_to_come():
    line = WorkProgressLine("rig x", stream=io.StringIO())
    line(WorkProgress("first", 0, 4))
    t0 = line.t0
    assert line.line(t0 + 5) == "rig x [..............] 0/4 0:05: first"
    line.current, line.step_t0 = WorkProgress("third", 2, 4), t0 + 60  # two steps took a minute
    assert line.line(t0 + 70) == "rig x [#######.......] 2/4 1:10, about 0:50 left: third"
    line.close()


def test_a_run_on_a_terminal_shows_frames_and_the_time_left(tmp_path):
    status, out, err = run_with_stderr_on_a_terminal(
        [RIG, "run", "--protocol", "perpendicular", "--frames", "12", "--stops", "0.5,1.0,1.5", "--camera", "fake:width=32",
         "-o", str(tmp_path / "r.h5")])
    assert status == 0 and "recorded 3 stops" in out
    bars = [f for f in err.split("\r") if "frames" in f]
    assert any(re.search(r"\[ 2/3\]   1\.000m #+\.* \d+/12 frames, about \d+:\d\d left", b) for b in bars), bars
    assert re.search(r"\[ 1/3\]   0\.500m done: .*\(\s*\d+\.\d s, about \d+:\d\d left\)", err)


def test_a_time_left_is_a_lower_bound_while_the_diagnosis_may_still_add_steps(tmp_path):
    """A diagnosis learns its steps as it goes (a second effect, empirical terms), so a time left from the steps
    counted so far runs low. Every report that does not say more may come (`more_may_come`, shown as 'at
    least') has a total no later report exceeds."""
    from rig.diagnosis import diagnose
    from rig.models import ModelData
    from rig.simulation.scenarios import hidden_scenario, record_scenario

    path = record_scenario(hidden_scenario(1000, "slant_range+noise_floor", width=30, frames=20), tmp_path / "pair.h5")
    reports = []
    diagnose(ModelData.from_recording(path), progress=reports.append)
    totals = [r.total for r in reports]
    assert max(totals) > totals[0], totals  # the work grew as it went: the case that ran low
    for i, r in enumerate(reports):
        if not r.more_may_come:
            assert max(totals[i:]) <= r.total, (i, r, totals)
    assert reports[0].more_may_come and not reports[-1].more_may_come
