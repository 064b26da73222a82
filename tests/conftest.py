"""Shared helpers: small simulated rigs."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import os

import pytest


def _fail_skips_in_ci(report) -> None:
    """In CI everything the tests need is installed, so a skip means a broken set-up: fail it."""
    if os.environ.get("CI") and report.skipped:
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


def pytest_xdist_auto_num_workers(config):
    """`-n auto`: two workers a core. The serial-stage tests run GRBL and Zaber controllers in real time and
    mostly wait (82 s of wall time for 6 s of CPU in tests/test_grbl_protocol.py); with one worker a core a
    waiting test holds a core idle. Measured on 2 cores: 6 min 4 s with 2 workers, 5 min 23 s with 4."""
    import os

    return 2 * (os.cpu_count() or 1)


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
