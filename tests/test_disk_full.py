"""A full disk, on a real small file system (a size-limited tmpfs: root can mount one; CI runs as root):
one line, a non-zero exit, no traceback, no segfault, every finished stop kept, and --resume finishes
once there is room. Without root, the same runs on a writer that fails with ENOSPC on cue.

A run (or import) whose whole recording does not fit is refused before it starts (tests/test_plan_check.py),
so the runs here start on a disk with room for all of it, and the disk fills while they run: after the
third stop a ballast file takes all but a little of the free space, as another program filling the disk would."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from protocols.recording import Recording
from protocols.stop_journal import journal_dir

pytestmark = pytest.mark.slow


ROOT = Path(__file__).resolve().parents[1]
CAMERA = "fake:width=106,height=60,seed=2"


def _mount(where: Path, size_kb: int) -> bool:
    where.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        return False
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(where)], capture_output=True)
    return p.returncode == 0


def _resize(where: Path, size_kb: int) -> None:
    subprocess.run(["mount", "-o", f"remount,size={size_kb}k", str(where)], check=True)


@pytest.fixture
def small_disk(tmp_path):
    """(folder on a small file system, resize function) or (folder, None) where a tmpfs cannot be mounted."""
    where = tmp_path / "disk"
    mounted = _mount(where, 20_000)
    yield where, (lambda kb: _resize(where, kb)) if mounted else None
    if mounted:
        subprocess.run(["umount", "-l", str(where)])


#: the command in a process whose writes fail as on a full disk. "budget N" (without root): writes of stop files
#: fail with ENOSPC after N bytes. "ballast N:LEAVE" (on a real small disk): once N stop files are written, a
#: file named ballast beside the output takes all the free space but LEAVE bytes.
INJECTED = textwrap.dedent('''
    import errno, shutil, sys
    sys.path.insert(0, {root!r})
    from protocols import disk_space, stop_journal
    mode, arg = sys.argv[1], sys.argv[2]
    real_write, real_commit = stop_journal.write_bytes_durably, stop_journal.commit
    if mode == "budget":
        budget = [int(arg)]
        def write(data, final):
            if len(data) > budget[0]:
                raise OSError(errno.ENOSPC, "No space left on device", str(final))
            budget[0] -= len(data)
            return real_write(data, final)
        stop_journal.write_bytes_durably = write
        disk_space.free_bytes = lambda path: 10**12  # the checks before the run and each stop pass; the write fails
    else:
        n, leave = (int(x) for x in arg.split(":"))
        stops = [0]
        def fill_after(final):
            if final.parent.name.endswith(".stops"):
                stops[0] += 1
                if stops[0] == n:
                    free = shutil.disk_usage(final.parent).free
                    with open(final.parent.parent / "ballast", "wb") as f:
                        f.write(bytes(max(0, free - leave)))
        def write(data, final):
            real_write(data, final)
            fill_after(final)
        def commit(tmp, final):
            real_commit(tmp, final)
            fill_after(final)
        stop_journal.write_bytes_durably, stop_journal.commit = write, commit
    from rig.cli import main
    sys.exit(main(sys.argv[3:]))
''')


def rig(*args: str, budget: int | None = None, ballast: str | None = None) -> subprocess.CompletedProcess:
    if budget is None and ballast is None:
        cmd = [sys.executable, "-c", "import sys; from rig.cli import main; sys.exit(main(sys.argv[1:]))", *args]
    else:
        mode = ["budget", str(budget)] if budget is not None else ["ballast", ballast]
        cmd = [sys.executable, "-c", INJECTED.format(root=str(ROOT)), *mode, *args]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)


def test_a_run_that_fills_the_disk_stops_with_one_line_and_resumes(small_disk):
    where, resize = small_disk
    out = where / "run.h5"
    args = ["run", "--protocol", "perpendicular", "--camera", CAMERA, "--stage", "fake:", "--frames", "20", "-o", str(out)]
    p = rig(*args, budget=1_200_000) if resize is None else rig(*args, ballast="3:1200000")
    assert p.returncode == 2, (p.returncode, p.stderr)  # not 139 (a segfault), not a traceback
    assert "Traceback" not in p.stderr, p.stderr
    msg = p.stderr.strip().splitlines()[-1]  # progress lines above it, then the one line that says what happened
    assert "disk full at stop" in msg and "of 11" in msg and "--resume" in msg and "MB" in msg, msg
    saved = int(re.search(r"(\d+) of 11 stops are saved", msg).group(1))
    assert saved >= 1
    with Recording(out) as rec:
        assert len(rec.stop_labels()) == saved and rec.skipped == []
        for label in rec.stop_labels():
            rec.stop(label)
    if resize:
        (where / "ballast").unlink()  # room again
    p = rig(*args, "--resume")
    assert p.returncode == 0, p.stderr
    with Recording(out) as rec:
        assert len(rec.stop_labels()) == 11 and rec.assembled
    assert not journal_dir(out).exists()


def test_an_import_that_fills_the_disk_leaves_nothing(small_disk, tmp_path):
    from simrig import record_perpendicular
    from test_import import dump

    where, resize = small_disk
    live = tmp_path / "live.h5"
    record_perpendicular(live, seed=3, width=106, frames=8, stops_m=[0.5, 1.0, 1.5, 2.0, 2.5, 3.0], keep_raw=True)
    src = dump(live, tmp_path / "frames")
    out = where / "wall.h5"
    if resize is None:
        p = rig("import", str(src), "-o", str(out), budget=600_000)
    else:
        p = rig("import", str(src), "-o", str(out), ballast="3:600000")
        (where / "ballast").unlink()
    assert p.returncode == 2, (p.returncode, p.stderr)
    assert "Traceback" not in p.stderr and "disk full at stop" in p.stderr.strip().splitlines()[-1], p.stderr
    assert "free about" in p.stderr and "stop 1 of" not in p.stderr  # it stopped part-way, not before starting
    assert list(where.iterdir()) == [], list(where.iterdir())  # no hidden temporary file left filling the disk


def test_a_report_that_fills_the_disk_is_one_line_and_keeps_the_old_one(small_disk, tmp_path, monkeypatch, capsys):
    import errno

    from rig.cli import main
    from rig.simulation.scenarios import hidden_scenario, record_scenario

    where, resize = small_disk
    rec = record_scenario(hidden_scenario(5, "censoring", width=40, frames=12), tmp_path / "c.h5")
    out = where / "report"
    out.mkdir()
    (out / "diagnosis.html").write_text("the previous report")
    if resize:
        resize(120)  # room for the old report, not for six plots
    else:
        from rig.reports import diagnosis_plots

        def full(*a, **k):
            raise OSError(errno.ENOSPC, "No space left on device", str(out / "diagnosis-residuals.png"))
        monkeypatch.setattr(diagnosis_plots, "write_plots", full)
    assert main(["diagnose", str(rec), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rig: error: disk full") and "free some space" in err[0], err
    assert (out / "diagnosis.html").read_text() == "the previous report"  # the old report whole, nothing mixed in
    assert sorted(p.name for p in where.iterdir()) == ["report"]  # the work folder removed
