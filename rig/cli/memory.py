"""How the process's memory allocator returns memory, for the commands that are judged by their peak."""

from __future__ import annotations


def return_large_blocks_at_once() -> None:
    """For reading a recording stop after stop in a command judged by its peak memory (rig fit): glibc keeps freed
    blocks of the size of a stop's arrays on its heap once it has seen a few (its mmap threshold rises by itself), so
    the reading holds ~35 MB it no longer uses. A fixed 1 MB threshold gives blocks that large back when they are
    freed (on a full sweep: 478 -> 444 MB after reading and fitting, for 0.5 s more of page faults). Not for the
    work after the reading (`keep_large_blocks`). Elsewhere than glibc: nothing."""
    _mmap_threshold(1 << 20)


def keep_large_blocks() -> None:
    """After the reading: blocks up to 32 MB stay on the heap when freed. The work that visits every pixel again
    (the headline's residuals, in pieces and per stop) would otherwise map and fault in fresh pages for every block
    above 1 MB: 1.6 GB of page faults a pass on a full sweep, 1.5 s of its 4 s (measured: 2.3 s and 7,000 faults
    against 4.0 s and 414,000), for the same peak (+35 MB either way)."""
    _mmap_threshold(32 << 20)


def _mmap_threshold(size: int) -> None:
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt(-3, size)  # M_MMAP_THRESHOLD
    except (OSError, AttributeError):
        pass
