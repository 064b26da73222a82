"""A full disk at any write of `rig run` and `rig import`, injected by the kernel: one line, keeps what is saved, no stray file.

The disk is filled by the kernel, not by us: strace injects ENOSPC into one system call of the real command
(`strace -f -e inject=pwrite64:error=ENOSPC:when=N`), h5py's and Python's writes alike; the command is forked from
one process that has imported rig and run it once (tests/forked_rig.py), and strace attaches to the fork. strace is
installed by the project's set-up (dev.py), as libusb is. Issue 28 found a 30-line h5py traceback (`RuntimeError: Unable to
synchronously copy object ... errno = 28`) at every pwrite64 of the final assembly, and a lock file left behind.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from forked_rig import ForkServer, call_counts
from protocols.recording import Recording

pytestmark = pytest.mark.slow


ROOT = Path(__file__).resolve().parents[1]
RIG = [str(Path(sys.executable).parent / "rig")]  # tests/fault_matrix.py starts the commands as processes
RUN = ["run", "--protocol", "perpendicular", "--camera", "fake:width=16,height=9,seed=1", "--stage", "fake:",
       "-o", "run.h5", "--stops", "0.5:1.5:0.5", "--frames", "5", "-q"]
BAG = ROOT / "tests" / "vendor" / "real" / "realsense" / "single_depth_color_640x480.bag"
IMPORT = ["import", str(BAG), "-o", "d.h5", "--distance-m", "1.6", "-q"]


def _strace_present() -> None:
    assert shutil.which("strace"), "strace is not installed; `python3 dev.py setup` installs it (apt-get install strace)"


def _forked(forked, args: list[str], cwd: Path, inject: tuple[str, int] | None = None,
            error: str = "ENOSPC") -> subprocess.CompletedProcess:
    """`rig *args` forked from the module's fork server (tests/forked_rig.py), with `error` injected at the N-th
    `call` of `inject`; the server runs each command once in itself first (on a copy of `cwd`)."""
    _strace_present()
    forked.warm_once(args, cwd)
    strace = None
    if inject is not None:
        call, n = inject
        strace = ["-o", "/dev/null", "-e", f"trace={call}", "-e", f"inject={call}:error={error}:when={n}"]
    return forked.run(args, cwd, strace)


def _forked_calls(forked, args: list[str], cwd: Path) -> dict[str, int]:
    """How many times the forked command makes each of write and pwrite64 on a disk with room (one traced run); what
    it wrote is removed."""
    forked.warm_once(args, cwd)
    log = cwd.parent / f"{cwd.name}.strace"
    before = set(cwd.iterdir())
    assert forked.run(args, cwd, ["-o", str(log), "-e", "trace=write,pwrite64"]).returncode == 0
    lines = log.read_text().splitlines()
    log.unlink()
    for p in set(cwd.iterdir()) - before:
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    return call_counts(lines, ("write", "pwrite64"))


@pytest.fixture(scope="module")
def forked():
    """One process that has imported rig, to fork the trials from (tests/forked_rig.py): each trial then costs the
    command, not an interpreter's start-up too (the import's 16 trials: ~13 s of CPU as processes of their own)."""
    server = ForkServer()
    yield server
    server.close()


def _complete(path: Path) -> bool:
    if not path.exists():
        return False
    with Recording(path) as rec:
        return "ended_utc" in rec.attrs and not rec.skipped


def _one_line(p: subprocess.CompletedProcess) -> str:
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "Traceback" not in p.stderr, (p.returncode, p.stderr[-2000:])
    assert lines[0].startswith("rig: error: ") and ("disk full" in lines[0] or "no space" in lines[0]), lines[0]
    return lines[0]


def test_a_full_disk_at_every_write_of_a_run_is_one_line_and_resume_finishes_it(tmp_path, forked):
    """Every write and pwrite64 of a small run (HDF5's own writes included: it assembles in memory, and Python
    writes the file; on disk, HDF5 1.14 segfaulted in close() after ENOSPC at one pwrite64 of 69)."""
    calls = [(call, n) for call, total in _forked_calls(forked, RUN, tmp_path).items() for n in range(1, total + 1)]
    assert len(calls) >= 5
    refused = 0
    for inject in calls:
        p = _forked(forked, RUN, tmp_path, inject)
        refused += p.returncode != 0
        left = sorted(x.name for x in tmp_path.iterdir())
        if p.returncode == 0 or _complete(tmp_path / "run.h5"):  # the fault hit stdout, after the recording was whole
            assert left == ["run.h5"], (inject, left)
            if p.returncode:
                _one_line(p)
        else:
            line = _one_line(p)
            assert set(left) <= {"run.h5", "run.h5.stops"}, (inject, left)  # no lock, no .assembling, no .tmp
            if "run.h5" in left:
                assert "--resume" in line and ("of 3 stops are saved" in line or "assembling" in line), line
                assert _forked(forked, [*RUN, "--resume"], tmp_path).returncode == 0
            else:
                assert "run the command again" in line, line
                assert _forked(forked, RUN, tmp_path).returncode == 0
        with Recording(tmp_path / "run.h5") as rec:
            assert rec.stop_labels() == ["0.500m", "1.000m", "1.500m"] and "ended_utc" in rec.attrs, inject
        assert sorted(x.name for x in tmp_path.iterdir()) == ["run.h5"], inject
        (tmp_path / "run.h5").unlink()
    assert refused >= len(calls) - 2, (refused, len(calls))  # the faults took effect (8 of 9 here; strace 6.1)


def test_a_full_disk_at_every_write_of_an_import_is_one_line_and_leaves_nothing(tmp_path, forked):
    # every write; of the provenance's pwrite64s (HDF5 writing into the import's temporary file) the first and last
    # (every index: tests/fault_matrix.py)
    total = _forked_calls(forked, IMPORT, tmp_path)
    calls = [("write", n) for n in range(1, total["write"] + 1)] + [("pwrite64", 1), ("pwrite64", total["pwrite64"])]
    assert len(calls) >= 5
    refused = 0
    for call, n in calls:
        inject = (call, n)
        p = _forked(forked, IMPORT, tmp_path, inject)
        refused += p.returncode != 0
        left = sorted(x.name for x in tmp_path.iterdir())
        if p.returncode == 0 or _complete(tmp_path / "d.h5"):  # the fault hit stdout, after the import was whole
            assert left == ["d.h5"], (inject, left)
            if p.returncode:
                _one_line(p)
            (tmp_path / "d.h5").unlink()
            continue
        line = _one_line(p)
        assert "nothing was written; free" in line and line.endswith(" and import again"), (inject, line)
        assert left == [], (inject, left)
    assert refused >= len(calls) - 2, (refused, len(calls))  # the faults took effect (8 of 9 here; strace 6.1)


def test_a_full_disk_while_diagnose_writes_its_report_is_one_line_and_leaves_no_empty_folder(tmp_path, forked):
    """Issue 28: a full disk left an empty report folder from `rig diagnose --out`."""
    assert _forked(forked, RUN, tmp_path).returncode == 0
    for n in (1, 4):  # the first plot, and the page written after the three plots (each written in one call)
        # one process (--jobs 1): with a pool, its pipes' writes come first, in no fixed order across processes
        p = _forked(forked, ["diagnose", "run.h5", "--out", "rep", "-q", "--jobs", "1"], tmp_path, ("write", n))
        _one_line(p)
        assert sorted(x.name for x in tmp_path.iterdir()) == ["run.h5"], (n, list(tmp_path.iterdir()))


def test_an_io_error_is_one_line_naming_what_is_saved(tmp_path, forked):
    """EIO (a failing disk, a pulled USB drive) at the header, at a stop's file, and in an import's provenance."""
    for n, saved in ((2, "nothing was recorded"), (5, "2 of 3 stops are saved in run.h5; re-run the same command with --resume")):
        p = _forked(forked, RUN, tmp_path, ("write", n), "EIO")
        lines = p.stderr.strip().splitlines()
        assert p.returncode == 2 and len(lines) == 1 and "Traceback" not in p.stderr, p.stderr[-1500:]
        assert lines[0].startswith("rig: error: writing run.h5 failed (Input/output error); check the disk") and saved in lines[0]
        if (tmp_path / "run.h5").exists():
            assert _forked(forked, [*RUN, "--resume"], tmp_path).returncode == 0
            (tmp_path / "run.h5").unlink()
    p = _forked(forked, IMPORT, tmp_path, ("pwrite64", 1), "EIO")
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "nothing was written" in lines[0], p.stderr[-1500:]
    assert list(tmp_path.iterdir()) == []
