"""A process killed at an exact system call leaves nothing the next run, resume or import does not clean up.

The kill comes from the kernel at the N-th call (`strace -f -e inject=write:signal=KILL:when=N`), in the real
command (forked from one process that has imported rig: tests/forked_rig.py), at the lock, the middle and the end of a small run (every index: tests/fault_matrix.py). Issue 28 found that a kill during the final assembly left `.run.h5.<pid>.assembling` (a full-size copy)
that no later --resume removed (14 of 40 injections), and a kill in the header write left `run.h5.<pid>.tmp`.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from protocols.leftovers import dead_leftovers
from protocols.recording import Recording
from test_enospc_injection import IMPORT, RUN, _forked, _forked_calls, forked  # noqa: F401 (a fixture)
import pytest

pytestmark = pytest.mark.slow




def _killed(forked, args: list[str], cwd: Path, call: str, n: int) -> int:
    """`rig *args` forked from the fork server (tests/forked_rig.py) and killed by the kernel at its N-th `call`."""
    forked.warm_once(args, cwd)
    strace = ["-o", "/dev/null", "-e", f"trace={call}", "-e", f"inject={call}:signal=KILL:when={n}"]
    return forked.run(args, cwd, strace).returncode


def _main_writes(forked, args: list[str], cwd: Path) -> int:
    """The writes of the rig process itself (strace counts each process's calls apart for `when=`)."""
    forked.warm_once(args, cwd)
    log = cwd.parent / f"{cwd.name}.strace"
    assert forked.run(args, cwd, ["-o", str(log), "-e", "trace=write"]).returncode == 0
    per_pid: dict[str, int] = {}
    for line in log.read_text().splitlines():
        if "write(" in line:
            pid = line.split()[0] if not line.startswith("write(") else "the command"
            per_pid[pid] = per_pid.get(pid, 0) + 1
    log.unlink()
    for p in list(cwd.iterdir()):
        p.unlink() if p.is_file() else None
    shutil.rmtree(cwd / "run.h5.stops", ignore_errors=True)
    return max(per_pid.values())


def _strays(cwd: Path) -> list[str]:
    top = [p.name for p in cwd.iterdir() if p.name not in ("run.h5", "run.h5.stops", "run.h5.lock")]
    stops = cwd / "run.h5.stops"
    inside = [p.name for p in stops.iterdir() if not p.name.endswith(".h5")] if stops.is_dir() else []
    return top + inside


def test_kills_during_a_run_leave_nothing_after_the_resume(tmp_path, forked):
    total = _main_writes(forked, RUN, tmp_path)
    strays = 0
    # the rig process writes the lock, the header, each stop's file, the assembled file, then two lines to stdout;
    # killed in the header, the first stop and the assembly (every index: tests/fault_matrix.py)
    for call, n in [("write", 2), ("write", 3), ("write", total - 2)]:
        assert _killed(forked, RUN, tmp_path, call, n) == -9, (call, n)
        strays += len(_strays(tmp_path))
        again = [*RUN, "--resume"] if (tmp_path / "run.h5").exists() else RUN
        p = _forked(forked, again, tmp_path)
        assert p.returncode == 0, (call, n, p.stderr)
        assert sorted(x.name for x in tmp_path.iterdir()) == ["run.h5"], (call, n, list(tmp_path.iterdir()))
        with Recording(tmp_path / "run.h5") as rec:
            assert rec.stop_labels() == ["0.500m", "1.000m", "1.500m"] and "ended_utc" in rec.attrs
        (tmp_path / "run.h5").unlink()
    assert strays > 0  # the kills did leave something behind, which the next run removed


def test_a_killed_import_is_cleaned_up_by_the_next_import(tmp_path, forked):
    total = _forked_calls(forked, IMPORT, tmp_path)["pwrite64"]  # the provenance, written into the import's temp file
    assert _killed(forked, IMPORT, tmp_path, "pwrite64", total // 2) == -9
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left and all(".importing" in name for name in left), left
    p = _forked(forked, IMPORT, tmp_path)
    assert p.returncode == 0, p.stderr
    assert sorted(x.name for x in tmp_path.iterdir()) == ["d.h5"]


def test_a_live_writer_s_files_are_never_taken_for_leftovers(tmp_path):
    out = tmp_path / "run.h5"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    mine = [tmp_path / f".run.h5.{os.getpid()}.assembling", tmp_path / f"run.h5.{os.getpid()}.tmp"]
    theirs = [tmp_path / f".run.h5.{dead.pid}.assembling", tmp_path / f"run.h5.{dead.pid}.tmp",
              tmp_path / f".run.h5.{dead.pid}.importing", tmp_path / f".run.h5.{dead.pid}.importing.lock",
              tmp_path / f"..run.h5.{dead.pid}.importing.{dead.pid}.assembling",
              tmp_path / "run.h5.stops" / f"0.500m.h5.{dead.pid}.tmp"]
    (tmp_path / "run.h5.stops").mkdir()
    for p in mine + theirs + [tmp_path / ".other.h5.1.assembling"]:
        p.write_bytes(b"x")
    assert sorted(dead_leftovers(out)) == sorted(theirs)
