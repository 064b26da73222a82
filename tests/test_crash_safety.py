"""Kills at exact instants (tests/crash_child.py), and at random ones: every stop a run reported done is
readable afterwards, a run with nothing done starts again cleanly, and --resume completes the recording."""

from __future__ import annotations

import multiprocessing
import os
import random
import signal
import time
from pathlib import Path

import h5py
import pytest

import crash_child
from protocols.recording import Recording
from protocols.run_lock import lock_path
from protocols.stop_journal import journal_dir

pytestmark = pytest.mark.slow


#: each trial is a fork of one server process that imported the crash child once (tests/crash_server.py)
FORKS = multiprocessing.get_context("forkserver")
FORKS.set_forkserver_preload(["crash_server"])


def _server() -> None:
    """Start the fork server with this folder on its path: Python 3.11's server imports its preload from the
    default path only, and skips a module it cannot import without a word."""
    from multiprocessing import forkserver

    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).parent), *([old] if old else [])])
    try:
        forkserver.ensure_running()
    finally:
        if old is None:
            del os.environ["PYTHONPATH"]
        else:
            os.environ["PYTHONPATH"] = old
ALL = [f"{z:.3f}m" for z in (0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0)]

# (point, which call): the header, a stop's in-memory image, the renames, HDF5's flush and close inside a
# stop, and every step of the assembly at the end
EXACT = [
    ("before:write_bytes_durably", 1), ("after:write_bytes_durably", 1),  # the header
    ("before:write_bytes_durably", 4), ("after:write_bytes_durably", 4),  # the third stop
    ("before:replace", 1), ("after:replace", 1), ("before:replace", 5), ("after:replace", 5),
    ("before:fsync_dir", 3), ("before:h5_flush", 2), ("after:h5_flush", 3), ("before:h5_close", 4),
    ("before:h5_copy", 1), ("before:h5_copy", 7), ("after:h5_copy", 11),  # assembly (in memory): copying the stops
    ("before:write_bytes_durably", 13), ("after:write_bytes_durably", 13),  # assembly: the file written whole
    ("before:replace", 13), ("after:replace", 13), ("before:rmtree", 1),  # assembly: its rename, the clean-up
]
# the assembly of a recording too big for memory (raw frames: rig assembles those on disk), forced for a small one
EXACT_ON_DISK = [("before:copyfile", 1), ("after:copyfile", 1), ("before:h5_copy", 7),
                 ("before:commit", 1), ("after:commit", 1)]
EXACT_RAW = [("before:commit", 2), ("after:commit", 2), ("before:h5_close", 3), ("after:h5_close", 6)]


def start(out, point: str = "none", n: int = 0, *flags: str):
    """The crash child (tests/crash_child.py) started in a fork: (process, the receiving end of its lines)."""
    _server()
    receive, send = FORKS.Pipe(duplex=False)
    proc = FORKS.Process(target=crash_child.run_in_fork, args=([str(out), point, str(n), *flags], send), daemon=True)
    proc.start()
    send.close()
    return proc, receive


def lines_until_exit(proc, receive, timeout: float, until=None) -> list[str]:
    """The child's lines, until it exits (or until `until(lines)` holds); fails after `timeout` s."""
    lines: list[str] = []
    deadline = time.monotonic() + timeout
    while until is None or not until(lines):
        if not receive.poll(max(0.0, deadline - time.monotonic())):
            proc.kill()
            raise AssertionError(f"the crash child sent nothing for {timeout} s: {lines}")
        try:
            lines.append(receive.recv())
        except EOFError:
            break
    assert not any(line.startswith("error ") for line in lines), lines[-1]
    return lines


def child(out, point: str = "none", n: int = 0, *flags: str, timeout: float = 120) -> tuple[int, list[str]]:
    proc, receive = start(out, point, n, *flags)
    lines = lines_until_exit(proc, receive, timeout)
    proc.join(timeout)
    return proc.exitcode, [line.split()[1] for line in lines if line.startswith("done ")]


def check_after_kill(out: Path, done: list[str], raw: bool) -> None:
    """What was reported done is readable; then the run is finished by a re-run or --resume."""
    flags = ["--raw"] if raw else []
    if done:
        with Recording(out) as rec:
            labels = rec.stop_labels()
            assert set(done) <= set(labels), (done, labels)
            for label in labels:
                s = rec.stop(label)
                assert s.stats.count.shape == (9, 16) and s.n_frames == 6
            assert rec.skipped == []
        code, again = child(out, "none", 0, "--resume", *flags)
    else:
        code, again = child(out, "none", 0, *flags)  # nothing saved: a new run is not blocked by the leftovers
    assert code == 0, again
    with Recording(out) as rec:
        assert rec.stop_labels() == ALL and rec.assembled and "ended_utc" in rec.attrs
        for label in ALL:
            rec.stop(label)
    assert not journal_dir(out).exists() and not lock_path(out).exists()
    with h5py.File(out) as f:  # one plain HDF5 file again, as docs/data-format.md describes
        assert sorted(f["stops"]) == sorted(ALL) and all(f["stops"][k].attrs["complete"] for k in ALL)
        if raw:
            assert f["stops"]["1.000m"]["raw_depth"].shape == (6, 9, 16)


@pytest.mark.parametrize("point,n", EXACT)
def test_a_kill_at_an_exact_instant_loses_nothing_reported_done(tmp_path, point, n):
    out = tmp_path / "run.h5"
    code, done = child(out, point, n)
    assert code == -signal.SIGKILL, (code, done)
    check_after_kill(out, done, raw=False)


@pytest.mark.parametrize("point,n", EXACT_ON_DISK)
def test_a_kill_while_assembling_on_disk_loses_nothing_reported_done(tmp_path, point, n):
    out = tmp_path / "run.h5"
    code, done = child(out, point, n, "--on-disk-assembly")
    assert code == -signal.SIGKILL, (code, done)
    check_after_kill(out, done, raw=False)


@pytest.mark.parametrize("point,n", EXACT_RAW)
def test_a_kill_while_raw_frames_are_written_loses_nothing_reported_done(tmp_path, point, n):
    out = tmp_path / "run.h5"
    code, done = child(out, point, n, "--raw")
    assert code == -signal.SIGKILL, (code, done)
    check_after_kill(out, done, raw=True)


def test_kills_at_random_instants(tmp_path):
    """Each trial is killed a random 0-50 ms after the run reported its k-th stop done (k random, 1-11: the 11th is
    followed by the assembly), so the instant falls inside the run whatever the machine's load (instants drawn from
    a timed whole run came too late in CI, when the timed runs had been slow)."""
    rng = random.Random(14)
    kills = 0
    for trial in range(8):
        out = tmp_path / f"r{trial}.h5"
        proc, receive = start(out)
        k = rng.randint(1, len(ALL))
        lines = lines_until_exit(proc, receive, 120, until=lambda got: sum(x.startswith("done ") for x in got) >= k)
        time.sleep(rng.uniform(0.0, 0.05))
        proc.kill()  # SIGKILL
        lines += lines_until_exit(proc, receive, 120)
        proc.join(120)
        done = [line.split()[1] for line in lines if line.startswith("done ")]
        if proc.exitcode == 0:
            continue  # it finished first
        assert proc.exitcode == -signal.SIGKILL, proc.exitcode
        kills += 1
        check_after_kill(out, done, raw=False)
    assert kills >= 6, f"only {kills} of 8 trials were killed before the run finished"


@pytest.mark.parametrize("point", ["after:copyfile", "before:commit", "after:commit"])
def test_a_kill_while_a_resume_replaces_the_plan_keeps_the_file_whole(tmp_path, point):
    """A resumed run that changes the stops not yet recorded writes the new plan into the header (a copy,
    renamed into place): killed on either side of the rename, the file holds the old plan or the new one."""
    out = tmp_path / "run.h5"
    code, _ = child(out, "after:write_bytes_durably", 4)  # the header and three stops written
    assert code == -signal.SIGKILL
    new = ["0.500m", "0.750m", "1.000m", "2.000m", "3.000m"]
    code, done = child(out, point, 1, "--resume", "--stops", "0.5,0.75,1.0,2.0,3.0")
    assert code == -signal.SIGKILL and done == [], (code, done)
    with Recording(out) as rec:
        assert rec.stop_labels() == ALL[:3] and rec.skipped == []
        assert rec.protocol_params["stops_m"] in ([float(z[:-1]) for z in ALL], [0.5, 0.75, 1.0, 2.0, 3.0])
    code, done = child(out, "none", 0, "--resume", "--stops", "0.5,0.75,1.0,2.0,3.0")
    assert code == 0 and done == ["2.000m", "3.000m"], (code, done)
    with Recording(out) as rec:
        assert rec.stop_labels() == new and rec.assembled and rec.protocol_params["stops_m"] == [0.5, 0.75, 1.0, 2.0, 3.0]


def test_a_kill_inside_the_last_clean_up_is_finished_by_resume(tmp_path):
    """rmtree of the stop folder killed after its last file but before the folder itself: the recording is
    complete, and the next --resume removes the empty folder (seen once in 8 random kills under load)."""
    out = tmp_path / "run.h5"
    assert child(out)[0] == 0
    journal_dir(out).mkdir()
    (journal_dir(out) / "0.500m.h5.4242.tmp").write_bytes(b"torn")  # a stop's image torn by the kill, too
    code, done = child(out, "none", 0, "--resume")
    assert code == 0 and done == []
    assert not journal_dir(out).exists()
    with Recording(out) as rec:
        assert rec.stop_labels() == ALL and rec.assembled
