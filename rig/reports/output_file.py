"""Writing a report's files: text a person reads whatever bytes a file name held, and whole files or none.

A file name on Linux is bytes; Python hands an undecodable byte to rig as a lone surrogate (PEP 383), which neither
UTF-8 nor matplotlib's font engine accepts. `shown` writes such a byte as \\xNN, as `ls -b` does. A file is written
beside its final path and renamed over it (`aside`), so a kill or a full disk leaves the old file or none, never a
part of one.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import io
import os
from pathlib import Path
from typing import Any, Iterator

from protocols.run_lock import alive
from protocols.stop_journal import fsync_file


def shown(text: str) -> str:
    """`text` with each undecodable byte of a file name (a lone surrogate) written as \\xNN."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


@contextlib.contextmanager
def aside(path: str | Path) -> Iterator[Path]:
    """A path to write `path`'s new content to; the content replaces `path` when the block ends, and nothing of it is
    left if the block raises or the process is killed while writing.

    On Linux the content goes to a file with no name (O_TMPFILE in `path`'s folder, yielded as /proc/self/fd/N), which
    is linked as `.NAME.PID.writing` and renamed over `path` at the end: a kill before the link leaves nothing, a kill
    between the link and the rename leaves that one file, which the next write of `path` removes (its PID is gone).
    Elsewhere the named file is written directly. Writers get it as a file object (`open(tmp, "wb")`): one given the
    /proc path may resolve it to the file's old name and write a new file there (tifffile does)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.writing")
    _remove_dead_leftovers(path)
    fd = _unnamed_file(path.parent)
    try:
        yield Path(f"/proc/self/fd/{fd}") if fd is not None else tmp
        if fd is not None:  # the data on the disk before the name (a power cut leaves the old file or the new)
            os.fsync(fd)
        else:
            fsync_file(tmp)
        if fd is not None:  # linkat(..., AT_SYMLINK_FOLLOW): CPython calls link(2), which would not follow it, unless
            folder = os.open(path.parent, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))  # a dir_fd is given
            try:
                os.link(f"/proc/self/fd/{fd}", tmp.name, dst_dir_fd=folder, follow_symlinks=True)
            finally:
                os.close(folder)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    finally:
        if fd is not None:
            os.close(fd)


def _unnamed_file(folder: Path) -> int | None:
    """A writable file with no name in `folder` (O_TMPFILE), or None where the system or file system has none."""
    flag = getattr(os, "O_TMPFILE", None)
    if flag is None or not os.path.isdir("/proc/self/fd"):
        return None
    try:
        return os.open(folder, flag | os.O_WRONLY, 0o644)
    except OSError as e:
        if e.errno in (errno.EOPNOTSUPP, errno.EISDIR, errno.EINVAL, errno.ENOENT):
            return None
        raise


def _remove_dead_leftovers(path: Path) -> None:
    """`.NAME.PID.writing` beside `path` from a process that is gone (killed between its link and its rename)."""
    for old in path.parent.glob(f".{glob.escape(path.name)}.*.writing"):
        pid = old.name[len(path.name) + 2:-len(".writing")]
        if pid.isdigit() and not alive(int(pid)):
            with contextlib.suppress(OSError):
                old.unlink()


def save_figure(fig: Any, path: str | Path, **savefig: Any) -> Path:
    """A matplotlib figure saved to `path` (its format from the suffix), its texts `shown`, whole or not at all."""
    import matplotlib.text

    for t in fig.findobj(matplotlib.text.Text):
        text = t.get_text()
        if text and text != shown(text):
            t.set_text(shown(text))
    path = Path(path)
    image = io.BytesIO()  # drawn whole first, then written in one call (matplotlib writes a PNG in three)
    fig.savefig(image, format=path.suffix.lstrip(".") or "png", **savefig)
    with aside(path) as tmp, open(tmp, "wb") as f:  # a file object: a writer given a path may resolve it
        f.write(image.getbuffer())
    return path


def write_text(path: str | Path, text: str) -> Path:
    """`text` (UTF-8, file names `shown`) written to `path`, whole or not at all."""
    path = Path(path)
    with aside(path) as tmp:
        tmp.write_text(shown(text), encoding="utf-8")
    return path
