"""Where a run keeps its completed stops until the recording is assembled: one small HDF5 file per stop.

    run.h5           the experiment's header (and, once assembled, every stop): only ever replaced whole,
                     by writing a copy beside it, fsync, and an atomic rename
    run.h5.stops/    one file per completed stop, <label>.h5; written as <label>.h5.partial, fsynced and
                     renamed, so a stop's file exists under its own name only once it is complete

Why (docs/reliability.md): HDF5 updates a file in place, and a process killed inside `H5Fflush`
leaves its B-trees half written; 26 of 62 kills at that instant made stops that the run had
reported done unreadable. A rename is atomic on POSIX file systems, and a file that is never
modified after its rename cannot be damaged by a later kill. Readers (`Recording`) read the
header file and the stop files together, so an interrupted run is readable as it stands;
`RecordingWriter.finish` copies the stops into a new run.h5, renames it into place, then
removes the folder.
"""

from __future__ import annotations

import os
from pathlib import Path
from urllib.parse import quote, unquote

STOP_SUFFIX = ".h5"
PARTIAL_SUFFIX = ".h5.partial"
#: the longest a stop's own file name may be, in bytes: file systems take 255, and the writer adds ".<pid>.tmp"
MAX_NAME_BYTES = 230
#: the group holding the stop inside its own file (copied to /stops/<label> on assembly)
STOP_GROUP = "stop"


def journal_dir(path: Path) -> Path:
    """The folder of completed stops beside a recording."""
    return path.with_name(path.name + ".stops")


def stop_file(path: Path, label: str) -> Path:
    return journal_dir(path) / (quote(label, safe="") + STOP_SUFFIX)


def partial_file(path: Path, label: str) -> Path:
    return journal_dir(path) / (quote(label, safe="") + PARTIAL_SUFFIX)


def completed_stop_files(path: Path) -> dict[str, Path]:
    """label -> file, for every completed stop file beside `path` (none: {})."""
    d = journal_dir(path)
    if not d.is_dir():
        return {}
    out = {}
    for p in sorted(d.iterdir()):
        if p.name.endswith(STOP_SUFFIX) and not p.name.startswith("."):
            out[unquote(p.name[: -len(STOP_SUFFIX)])] = p
    return out


def remove_partials(path: Path) -> list[str]:
    """Delete stop files that were never completed; return their labels."""
    d = journal_dir(path)
    if not d.is_dir():
        return []
    gone = []
    for p in d.iterdir():
        if p.name.endswith(PARTIAL_SUFFIX):
            p.unlink(missing_ok=True)
            gone.append(unquote(p.name[: -len(PARTIAL_SUFFIX)]))
    return gone


def fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return  # some file systems do not open directories; the rename is still atomic
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def commit(tmp: Path, final: Path) -> None:
    """Make `tmp` durable and give it the name `final` in one atomic step."""
    fsync_file(tmp)
    os.replace(tmp, final)
    fsync_dir(final.parent)


def write_bytes_durably(data: bytes, final: Path) -> None:
    """Write `data` beside `final`, fsync and rename: `final` is either absent, old, or whole."""
    tmp = final.with_name(final.name + f".{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, final)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(final.parent)
