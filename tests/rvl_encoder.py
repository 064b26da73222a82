"""A test-only RVL encoder, written from the algorithm's definition in A. D. Wilson, "Fast Lossless Depth Image
Compression" (ISS 2017: delta coding, the zigzag remapping, run lengths of zeros, variable-length nibbles), not from
any decoder: rig's decoder (drivers/bag/rvl.py) must read what
it writes.

The definition: scan the pixels in order; alternate a count of zeros and a count of the non-zeros that follow;
after each such count, each non-zero value as its difference to the previous non-zero value (0 before the first),
mapped to a non-negative integer as 2 d for d >= 0 and -2 d - 1 for d < 0. Each count and mapped value is written
in base 8, least significant digit first, one 4-bit nibble a digit whose high bit says that another digit follows.
Nibbles fill 32-bit words from the high end; a word is stored little-endian; the last word is padded with zero
nibbles at its low end.
"""

from __future__ import annotations

import numpy as np


def _digits(value: int) -> list[int]:
    """The nibbles of one number: base-8 digits, least significant first, 8 added to all but the last."""
    assert value >= 0
    out = [value % 8]
    value //= 8
    while value:
        out[-1] += 8
        out.append(value % 8)
        value //= 8
    return out


def encode_rvl(pixels: np.ndarray) -> bytes:
    """The RVL stream of the uint16 pixels (any shape, taken in C order)."""
    values = [int(v) for v in np.asarray(pixels, np.uint16).ravel()]
    nibbles: list[int] = []
    previous = 0
    i = 0
    while i < len(values):
        start = i
        while i < len(values) and values[i] == 0:
            i += 1
        nibbles += _digits(i - start)
        start = i
        while i < len(values) and values[i] != 0:
            i += 1
        nibbles += _digits(i - start)
        for v in values[start:i]:
            d = v - previous
            nibbles += _digits(2 * d if d >= 0 else -2 * d - 1)
            previous = v
    nibbles += [0] * (-len(nibbles) % 8)
    words = [sum(n << (28 - 4 * k) for k, n in enumerate(nibbles[j: j + 8])) for j in range(0, len(nibbles), 8)]
    return b"".join(w.to_bytes(4, "little") for w in words)
