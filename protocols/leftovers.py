"""Files a killed rig process leaves beside a recording, found by name and removed by the next writer of that path.

A process killed at the wrong instant can leave: `.run.h5.<pid>.assembling` (a full-size copy of the recording,
being assembled; recording_writer.finish), `run.h5.<pid>.tmp` (the header, or a stop file inside `run.h5.stops/`,
being written; stop_journal.write_bytes_durably), and for an import `.<out>.<pid>.importing` with its `.lock` and
`.stops` (the import's own recording, renamed into place when whole), and that recording's own assembling copy or
header being written (`..<out>.<pid>.importing.<pid>.assembling`). Each name carries the writer's PID; the next
run, resume or import of that path removes those whose process is gone (never a live one's).
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

from .run_lock import alive
from .stop_journal import journal_dir


def dead_leftovers(path: Path) -> list[Path]:
    """The leftovers of dead processes for the recording `path` (beside it and in its stop folder)."""
    name = re.escape(path.name)
    beside = re.compile(rf"^(?:\.{name}\.(?P<a>\d+)\.(?:assembling|importing(?:\.lock|\.stops)?)|{name}\.(?P<b>\d+)\.tmp"
                        rf"|\.{{1,2}}{name}\.(?P<c>\d+)\.importing\.\d+\.(?:assembling|tmp))$")
    inside = re.compile(r"^.+\.(?P<a>\d+)\.tmp$")
    found = []
    for folder, pattern in ((path.parent, beside), (journal_dir(path), inside)):
        try:
            entries = list(folder.iterdir())
        except OSError:
            continue
        for p in entries:
            m = pattern.match(p.name)
            if m and not alive(int(next(g for g in m.groups() if g))):
                found.append(p)
    return found


def remove_dead_leftovers(path: Path) -> list[Path]:
    """Remove the leftovers of dead processes for `path`; return what was removed."""
    removed = []
    for p in dead_leftovers(path):
        try:
            shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
            removed.append(p)
        except FileNotFoundError:
            pass
    return removed
