"""One depth message's pixels, decoded without ROS: a sensor_msgs Image or an image_transport compressedDepth image.

- `sensor_msgs/Image`: `16UC1` or `mono16` (integer counts; millimetres by REP 118) and `32FC1` (metres, REP 118;
  NaN, 0 and +/-inf are no depth), little- or big-endian (`is_bigendian`), rows `step` bytes apart.
- `sensor_msgs/CompressedImage` from compressed_depth_image_transport (read in ros-perception/image_transport_plugins
  at 7404d77, compressed_depth_image_transport/): `format` is the image's encoding, `;`, and `compressedDepth png`
  or `compressedDepth rvl` (codec.cpp lines 74-94: no `;`, or `compressedDepth` alone, is the older PNG form).
  `data` starts with a 12-byte ConfigHeader (compression_common.h lines 44-57: an int enum, INV_DEPTH = 0, and two
  floats depthParam[2]; host byte order, little-endian), then the payload (codec.cpp lines 99-114):
  a PNG (cv::imencode, codec.cpp lines 323 and 391), or for RVL the width and the height as 32-bit integers and
  the RVL stream (codec.cpp lines 133-155, 204-210, 342-351; drivers/bag/rvl.py).
  A 16-bit image is the counts themselves (codec.cpp lines 190-223; the header's floats are unset).
  A `32FC1` image is sent as quantised inverse depth v = A / z + B in 16 bits, A = z0 (z0 + 1), B = 1 - A / z_max
  (codec.cpp lines 291-316, truncated to an integer on assignment), 0 for no depth or z >= z_max; it reads back as
  z = A / (v - B) in float arithmetic, v = 0 as NaN (codec.cpp lines 163-184), A and B from the header.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from .rvl import RvlError, decode_rvl

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
#: integer depth counts (REP 118: 16UC1 depth is millimetres)
COUNT_ENCODINGS = ("16UC1", "mono16")
#: depth in metres as float32 (REP 118)
METRE_ENCODINGS = ("32FC1",)
#: the ConfigHeader before a compressedDepth payload: compressionFormat (int), depthParam[2] (float)
CONFIG_HEADER = struct.Struct("<iff")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class DepthMessageError(ValueError):
    """A message rig cannot read as depth; the text is one line naming what it is (the caller adds where)."""


@dataclass(frozen=True)
class DepthFormat:
    """How a depth topic's frames are sent: the image encoding and the compression ('' for a raw Image)."""

    encoding: str
    compression: str = ""

    @property
    def metres(self) -> bool:
        """Depth in metres (float32), to be turned into counts; else integer counts."""
        return self.encoding in METRE_ENCODINGS

    def __str__(self) -> str:
        return f"{self.encoding}; compressedDepth {self.compression}" if self.compression else self.encoding


def depth_format(msg: Any, msgtype: str, topic: str) -> DepthFormat:
    """The format of one message of a depth topic; DepthMessageError naming it when rig does not read it."""
    if msgtype == IMAGE:
        if msg.encoding not in COUNT_ENCODINGS + METRE_ENCODINGS:
            raise DepthMessageError(f"{topic} is {msg.encoding}; rig reads depth as {', '.join(COUNT_ENCODINGS + METRE_ENCODINGS)} "
                                    "(or their compressedDepth): record the depth topic")
        return DepthFormat(str(msg.encoding))
    fmt = str(msg.format)
    encoding, sep, rest = fmt.partition(";")
    encoding = encoding.strip()
    if not sep and topic.endswith("/compressedDepth"):  # the older form: the encoding alone, PNG (codec.cpp 77-79)
        compression = "png"
    elif "compressedDepth png" in rest or ("compressedDepth" in rest and "compressedDepth " not in rest):
        compression = "png"
    elif "compressedDepth rvl" in rest:
        compression = "rvl"
    else:
        raise DepthMessageError(f"{topic} is a CompressedImage in format {fmt!r}, which rig does not read; rig reads "
                                "compressedDepth png or rvl (image_transport) and raw depth images: record one of those")
    if encoding not in COUNT_ENCODINGS + METRE_ENCODINGS:
        raise DepthMessageError(f"{topic} is compressedDepth of {encoding!r} (format {fmt!r}); rig reads it for "
                                f"{', '.join(COUNT_ENCODINGS + METRE_ENCODINGS)}")
    return DepthFormat(encoding, compression)


def quantisation(msg: Any) -> tuple[float, float]:
    """A compressedDepth message's depthParam A, B (the inverse-depth quantisation of 32FC1; unset for 16-bit)."""
    _, a, b = CONFIG_HEADER.unpack_from(bytes(msg.data[: CONFIG_HEADER.size]))
    return float(a), float(b)


def decode(msg: Any, fmt: DepthFormat) -> np.ndarray:
    """The message's depth as an (H, W) array: uint16 counts, or float32 metres (NaN where there is none, as sent)."""
    if not fmt.compression:
        return _raw(msg, fmt)
    data = bytes(msg.data)
    if len(data) <= CONFIG_HEADER.size:  # codec.cpp line 99
        raise DepthMessageError(f"compressedDepth message of {len(data)} bytes, no image after its 12-byte header")
    _, depth_a, depth_b = CONFIG_HEADER.unpack_from(data)
    payload = data[CONFIG_HEADER.size:]
    counts = _png(payload) if fmt.compression == "png" else _rvl(payload)
    if not fmt.metres:
        return counts
    # z = A / (v - B) in float32, v = 0 no depth (codec.cpp lines 176-183)
    v = counts.astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.float32(depth_a) / (v - np.float32(depth_b))
    z[counts == 0] = np.nan
    return z


def _raw(msg: Any, fmt: DepthFormat) -> np.ndarray:
    width, height, step = int(msg.width), int(msg.height), int(msg.step)
    size = 4 if fmt.metres else 2
    data = np.frombuffer(bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data, np.uint8)
    if step < size * width or data.size < step * height:
        raise DepthMessageError(f"{width}x{height} {fmt} image with {data.size} bytes in rows of {step}; the message is damaged")
    rows = data[: step * height].reshape(height, step)[:, : size * width]
    dtype = (">" if msg.is_bigendian else "<") + ("f4" if fmt.metres else "u2")
    return rows.copy().view(dtype).astype(np.float32 if fmt.metres else np.uint16, copy=False)


def _png(payload: bytes) -> np.ndarray:
    """A 16-bit grayscale PNG (what cv::imencode writes for CV_16UC1) as uint16."""
    if payload[:8] != PNG_SIGNATURE or payload[12:16] != b"IHDR" or len(payload) < 26:
        raise DepthMessageError("compressedDepth png whose payload is no PNG")
    bit_depth, colour_type = payload[24], payload[25]
    if (bit_depth, colour_type) != (16, 0):
        raise DepthMessageError(f"compressedDepth png of bit depth {bit_depth}, colour type {colour_type}; "
                                "depth is a 16-bit grayscale PNG")
    from PIL import Image  # Pillow, a dependency of rig; only needed for PNG payloads

    try:
        with Image.open(io.BytesIO(payload)) as im:
            im.load()
            return np.asarray(im).astype(np.uint16, copy=False)
    except Exception as e:  # Pillow raises many kinds for a damaged file
        raise DepthMessageError(f"compressedDepth png unreadable ({type(e).__name__}: {' '.join(str(e).split())})") from None


def _rvl(payload: bytes) -> np.ndarray:
    if len(payload) < 8:
        raise DepthMessageError("compressedDepth rvl shorter than its 8-byte size")
    width, height = struct.unpack_from("<II", payload)
    # codec.cpp lines 136-151 refuse a zero size and (for 32FC1 only) more than 10 pixels a byte, which a frame with
    # no depth at all exceeds; here a size past 2^28 pixels is taken for a damaged message, any other decoded
    if width == 0 or height == 0 or width * height > 1 << 28:
        raise DepthMessageError(f"compressedDepth rvl says {width}x{height} px in {len(payload)} bytes; the message is damaged")
    try:
        return decode_rvl(payload[8:], width * height).reshape(height, width)
    except RvlError as e:
        raise DepthMessageError(f"compressedDepth rvl damaged: {e}") from None
