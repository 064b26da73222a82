"""Files of depth frames: 16-bit grayscale PNGs (one frame each) and .npy arrays (a frame or a stack).

Headers are read and checked before any frame is decoded; frames are then read one at a time.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import FolderImportError
from .manifest import one_line

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_COLOUR_TYPES = {0: "grayscale", 2: "colour (RGB)", 3: "palette (colour)", 4: "grayscale+alpha", 6: "colour (RGBA)"}


@dataclass(frozen=True)
class FrameFile:
    """One file of frames: a PNG (one frame) or a .npy (one frame or a stack)."""

    path: Path
    kind: str  # "png" or "npy"
    n_frames: int
    shape: tuple[int, int]  # (height, width)
    ir: bool = False  # IR images keep uint8: their full scale (255) is where they clip (data-format.md, ir_saturated)

    def frames(self) -> Iterator[np.ndarray]:
        """The file's frames, one at a time, as uint16 (IR images: uint8 or uint16, as stored)."""
        if self.kind == "png":
            yield self._kept(_decode_png(self.path, self.shape), str(self.path))
            return
        stack = _open_npy(self.path)
        if stack.ndim == 2:
            stack = stack[np.newaxis]
        for i in range(len(stack)):
            yield self._kept(np.array(stack[i]), f"{self.path} (frame {i})")

    def _kept(self, a: np.ndarray, name: str) -> np.ndarray:
        return a if self.ir and a.dtype in (np.uint8, np.uint16) else _as_uint16(a, name)


def inspect_file(path: Path, *, ir: bool = False) -> FrameFile:
    """Read the file's header only; refuse what cannot be a depth frame (or an IR image)."""
    if path.suffix.lower() == ".png":
        return _inspect_png(path, ir=ir)
    return _inspect_npy(path, ir=ir)


def _inspect_png(path: Path, *, ir: bool) -> FrameFile:
    try:
        with open(path, "rb") as f:
            head = f.read(26)
    except OSError as e:
        raise FolderImportError(f"{path}: cannot be read ({e.strerror})") from None
    if len(head) < 26 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise FolderImportError(f"{path}: not a readable PNG file (no PNG header); remove it or replace it with the original")
    width, height, bit_depth, colour_type = struct.unpack(">IIBB", head[16:26])
    what = "IR images" if ir else "depth frames"
    if colour_type != 0:
        kind = PNG_COLOUR_TYPES.get(colour_type, f"colour type {colour_type}")
        raise FolderImportError(f"{path}: {kind} PNG; {what} must be grayscale PNGs"
                                + ("" if ir else " with 16 bits (0 = no data); move other images out of the stop folders"))
    if bit_depth != 16 and not (ir and bit_depth == 8):
        raise FolderImportError(f"{path}: {bit_depth}-bit grayscale PNG; {what} must be 16-bit"
                                + ("" if ir else " (an 8-bit image has lost the depth); export the camera's 16-bit depth"))
    return FrameFile(path, "png", 1, (height, width), ir)


def _inspect_npy(path: Path, *, ir: bool) -> FrameFile:
    a = _open_npy(path)
    if ir and a.dtype.kind not in "ui":
        raise FolderImportError(f"{path}: {a.dtype} values; .npy IR images must hold integers (uint8 or uint16)")
    if not ir and (a.dtype.kind not in "ui" or a.dtype.itemsize < 2):
        raise FolderImportError(f"{path}: {a.dtype} values; .npy depth frames must hold 16-bit integer depth counts "
                                "(uint16, 0 = no data), e.g. np.round(z_m / depth_unit_m).astype(np.uint16)")
    if a.ndim not in (2, 3):
        raise FolderImportError(f"{path}: array of shape {a.shape}; a .npy file holds one frame (H, W) or a stack (N, H, W)")
    n = 1 if a.ndim == 2 else a.shape[0]
    return FrameFile(path, "npy", n, tuple(a.shape[-2:]), ir)


def _open_npy(path: Path) -> np.ndarray:
    """Memory-map a .npy file: the header is read, the frames stay on disk until sliced."""
    try:
        return np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise FolderImportError(f"{path}: unreadable .npy file ({one_line(e)})") from None


def _decode_png(path: Path, shape: tuple[int, int]) -> np.ndarray:
    from PIL import Image  # Pillow: needed only to decode PNGs

    try:
        with Image.open(path) as im:
            im.load()
            a = np.asarray(im)
    except Exception as e:  # Pillow raises many kinds for damaged files
        raise FolderImportError(f"{path}: unreadable PNG ({one_line(e)})") from None
    if a.shape != shape:
        raise FolderImportError(f"{path}: decodes to {a.shape[::-1]} px, its header says {shape[::-1]}; the file is damaged")
    return a


def _as_uint16(a: np.ndarray, name: str) -> np.ndarray:
    if a.dtype == np.uint16:
        return a
    if a.dtype.kind in "ui" and (a.size == 0 or (a.min() >= 0 and a.max() <= 65535)):
        return a.astype(np.uint16)
    raise FolderImportError(f"{name}: values outside 0-65535 ({a.dtype}); frames must be 16-bit counts")
