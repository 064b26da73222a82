"""Can an output be written? Asked before long work starts, so a report is never lost at the end of it.

The answer comes from the file system, about the folder the output goes to or, when that folder does not exist yet,
the nearest folder above it that does: access(2) for writing and searching (which also answers EROFS on a read-only
file system, for root too), and statvfs's read-only flag. Nothing is created: a test file that a kill interrupted
would stay behind. No one can write under a path that runs through a regular file: that is asked first.
"""

from __future__ import annotations

import os
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
        read_only = bool(os.statvfs(existing).f_flag & os.ST_RDONLY)
    except OSError as e:
        return f"no file can be created in {existing} ({e.strerror or e})"
    if read_only:
        return f"no file can be created in {existing} (Read-only file system)"
    if not os.access(existing, os.W_OK | os.X_OK):
        return f"no file can be created in {existing} (Permission denied)"
    return None
