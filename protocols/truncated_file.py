"""Reading a recording whose end is missing (a copy cut short, a disk that filled under another program).

HDF5 refuses a file shorter than the length its superblock stores ("truncated file: eof = N, ..., stored_eof = M").
`open_truncated` opens it read-only through a file object that reads the bytes that are there and zeros past them,
so every object whose bytes survive reads as it was; an object reaching into the missing end fails its checksum
(Fletcher-32 on every statistics dataset, HDF5's own on its metadata), and readers skip that stop as they skip any
damaged one. The file on disk is not touched. Where the missing end holds what indexes the stops, none can be found,
and `truncated_words` says so.
"""

from __future__ import annotations

import io
import os
import re
from pathlib import Path

import h5py

from .recording_errors import RecordingError

#: what a truncated file whose header or index of stops is in the missing end has lost
LOST_INDEX = ("its header or the index of its stops is in the missing end, so no stop can be found: restore it from a "
              "copy, or record again (docs/reliability.md)")
_TRUNCATED = re.compile(r"truncated file: eof = (\d+).*stored_eof = (\d+)")


class ZeroPaddedFile(io.RawIOBase):
    """The file at `path` read-only, `length` bytes long: its own bytes, then zeros."""

    def __init__(self, path: str | Path, length: int):
        self._f = open(path, "rb")
        self._length = length
        self._pos = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        base = {os.SEEK_SET: 0, os.SEEK_CUR: self._pos, os.SEEK_END: self._length}[whence]
        self._pos = base + offset
        return self._pos

    def tell(self) -> int:
        return self._pos

    def readinto(self, buffer) -> int:
        want = max(0, min(len(buffer), self._length - self._pos))
        self._f.seek(self._pos)
        got = self._f.readinto(memoryview(buffer)[:want]) or 0
        memoryview(buffer)[got:want] = bytes(want - got)
        self._pos += want
        return want

    def close(self) -> None:
        self._f.close()
        super().close()


def truncation(e: OSError) -> tuple[int, int] | None:
    """(bytes there, bytes the file should have) from HDF5's "truncated file" error; None for another error."""
    m = _TRUNCATED.search(str(e))
    return (int(m.group(1)), int(m.group(2))) if m else None


def open_hdf5(path: Path) -> tuple[h5py.File, tuple[int, int] | None]:
    """The HDF5 file at `path` opened read-only, and None; or, truncated, opened as if it were its stored length long
    (zeros past its end) and (bytes there, bytes it should have). A RecordingError for a file that is not HDF5."""
    try:
        return h5py.File(path, "r"), None
    except OSError as e:
        cut = truncation(e)
        if cut is None:
            raise RecordingError(f"{path} is not an HDF5 file ({e}); pass a recording written by rig run or rig "
                                 "import") from None
    try:
        return h5py.File(ZeroPaddedFile(path, cut[1]), "r"), cut
    except OSError:
        raise RecordingError(truncated_words(path, *cut, LOST_INDEX)) from None


def truncated_words(path: str | Path, have: int, want: int, lost: str) -> str:
    """What a truncated file holds, in one line: how much is there and what is lost (`lost`)."""
    return f"{path} is truncated: {have:,} of its {want:,} bytes are there ({100 * have / want:.0f} %); {lost}"
