"""Shared helpers: small simulated rigs."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import os

# One worker a core (pytest_xdist_auto_num_workers below): one BLAS thread each (rig/runtime/blas_threads.py), set before
# numpy is imported; the workers and the commands the tests start inherit it.
from rig.runtime.blas_threads import one_blas_thread  # noqa: E402
from rig.runtime.process_gc import collect_less_often, freeze_before_exit  # noqa: E402

one_blas_thread()
collect_less_often()  # as the `rig` program does (rig/runtime/process_gc.py): the workers' collector runs less often

import pytest

pytest_plugins = ["cpu_table"]  # `--cpu-table=FILE`: the CPU by test file (tests/cpu_table.py)


def _fail_skips_in_ci(report) -> None:
    """In CI everything the tests need is installed, so a skip means a broken set-up: fail it. An expected
    failure (xfail) is reported as skipped too, with `wasxfail`: that is no skip, and stays as it is."""
    if os.environ.get("CI") and report.skipped and not hasattr(report, "wasxfail"):
        report.outcome = "failed"
        report.longrepr = f"skipped in CI, where every dependency is installed: {report.longrepr}"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    _fail_skips_in_ci(outcome.get_result())


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    _fail_skips_in_ci(outcome.get_result())


def pytest_addoption(parser):
    parser.addoption("--quick", action="store_true",
                     help="the inner loop: the tests not marked slow (the same as -m 'not slow')")


def pytest_collection_modifyitems(config, items):
    """`--quick` leaves out the tests marked `slow` (pyproject.toml's markers say which)."""
    if not config.getoption("--quick"):
        return
    slow = [item for item in items if item.get_closest_marker("slow") is not None]
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if item.get_closest_marker("slow") is None]


def pytest_unconfigure(config):
    """The session is over (in each xdist worker and in the controller): what it made is frozen, so the
    interpreter's shutdown collections pass over nothing (rig/runtime/process_gc.py)."""
    freeze_before_exit()


def pytest_xdist_auto_num_workers(config):
    """`-n auto`: one worker a core. Two a core finished sooner (the serial-stage tests run GRBL and Zaber
    controllers in real time and mostly wait: 5 min 23 s against 6 min 4 s, measured on 2 cores in 2026-11), but
    every CPU-bound test then shares its core and its caches with another and takes more CPU to do the same work:
    tests/test_diagnosis.py + tests/test_recovery.py took 191-210 s of the machine's CPU with 4 workers and 166-183 s
    with 2, and the whole `.ci/run` from a fresh clone 1,003 s with 4 and 898 s with 2 (2026-11-26, the same
    commit back to back; 10 min 16 s and 13 min 0 s of wall time). The suite is held to a CPU budget (10 min),
    not to its wall time (20 min), so one worker a core."""
    import os

    return os.cpu_count() or 1


@pytest.fixture(scope="session")
def small_recording(tmp_path_factory) -> Path:
    """The small recording the CLI tests read and never change: a perpendicular run of the fake camera, 32 px
    wide, 8 frames a stop at 0.5, 1.0, 1.5 and 2.0 m, exposure 3300 us, gain 32. Made once for all the xdist
    workers of a run (under a lock in the temp folder they share), not once a module."""
    import fcntl

    from simrig import record_perpendicular

    root = tmp_path_factory.getbasetemp().parent  # one per pytest run, shared by its workers
    path = root / "small-recording" / "four-stops.h5"
    path.parent.mkdir(exist_ok=True)
    with open(root / "small-recording.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not path.exists():
            making = path.parent / "making" / "four-stops.h5"
            making.parent.mkdir(exist_ok=True)
            record_perpendicular(making, width=32, frames=8, stops_m=[0.5, 1.0, 1.5, 2.0], exposure_us=3300.0,
                                 gain=32.0)
            making.rename(path)
    return path
