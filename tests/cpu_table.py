"""Where the suite's CPU goes: `pytest --cpu-table=FILE` writes a table of CPU by test file (docs/testing.md's).

Each test's CPU is its process's own (all threads, `time.process_time`) plus the processes it started and waited
for (`RUSAGE_CHILDREN`: the `rig` commands, the firmware, the crash children), over its setup, call and teardown;
a module's fixtures count in its first test. In an xdist worker it travels to the controller in the report's
`user_properties`, where the files are added up. What no test waits for (a server's children) is in no row: the
machine's busy time that `python3 dev.py test` prints holds it.
"""

from __future__ import annotations

import resource
import time
from collections import defaultdict
from pathlib import Path

import pytest

KEY = "cpu_s"


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + r.ru_utime + r.ru_stime


def pytest_addoption(parser):
    parser.addoption("--cpu-table", metavar="FILE", default=None,
                     help="write the CPU of each test file (own + the processes it waited for) as a Markdown table")


def _measured(item):
    t0 = _cpu()
    yield
    item.user_properties.append((KEY, _cpu() - t0))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
    yield from _measured(item)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    yield from _measured(item)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item):
    yield from _measured(item)


class Table:
    """The controller's sums by file: tests, CPU (s) and wall time (s)."""

    def __init__(self, path: str) -> None:
        self.path = Path(path)
        self.rows: dict[str, list[float]] = defaultdict(lambda: [0, 0.0, 0.0])

    def pytest_runtest_logreport(self, report):
        row = self.rows[report.nodeid.split("::")[0]]
        row[2] += report.duration
        if report.when == "teardown":
            row[0] += 1
            row[1] += sum(v for k, v in report.user_properties if k == KEY)

    def pytest_terminal_summary(self, terminalreporter):
        rows = sorted(self.rows.items(), key=lambda kv: -kv[1][1])
        cpu = sum(r[1] for _, r in rows)
        lines = ["| test file | tests | CPU (s) | share | wall in its tests (s) |", "|---|---:|---:|---:|---:|"]
        lines += [f"| `{name}` | {n} | {c:.1f} | {100 * c / cpu:.1f} % | {w:.1f} |" for name, (n, c, w) in rows]
        lines.append(f"| all | {sum(r[0] for _, r in rows)} | {cpu:.1f} | 100 % | {sum(r[2] for _, r in rows):.1f} |")
        self.path.write_text("\n".join(lines) + "\n")
        terminalreporter.write_sep("-", f"CPU by test file: {cpu:.0f} s in the tests, the table in {self.path}")
        for name, (n, c, w) in rows[:10]:
            terminalreporter.write_line(f"{c:7.1f} s  {100 * c / cpu:4.1f} %  {n:4d} tests  {name}")


def pytest_configure(config):
    path = config.getoption("--cpu-table")
    if path and not hasattr(config, "workerinput"):  # the controller (or a run without workers) adds up
        config.pluginmanager.register(Table(path), "cpu-table")
