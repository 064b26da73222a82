"""Named regions of the depth image."""

from __future__ import annotations


def center_box(shape: tuple[int, int], fraction: float = 0.1) -> tuple[slice, slice]:
    """The central region (fraction of each side, at least 4 px) used for the per-frame series."""
    h, w = shape
    bh, bw = max(4, int(h * fraction)), max(4, int(w * fraction))
    return slice((h - bh) // 2, (h + bh) // 2), slice((w - bw) // 2, (w + bw) // 2)
