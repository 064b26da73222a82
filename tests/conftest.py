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
