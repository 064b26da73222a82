"""Can an output be written? Asked before long work starts, so a report is never lost at the end of it.

The answer comes from trying: a test file is created (and removed) in the folder the output goes to,
or, when that folder does not exist yet, in the nearest folder above it that does. Permission bits
alone would not do: root may write anywhere except on a read-only file system, and no one can
write under a path that runs through a regular file.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def output_problem(path: str | Path, *, folder: bool = False) -> str | None:
    """Why `path` (a file, or with `folder` a folder to write files into) cannot be written; None if it can."""
    p = Path(path)
    if folder and p.exists() and not p.is_dir():
        return f"{p} is a file, not a folder"
    if not folder and p.is_dir():
        return f"{p} is a folder, not a file"
    if not folder and p.exists() and not os.access(p, os.W_OK):
        return f"{p} exists and is read-only"
    where = p if folder else p.parent
    existing = where
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        return f"{existing} is a file, not a folder" if existing == where else f"{existing} is a file, so {where} cannot be made"
    try:
        fd, name = tempfile.mkstemp(prefix=".rig-write-test-", dir=existing)
    except OSError as e:
        return f"no file can be created in {existing} ({e.strerror or e})"
    os.close(fd)
    os.unlink(name)
    return None
