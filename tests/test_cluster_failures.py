"""A fleet on a real Dask cluster (`--scheduler`): relative paths reach workers that run in another working
directory, and a cluster without workers (none at the start, or the last one killed mid-run) ends the command with
one line within --timeout, the results that came before kept. The scheduler runs in this process
(distributed.LocalCluster, TCP); a worker that must die is a `dask worker` process, killed with SIGKILL."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from cli_in_process import rig_in_process
from simrig import record_perpendicular

import rig.fleet.many  # noqa: F401 (imported before any clock starts: the times measured are rig's waits)

#: --timeout of these tests, s; the engine polls every min(1 s, timeout / 4) and asks the scheduler for its workers,
#: so the line comes within TIMEOUT_S + a poll + a round trip: SLACK_S bounds those on a loaded 2-core machine
TIMEOUT_S = 0.5
SLACK_S = 1.5


def _fleet(folder: Path, seeds=(1, 2)) -> Path:
    folder.mkdir(parents=True)
    for s in seeds:
        record_perpendicular(folder / f"cam-{s}.h5", seed=s, width=16, frames=4, stops_m=[0.5, 1.0, 2.0])
    return folder


def _cluster(workers: int):
    from distributed import LocalCluster

    return LocalCluster(n_workers=workers, threads_per_worker=1, processes=False, dashboard_address=None,
                        protocol="tcp://")


def _within(deadline_s: float, ready) -> bool:
    """Poll `ready()` until it is true (True), or for `deadline_s` (False)."""
    end = time.monotonic() + deadline_s
    while not ready():
        if time.monotonic() > end:
            return False
        time.sleep(0.02)
    return True


@pytest.mark.slow
def test_relative_paths_reach_workers_in_another_working_directory(tmp_path, monkeypatch):
    """rig runs in lab/ and names lab/fleet as `fleet`; the cluster's workers (threads of this process) run in
    elsewhere/, where `fleet` does not exist. `rig fit --many fleet` and the fits of `rig compare` and `rig
    repeatability` (`fit_all_for_comparison`, without their plots) work there, and report each recording as given."""
    lab, elsewhere = tmp_path / "lab", tmp_path / "elsewhere"
    _fleet(lab / "fleet")
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    in_lab = ("import json, sys; from rig.cli import main; a = sys.argv[1]; "
              "print('status', main(['fit', '--many', 'fleet', '--json', '--scheduler', a]), flush=True); "
              "from rig.fleet.many import fit_all_for_comparison; from rig.recordings.recording_fits import FitJob; "
              "jobs = [FitJob(p) for p in ('fleet/cam-1.h5', 'fleet/cam-2.h5', './fleet/cam-1.h5')]; "
              "print(json.dumps(sorted((r.path, r.error, r.values['lambda']) for r in fit_all_for_comparison(jobs, "
              "scheduler=a))))")
    with _cluster(workers=1) as cluster:
        r = subprocess.run([sys.executable, "-c", in_lab, cluster.scheduler_address], cwd=lab, capture_output=True,
                           text=True, timeout=120)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    fitted, compared = r.stdout.split("status ")
    docs = [json.loads(line) for line in fitted.splitlines()]
    assert sorted(d["file"] for d in docs) == ["fleet/cam-1.h5", "fleet/cam-2.h5"]
    assert all(d["fits"][0]["values"]["lambda"] > 0 for d in docs) and compared.startswith("0\n")
    fits = json.loads(compared[2:])
    assert [f[:2] for f in fits] == [["./fleet/cam-1.h5", ""], ["fleet/cam-1.h5", ""], ["fleet/cam-2.h5", ""]]
    assert fits[0][2] == fits[1][2] > 0  # one fit of cam-1, reported under both of its names


@pytest.mark.slow
def test_a_scheduler_without_workers_is_one_line_within_the_timeout(tmp_path):
    folder = _fleet(tmp_path / "fleet")
    with _cluster(workers=0) as cluster:
        start = time.monotonic()
        fitted = rig_in_process("fit", folder, "--many", "--scheduler", cluster.scheduler_address, "--timeout", TIMEOUT_S)
        waited_s = time.monotonic() - start
        compared = rig_in_process("compare", *sorted(folder.glob("*.h5")), "--plot", tmp_path / "c.png",
                                  "--scheduler", cluster.scheduler_address, "--timeout", TIMEOUT_S)
    for r in (fitted, compared):
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert "the scheduler has no worker, and none joined within 0.5 s (--timeout); 0 of 2" in r.stderr
        assert f"start workers (dask worker {cluster.scheduler_address}) or check the scheduler address" in r.stderr
    assert TIMEOUT_S <= waited_s < TIMEOUT_S + SLACK_S


def _dask_worker(address: str, cwd: Path, threads: int) -> subprocess.Popen:
    """A `dask worker` process without a nanny (a nanny would start a killed worker again)."""
    return subprocess.Popen([str(Path(sys.executable).parent / "dask"), "worker", address, "--no-nanny", "--nthreads",
                             str(threads), "--no-dashboard"], cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _kill_when(worker: subprocess.Popen, watcher, first_out: threading.Event, killed_at: list[float]) -> threading.Thread:
    """A thread that SIGKILLs `worker` at an exact point: once `first_out` is set and the scheduler (asked through
    the client `watcher`) reports a task processing; it notes the time in `killed_at`."""
    def kill():
        if first_out.wait(60) and _within(10, lambda: any(watcher.processing().values())):
            killed_at.append(time.monotonic())
            worker.send_signal(signal.SIGKILL)

    thread = threading.Thread(target=kill)
    thread.start()
    return thread


@pytest.mark.slow
def test_the_last_worker_killed_mid_run_is_one_line_within_the_timeout(tmp_path):
    """One worker process: once the scheduler reports a recording's task processing there, it gets SIGKILL."""
    from distributed import Client

    folder = _fleet(tmp_path / "fleet")
    with _cluster(workers=0) as cluster, Client(cluster.scheduler_address, set_as_default=False) as watcher:
        address = cluster.scheduler_address
        worker = _dask_worker(address, tmp_path, threads=1)
        try:
            watcher.wait_for_workers(1, timeout=30)
            at_once, killed_at = threading.Event(), []
            at_once.set()
            killer = _kill_when(worker, watcher, at_once, killed_at)
            r = rig_in_process("fit", folder, "--many", "--scheduler", address, "--timeout", TIMEOUT_S)
            returned_at = time.monotonic()
            killer.join(70)
        finally:
            worker.kill()
            worker.wait(10)
    assert killed_at, f"no task was reported processing; rig said {r.stderr!r}"
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert ("the cluster lost its last worker, and none joined within 0.5 s (--timeout); 0 of 2 recordings fitted; "
            f"start workers (dask worker {address}) or check the scheduler address") in r.stderr
    assert TIMEOUT_S <= returned_at - killed_at[0] < TIMEOUT_S + SLACK_S


@pytest.mark.slow
def test_results_that_came_before_the_last_worker_was_lost_stay():
    """The engine on the same cluster, with a task that finishes at once and one that sleeps: the first result is
    handed over, then the worker is killed while the other is processing; NoWorkers says 1 of 2."""
    from distributed import Client

    from rig.fleet.executors import NoWorkers, run_each

    with _cluster(workers=0) as cluster, Client(cluster.scheduler_address, set_as_default=False) as watcher:
        worker = _dask_worker(cluster.scheduler_address, Path.cwd(), threads=2)
        try:
            watcher.wait_for_workers(1, timeout=30)
            first_out, killed_at, results = threading.Event(), [], []
            killer = _kill_when(worker, watcher, first_out, killed_at)
            with pytest.raises(NoWorkers) as lost:
                for result in run_each(time.sleep, [0.0, 60.0], scheduler=cluster.scheduler_address, timeout_s=TIMEOUT_S):
                    results.append(result)
                    first_out.set()
            killer.join(70)
        finally:
            worker.kill()
            worker.wait(10)
    assert killed_at and results == [None] and (lost.value.done, lost.value.total) == (1, 2)
    assert "lost its last worker" in str(lost.value) and "1 of 2 recordings fitted" in str(lost.value)


def test_a_scheduler_that_goes_away_mid_run_is_one_line():
    """The scheduler (no workers: the tasks wait there) is closed under a run whose timeout is far off."""
    from distributed import Client

    from rig.fleet.executors import run_each

    cluster = _cluster(workers=0)
    with Client(cluster.scheduler_address, set_as_default=False) as watcher:
        waiting = lambda: watcher.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) == 2
        closer = threading.Thread(target=lambda: _within(10, waiting) and cluster.close())
        closer.start()
        with pytest.raises(ValueError) as gone:
            list(run_each(time.sleep, [0.0, 0.0], scheduler=cluster.scheduler_address, timeout_s=60))
        closer.join(10)
    assert str(gone.value) == (f"--scheduler {cluster.scheduler_address}: the Dask scheduler went away after 0 of 2 "
                               "recordings; restart it (dask scheduler) and its workers, then run again")


def test_a_timeout_that_is_not_positive_is_one_line(tmp_path):
    folder = _fleet(tmp_path / "fleet", seeds=(1,))
    r = rig_in_process("fit", folder, "--many", "--timeout", "0", "--scheduler", "tcp://127.0.0.1:1")
    assert r.returncode == 2
    assert r.stderr == "rig: error: --timeout 0: give a positive number of seconds to wait for a worker (default: 60)\n"
