"""A live look at the wall before recording, without Textual: one depth frame's fill rate, the wall's plane (its
distance and tilts, fitted by `rig.accuracy.tilted_wall`) and the depth image shrunk to a terminal's cells.

One frame's pixels carry no variance of their own: each is given the depth unit's rounding, q^2 / 12, and the plane
fit's relief term (`rig.accuracy.pixel_weights`) estimates the rest of their scatter from the frame itself."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.camera import Intrinsics
from rig.accuracy.tilted_wall import WallPlane, fit_plane, wall_plane

#: the fewest pixels with depth a plane is fitted to (three parameters, and a scatter to estimate)
MIN_PIXELS = 6
#: at most about this many pixels are fitted (a regular grid of them): a 848x480 frame whole takes 0.12 s of CPU,
#: five times a second; this many, a few ms, and the tilt's standard error grows only as 1/sqrt(pixels)
FIT_PIXELS = 4000


@dataclass(frozen=True)
class WallView:
    fill_rate: float  # the fraction of the frame's pixels with a depth
    plane: WallPlane | None  # None: too few pixels with depth, or all in a line
    image_m: np.ndarray  # the mean depth of each block of pixels, m; NaN where none of them has a depth


def wall_view(depth: np.ndarray, intrinsics: Intrinsics, depth_scale_m: float,
              blocks: tuple[int, int] = (48, 96)) -> WallView:
    """What one depth frame (counts of `depth_scale_m`; 0: no depth) shows of the wall; the image in at most
    `blocks` (rows, columns) blocks."""
    valid = depth > 0
    z_m = np.where(valid, depth.astype(np.float64) * depth_scale_m, np.nan)
    plane = None
    step = max(1, math.ceil(math.sqrt(valid.size / FIT_PIXELS)))
    v, u = (a * step for a in np.nonzero(valid[::step, ::step]))
    if u.size >= MIN_PIXELS:
        x = (u - intrinsics.cx) / intrinsics.fx  # normalised image coordinates (the pinhole's ray through the pixel)
        y = (v - intrinsics.cy) / intrinsics.fy
        try:
            plane = wall_plane(*fit_plane(z_m[v, u], np.full(u.size, depth_scale_m ** 2 / 12), x, y),
                               math.nan, math.nan)
        except np.linalg.LinAlgError:  # every pixel with depth in one row or column: no plane
            plane = None
    return WallView(float(valid.mean()) if valid.size else math.nan, plane, shrink(z_m, blocks))


def shrink(z_m: np.ndarray, blocks: tuple[int, int]) -> np.ndarray:
    """The mean of each of at most `blocks` blocks of `z_m`, NaN left out; NaN where a block has no value."""
    rows = np.linspace(0, z_m.shape[0], min(blocks[0], z_m.shape[0]) + 1).astype(int)[:-1]
    cols = np.linspace(0, z_m.shape[1], min(blocks[1], z_m.shape[1]) + 1).astype(int)[:-1]
    have = np.isfinite(z_m)
    total = np.add.reduceat(np.add.reduceat(np.where(have, z_m, 0.0), rows, axis=0), cols, axis=1)
    count = np.add.reduceat(np.add.reduceat(have.astype(np.int64), rows, axis=0), cols, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def view_rows(view: WallView) -> list[tuple[str, str]]:
    """The numbers as (label, value) rows: the fill, the wall's distance and its tilts with their standard errors."""
    fill = f"fill {100 * view.fill_rate:.1f} %"
    p = view.plane
    if p is None:
        return [("wall", f"{fill}; too few pixels for a plane")]
    return [("wall", f"{p.distance_m:.3f} m on the axis, {fill}"),
            ("tilt", f"{p.tilt_deg:+.2f} +/- {p.tilt_se_deg:.2f} deg left-right"),  # about the vertical axis
            ("", f"{p.tilt_x_deg:+.2f} +/- {p.tilt_x_se_deg:.2f} deg up-down")]
