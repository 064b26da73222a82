"""A small simulated run that SIGKILLs itself at an exact instant (for tests/test_crash_safety.py).

    python tests/crash_child.py OUT.h5 POINT N [--raw] [--resume] [--stops 0.5,1.0,...] [--on-disk-assembly]

POINT is a function the writer calls (wrapped here, in this test process only: nothing in rig
knows about it) and N which call of it dies: the process kills itself just *before* the call
("before:NAME") or just *after* it returns ("after:NAME"), or "none". Every stop the runner
reports done is printed as "done LABEL" (flushed) before the run moves on.
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


def main() -> None:
    out, point, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
    raw, resume = "--raw" in sys.argv, "--resume" in sys.argv
    devices = open_devices("fake:width=16,height=9,seed=5", "fake:")
    stops = {} if "--stops" not in sys.argv else {"stops_m": [float(z) for z in sys.argv[sys.argv.index("--stops") + 1].split(",")]}
    plan = perpendicular(frames_per_stop=6, keep_raw=raw, **stops)

    def progress(e):
        if e.kind == "stop_done":
            print(f"done {e.stop}", flush=True)

    if "--on-disk-assembly" in sys.argv:  # as for a recording too big to assemble in memory
        recording_writer.IN_MEMORY_ASSEMBLY_BYTES = 0
    if point != "none":
        arm(point, n)
    Runner(devices.camera, devices.stage, sleep=lambda s: None, progress=progress).run(plan, out, resume=resume)
    print("finished", flush=True)


if __name__ == "__main__":
    main()
