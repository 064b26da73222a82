"""RVL, the lossless depth-image code of A. D. Wilson, "Fast Lossless Depth Image Compression" (ISS 2017), decoded.

image_transport's compressed_depth_image_transport sends it as the `rvl` form of compressedDepth (read in
ros-perception/image_transport_plugins at 7404d77, compressed_depth_image_transport/src/rvl_codec.cpp):

- the pixels, row by row, alternate a run of zeros and a run of non-zeros (CompressRVL, lines 49-64); each run
  starts with its length, and each non-zero pixel follows as the difference to the previous non-zero pixel
  (`previous` is not reset by a run of zeros), zigzag-mapped to a non-negative number, (delta << 1) ^ (delta >> 31)
  (line 60; undone by (p >> 1) ^ -(p & 1), line 84), the sum kept in 16 bits (unsigned short, lines 74-86);
- every number is a variable-length code of 4-bit nibbles (EncodeVLE, lines 11-24): the low 3 bits of what is
  left, the fourth bit set when more nibbles follow, least significant group first;
- nibbles fill 32-bit words from the most significant end (lines 15-16), each full word stored as a host int
  (little-endian on every machine ROS runs on), the last one shifted up to the top (lines 65-66); DecodeVLE
  (lines 26-41) reads them back in the same order.

The decode stops after width x height pixels (DecompressRVL, lines 70-90).
"""

from __future__ import annotations

import numpy as np

from ..compiled import njit


class RvlError(ValueError):
    """The RVL stream ends early or its runs overrun the image."""


def decode_rvl(payload: bytes, n_pixels: int) -> np.ndarray:
    """The `n_pixels` 16-bit values an RVL stream holds (a flat uint16 array); RvlError if it is damaged."""
    padded = bytes(payload) + b"\0" * (-len(payload) % 4)
    words = np.frombuffer(padded, "<u4").astype(np.uint32)
    out = np.zeros(n_pixels, np.uint16)
    status = _decode(words, out)
    if status == -1:
        raise RvlError(f"the RVL stream ends before {n_pixels} pixels ({len(payload)} bytes)")
    if status == -2:
        raise RvlError(f"a run of the RVL stream overruns the image's {n_pixels} pixels")
    return out


@njit(cache=True, nogil=True)
def _nibble(words, state):  # pragma: no cover - compiled
    """The next nibble, most significant first, of words[state[0]]; state: word index, nibbles left in the word, the
    word shifted so far. -1 past the last word."""
    if state[1] == 0:
        if state[0] >= words.shape[0]:
            return -1
        state[2] = np.int64(words[state[0]])
        state[0] += 1
        state[1] = 8
    nibble = (state[2] >> 28) & 0xF
    state[2] = (state[2] << 4) & 0xFFFFFFFF
    state[1] -= 1
    return nibble


@njit(cache=True, nogil=True)
def _number(words, state):  # pragma: no cover - compiled
    """One variable-length number: 3 bits a nibble, least significant first, while the nibble's top bit is set."""
    value = np.int64(0)
    shift = 0
    while True:
        nibble = _nibble(words, state)
        if nibble < 0 or shift > 33:
            return np.int64(-1)
        value |= np.int64(nibble & 0x7) << shift
        shift += 3
        if not nibble & 0x8:
            return value


@njit(cache=True, nogil=True)
def _decode(words, out):  # pragma: no cover - compiled
    """Runs of zeros and of delta-coded non-zeros into `out`; 0, or -1 (stream too short), -2 (a run overruns)."""
    state = np.zeros(3, np.int64)
    n = out.shape[0]
    i = 0
    previous = np.int64(0)
    while i < n:
        zeros = _number(words, state)
        if zeros < 0:
            return -1
        if zeros > n - i:
            return -2
        i += zeros  # `out` starts as zeros
        nonzeros = _number(words, state)
        if nonzeros < 0:
            return -1
        if nonzeros > n - i:
            return -2
        for _ in range(nonzeros):
            p = _number(words, state)
            if p < 0:
                return -1
            delta = (p >> 1) ^ -(p & 1)
            previous = (previous + delta) & 0xFFFF
            out[i] = previous
            i += 1
    return 0
