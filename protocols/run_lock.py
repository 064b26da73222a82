"""One writer per recording: a lock file beside it, holding the writer's PID, host and start time.

HDF5's own file locking is often off (NFS, HDF5_USE_FILE_LOCKING=FALSE), and then two writers
both report success and corrupt the file. `run.h5.lock` is created with its content at once (written to a file of
its own, then hard-linked to the lock's name: atomic, as O_CREAT | O_EXCL, on local file systems and on NFS), so no
other writer ever reads an empty lock and takes it for stale; a lock whose process is gone (same host, PID not
alive) is stale and taken over. Readers use `holder()` to say that a file is still being written.
"""

from __future__ import annotations

import datetime as _dt
import errno
import json
import os
import socket
import threading
import time
from pathlib import Path

from .disk_space import is_disk_full
from .recording_errors import RecordingError


def lock_path(path: Path) -> Path:
    return path.with_name(path.name + ".lock")


def alive(pid: int) -> bool:
    """A process with this PID exists on this host (one we may not signal counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def holder(path: Path) -> dict | None:
    """Who holds the lock on `path` (pid, host, started_utc), if a live process does."""
    lp = lock_path(Path(path))
    try:
        info = json.loads(lp.read_text())
        pid, host = int(info["pid"]), str(info["host"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if host == socket.gethostname() and not alive(pid):
        return None
    return info


#: a lock file this young whose content cannot be read is being written now (the O_EXCL path), not stale, s
FRESH_S = 60.0


def _being_written(file: Path) -> bool:
    """The lock exists, its content cannot be read, and it was made less than FRESH_S ago."""
    try:
        json.loads(file.read_text())["pid"]
        return False
    except (OSError, ValueError, KeyError, TypeError):
        pass
    try:
        return time.time() - file.stat().st_mtime < FRESH_S
    except OSError:
        return False


class RunLock:
    """`with RunLock(path):` or acquire()/release()."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.file = lock_path(self.path)
        self.held = False

    def acquire(self) -> "RunLock":
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "started_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise self.unwritable(e) from None
        for _ in range(2):
            try:
                self._create(info)
            except FileExistsError:
                who = holder(self.path)
                if who is None and _being_written(self.file):
                    who = {"pid": "?", "host": "this or another host", "started_utc": "just now"}
                if who is not None:
                    raise RecordingError(
                        f"{self.path} is being written by PID {who['pid']} on {who['host']} (since {who.get('started_utc', '?')}); "
                        f"wait for that run to end or stop it (a stale lock is {self.file})") from None
                self.file.unlink(missing_ok=True)  # stale: its process is gone
                continue
            except OSError as e:
                if is_disk_full(e):  # a full disk: no lock left behind, and one line
                    raise RecordingError(f"cannot write {self.path}: no space for its lock file in {self.path.parent} "
                                         f"({e.strerror or type(e).__name__}); free some space and run the command "
                                         "again") from None
                raise self.unwritable(e) from None  # the folder cannot hold files: nor could the output
            self.held = True
            return self
        raise RecordingError(f"could not take the lock {self.file}; remove it if no run is writing {self.path}")

    def _create(self, info: dict) -> None:
        """The lock file, created with its content at once: written to a file of this process's own, then hard-linked
        to the lock's name, which fails if the lock exists (atomic, as O_EXCL, also on NFS). Where the file system
        has no hard links (FAT, exFAT) it is created with O_EXCL and then written: `_being_written` covers that
        moment. FileExistsError when the lock exists."""
        own = self.file.with_name(f"{self.file.name}.{os.getpid()}.{threading.get_ident()}")
        try:
            with open(own, "w") as f:
                json.dump(info, f)
            try:
                os.link(own, self.file)
                return
            except FileExistsError:
                raise
            except OSError as e:
                if e.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK):
                    raise
        finally:
            own.unlink(missing_ok=True)
        fd = os.open(self.file, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        try:
            with os.fdopen(fd, "w") as f:
                json.dump(info, f)
        except OSError:
            self.file.unlink(missing_ok=True)
            raise

    def unwritable(self, e: OSError) -> RecordingError:
        """The output cannot be written where it is (the lock beside it is the first file a run creates)."""
        why = e.strerror or type(e).__name__
        return RecordingError(f"cannot write {self.path}: no file can be created in {self.path.parent} ({why}); choose "
                              f"an output in a folder you can write, e.g. -o {Path.home() / 'rig-output' / self.path.name}")

    def release(self) -> None:
        if self.held:
            self.file.unlink(missing_ok=True)
            self.held = False

    def __enter__(self) -> "RunLock":
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
