"""A small simulated run that SIGKILLs itself at an exact instant (for tests/test_crash_safety.py).

    python tests/crash_child.py OUT.h5 POINT N [--raw] [--resume] [--stops 0.5,1.0,...] [--on-disk-assembly]

POINT is a function the writer calls (wrapped here, in this test process only: nothing in rig
knows about it) and N which call of it dies: the process kills itself just *before* the call
("before:NAME") or just *after* it returns ("after:NAME"), or "none". Every stop the runner
reports done is printed as "done LABEL" (flushed) before the run moves on.

tests/test_crash_safety.py runs it as a fork of a process that has imported it once (`run_in_fork`, through
tests/crash_server.py): the same code, without paying for the imports in each of its ~75 trials.
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

import h5py

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocols import recording_writer, stop_journal  # noqa: E402
from protocols.perpendicular import perpendicular  # noqa: E402
from protocols.runner import Runner  # noqa: E402
from rig.devices import open_devices  # noqa: E402

#: where a kill can land: (module, attribute) of the calls the writer makes
POINTS = {
    "write_bytes_durably": (stop_journal, "write_bytes_durably"),  # the header and each in-memory stop
    "commit": (stop_journal, "commit"),  # a raw stop's partial file, and the assembled file
    "replace": (os, "replace"),  # the atomic rename itself
    "fsync_dir": (stop_journal, "fsync_dir"),
    "h5_flush": (h5py.File, "flush"),  # HDF5's flush, inside every stop and the assembly
    "h5_close": (h5py.File, "close"),
    "h5_copy": (h5py.Group, "copy"),  # the assembly copying one stop
    "copyfile": (recording_writer.shutil, "copyfile"),  # the assembly's copy of the header
    "rmtree": (recording_writer.shutil, "rmtree"),  # removing the stop files after assembly
}


def arm(point: str, n: int) -> None:
    when, name = point.split(":")
    owner, attr = POINTS[name]
    original = getattr(owner, attr)
    calls = [0]

    def wrapped(*args, **kw):
        calls[0] += 1
        if calls[0] == n and when == "before":
            os.kill(os.getpid(), signal.SIGKILL)
        out = original(*args, **kw)
        if calls[0] == n and when == "after":
            os.kill(os.getpid(), signal.SIGKILL)
        return out

    setattr(owner, attr, wrapped)


def main(argv: list[str], say=lambda line: print(line, flush=True)) -> None:
    out, point, n = argv[0], argv[1], int(argv[2])
    raw, resume = "--raw" in argv, "--resume" in argv
    devices = open_devices("fake:width=16,height=9,seed=5", "fake:")
    stops = {} if "--stops" not in argv else {"stops_m": [float(z) for z in argv[argv.index("--stops") + 1].split(",")]}
    plan = perpendicular(frames_per_stop=6, keep_raw=raw, **stops)

    def progress(e):
        if e.kind == "stop_done":
            say(f"done {e.stop}")

    if "--on-disk-assembly" in argv:  # as for a recording too big to assemble in memory
        recording_writer.IN_MEMORY_ASSEMBLY_BYTES = 0
    if point != "none":
        arm(point, n)
    Runner(devices.camera, devices.stage, sleep=lambda s: None, progress=progress).run(plan, out, resume=resume)
    say("finished")


def run_in_fork(argv: list[str], conn) -> None:
    """`main` in a forked process, its lines sent through `conn` (a multiprocessing Connection) as they come; an
    exception is sent as one "error ..." line with its traceback, and the process exits 1."""
    import traceback

    try:
        assert os.environ.get("NUMBA_DISABLE_JIT") == "1", "not forked from tests/crash_server.py's process"
        main(argv, conn.send)
    except BaseException:
        conn.send("error " + traceback.format_exc())
        conn.close()
        os._exit(1)
    conn.close()


if __name__ == "__main__":
    main(sys.argv[1:])
