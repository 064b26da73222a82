"""How much disk a stop needs, how much there is, and what a full disk looks like when it happens anyway.

A stop's file holds per-pixel statistics (count uint32, mean and three moment sums float64: 36
bytes a pixel), the mean IR images (float32, 4 bytes a pixel each), eight per-frame series
(about 45 bytes a frame) and, with raw frames kept, 2 bytes a pixel a frame. The statistics are
gzip-compressed, and gzip never grows data by more than a few bytes a block, so the uncompressed
size plus a margin is an upper bound: checked before each stop, a full disk is found before
anything is written.
"""

from __future__ import annotations

import errno
import shutil
from pathlib import Path

#: per-file overhead of HDF5 (superblock, object headers, B-trees), bytes; generous
FILE_OVERHEAD_BYTES = 256 * 1024
#: free space kept on top of what a stop (or a whole run) needs: the assembly at the end needs its own room
RESERVE_BYTES = 1024 * 1024


def stop_bytes(shape: tuple[int, int], n_frames: int, *, keep_raw: bool = False, ir: bool = True,
               ambient: bool = True) -> int:
    """Upper bound on a stop's file size, bytes."""
    pixels = int(shape[0]) * int(shape[1])
    per_pixel = 4 + 4 * 8 + (8 if ir else 0) + (4 if ambient else 0)  # ir: ir_mean and ir_saturated
    raw = 2 * pixels * int(n_frames) if keep_raw else 0
    return int(1.01 * (pixels * per_pixel + raw)) + 45 * int(n_frames) + FILE_OVERHEAD_BYTES


def free_bytes(path: Path) -> int:
    """Free bytes on the file system that holds `path` (or its nearest existing parent)."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free


def is_disk_full(e: BaseException) -> bool:
    """An OSError (or h5py's error) that means no space or quota is left."""
    if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(e)
    return "No space left" in text or "errno = 28" in text or "Disk quota exceeded" in text


def is_storage_failure(e: BaseException) -> bool:
    """An OSError (or h5py's error) from the storage itself: an I/O error, a file system gone read-only."""
    if isinstance(e, OSError) and e.errno in (errno.EIO, errno.EROFS):
        return True
    text = str(e)
    return "Input/output error" in text or "errno = 5," in text or "Read-only file system" in text


def megabytes(n: int) -> str:
    return f"{max(1, round(n / 1e6))} MB"


def size_text(n: int) -> str:
    """A size for people: MB below 10 GB, GB above."""
    return megabytes(n) if n < 10e9 else f"{n / 1e9:.0f} GB"
