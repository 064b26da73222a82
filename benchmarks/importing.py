"""`rig import` of a folder of 16-bit PNGs against a plain Pillow decode of the same files."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from .data import RIG
from .figures import Figure, run_measured


def importing(folder: Path) -> list[Figure]:
    """CPU s per frame of `rig import` (decode, statistics, series, recording) against decoding the PNGs with Pillow
    into numpy arrays and nothing else."""
    from PIL import Image

    files = sorted(folder.glob("*/depth_*.png"))
    t0 = time.process_time()
    for p in files:
        with Image.open(p) as im:
            np.asarray(im)
    t_decode = (time.process_time() - t0) / len(files)
    with tempfile.TemporaryDirectory() as tmp:
        cpu, _, wall, _ = run_measured([RIG, "-q", "import", str(folder), "-o", str(Path(tmp) / "imported.h5")])
    per = cpu / len(files)
    return [Figure(f"rig import of {len(files)} PNGs, per frame (CPU)", 1e3 * per, 1e3 * t_decode, "ms",
                   "<= 1.5x the decode alone", per <= 1.5 * t_decode, "Pillow decode alone",
                   note=f"{1 / per:.0f} frames/s; wall {wall:.1f} s, interpreter start included")]
