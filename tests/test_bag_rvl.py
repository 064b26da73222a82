"""drivers/bag/rvl.py, the RVL decoder of image_transport's compressedDepth rvl, against a stream worked out by hand
from the algorithm's definition and against a test-only encoder written from Wilson's paper (tests/rvl_encoder.py)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.bag.rvl import decode_rvl
from rvl_encoder import encode_rvl


def test_rvl_decoder_reads_a_stream_worked_out_by_hand():
    """The 8 pixels 0 0 1000 1001 1001 0 0 998, by the algorithm's definition (tests/rvl_encoder.py says it):

    run of 2 zeros: 2 -> nibble 0x2; run of 3 non-zeros: 3 -> 0x3;
    1000 - 0 = 1000 -> 2000 = 0o3720, digits 0, 2, 7, 3 low first -> 0x8, 0xA, 0xF, 0x3 (high bit: more follow);
    1001 - 1000 = 1 -> 2 -> 0x2; 1001 - 1001 = 0 -> 0 -> 0x0;
    run of 2 zeros -> 0x2; run of 1 non-zero -> 0x1; 998 - 1001 = -3 -> 2 * 3 - 1 = 5 -> 0x5.
    Nibbles 2 3 8 A F 3 2 0 | 2 1 5, from the high end of 32-bit words: 0x238AF320, 0x21500000 (the last padded
    with zero nibbles), little-endian: 20 F3 8A 23 00 00 50 21."""
    stream = bytes.fromhex("20F38A23" "00005021")
    assert decode_rvl(stream, 8).tolist() == [0, 0, 1000, 1001, 1001, 0, 0, 998]
    assert encode_rvl(np.array([0, 0, 1000, 1001, 1001, 0, 0, 998])) == stream  # the test encoder agrees with the hand
    with pytest.raises(ValueError, match="ends before 9 pixels"):
        decode_rvl(stream, 9)


def test_rvl_decoder_reads_what_the_paper_s_encoder_writes():
    rng = np.random.default_rng(3)
    for n in (1, 7, 8, 9, 192):  # word boundaries on either side; long runs of zeros and big jumps
        pixels = rng.integers(0, 65536, n).astype(np.uint16)
        pixels[rng.random(n) < 0.4] = 0
        assert np.array_equal(decode_rvl(encode_rvl(pixels), n), pixels), n
