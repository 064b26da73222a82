"""Every output as safe as the recordings (issue 52): a kill or ENOSPC from the kernel at every write, fsync, rename
and unlink of `rig export`, `rig fit --table`, `--plot`, `--report` and `rig compare --report`,
each over an old output, leaves every output old, whole or absent, and nothing else behind once the command has run
again (a kill between the link and the rename of the output file leaves `.NAME.PID.writing`, which the next write
removes: nothing can remove a file when its writer is killed).

The sweep is tests/output_fault_matrix.py (the table in docs/reliability.md), in its own single-threaded process: it
imports rig once and forks each trial, and strace attaches to the fork (`strace -p`), so a trial costs the command,
not an interpreter's start-up. The link of each output's unnamed file (linkat) and `rig export --sigma-map` are in
the full matrix (`python -m tests.output_fault_matrix`, docs/reliability.md), not here: the suite's CPU.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = ["export", "fit --table", "fit --plot", "fit --report", "compare --report"]
CALLS = ("write", "fsync", "rename", "unlink")


def test_every_call_of_every_output_writer_killed_or_failed_leaves_old_or_whole_and_nothing_behind():
    assert shutil.which("strace"), "strace is not installed; `python3 dev.py setup` installs it (apt-get install strace)"
    done = subprocess.run([sys.executable, "-m", "tests.output_fault_matrix", "--json", "--calls", ",".join(CALLS),
                           *COMMANDS], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    rows = {row["command"]: row for row in json.loads(done.stdout.splitlines()[-1])}
    assert sorted(rows) == sorted(COMMANDS)
    for name, row in rows.items():
        calls = row["calls"]
        outputs = 3 if name == "fit --report" else 2 if name == "compare --report" else 1
        # each output written aside: at least one write, an fsync and a rename each, all of them swept
        assert sorted(calls) == sorted(CALLS), calls
        assert calls["write"] > outputs and calls["fsync"] == calls["rename"] == outputs, (name, calls)
        assert row["trials"] == 2 * sum(calls.values()), (name, row)
        assert row["findings"] == [], (name, row["findings"])
