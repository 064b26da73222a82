"""Every output rig writes goes through rig.reports.output_file.aside (issue 52): whole or not at all.

A process killed while writing (os._exit in a forked child, no clean-up of any kind) leaves the old file and nothing
else; one that fails (a full disk) leaves the old file and nothing else; a leftover of a process killed between its
link and its rename is removed by the next write. The strace sweep over real commands (kills and ENOSPC at every
write, fsync, rename, unlink and linkat of rig export, fit --table/--plot/--report and compare --report) is in the
issue's closing note; this is its quick form.
"""

from __future__ import annotations

import os

import pytest

from rig.reports.output_file import aside, write_text


def test_a_process_killed_while_writing_leaves_the_old_file_and_nothing_else(tmp_path):
    out = tmp_path / "m.json"
    out.write_text("old")
    pid = os.fork()
    if pid == 0:  # the child: half the new content, then gone as SIGKILL would leave it (no finally, no atexit)
        with aside(out) as tmp:
            with open(tmp, "w") as f:
                f.write('{"half": ')
                f.flush()
                os._exit(0)
    os.waitpid(pid, 0)
    assert out.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["m.json"]


def test_a_write_that_fails_leaves_the_old_file_and_nothing_else(tmp_path):
    out = tmp_path / "t.csv"
    out.write_text("old")
    with pytest.raises(OSError, match="No space"):
        with aside(out) as tmp:
            with open(tmp, "w") as f:
                f.write("new,")
                raise OSError(28, "No space left on device")
    assert out.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["t.csv"]
    write_text(out, "new")
    assert out.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["t.csv"]


def test_a_leftover_of_a_process_that_is_gone_is_removed_by_the_next_write(tmp_path):
    out = tmp_path / "p.png"
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    os.waitpid(pid, 0)  # a PID that is gone
    (tmp_path / f".p.png.{pid}.writing").write_text("half")
    live = tmp_path / f".p.png.{os.getpid()}.writing.keep"  # not ours to judge: another name
    live.write_text("x")
    write_text(out, "whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["p.png", live.name])
