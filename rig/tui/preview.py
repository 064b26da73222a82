"""A live look at the wall before recording, without Textual: one depth frame's fill rate, the wall's plane (its
distance and tilts, fitted by `rig.accuracy.tilted_wall`), the IR image's level and saturation, and both images shrunk
to a terminal's cells. With a region of interest (`protocols.region_of_interest`) the numbers are the region's, as a
run's would be; the images are the whole frame's, with the region marked.

One frame's pixels carry no variance of their own: each is given the depth unit's rounding, q^2 / 12, and the plane
fit's relief term (`rig.accuracy.pixel_weights`) estimates the rest of their scatter from the frame itself."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from drivers.camera import CameraInfo, Frame, Intrinsics
from protocols.region_of_interest import Region
from protocols.stats import MeanImageAccumulator
from rig.accuracy.tilted_wall import WallPlane, fit_plane, wall_plane

#: the fewest pixels with depth a plane is fitted to (three parameters, and a scatter to estimate)
MIN_PIXELS = 6
#: at most about this many pixels are fitted (a regular grid of them): a 848x480 frame whole takes 0.12 s of CPU,
#: five times a second; this many, a few ms, and the tilt's standard error grows only as 1/sqrt(pixels)
FIT_PIXELS = 4000


@dataclass(frozen=True)
class IrView:
    mean_dn: float  # the mean IR level of the region's pixels (the whole image's without one), DN
    saturated: float | None  # the fraction of them at the full scale (`MeanImageAccumulator`'s rule); None: not checked
    full_scale_dn: int | None  # the level counted as saturated, DN (None: a float image, not checked)
    image_dn: np.ndarray  # the whole image's mean level of each block of pixels, DN


@dataclass(frozen=True)
class WallView:
    fill_rate: float  # the fraction of the frame's (or the region's) pixels with a depth
    plane: WallPlane | None  # None: too few pixels with depth, or all in a line
    image_m: np.ndarray  # the mean depth of each block of pixels, m; NaN where none of them has a depth
    inside: np.ndarray | None = None  # each block's fraction of pixels in the region (None: no region)
    region: str = ""  # the region in words (`Region.words`; "": the whole image)
    ir: IrView | None = None  # None: the camera gave no IR image


def wall_view(depth: np.ndarray, intrinsics: Intrinsics, depth_scale_m: float,
              blocks: tuple[int, int] = (48, 96), region: Region | None = None) -> WallView:
    """What one depth frame (counts of `depth_scale_m`; 0: no depth) shows of the wall, or of `region` of it (the
    plane fitted to the region's pixels at their rays in the whole image: `Region.intrinsics`); the whole image in
    at most `blocks` (rows, columns) blocks."""
    z_m = np.where(depth > 0, depth.astype(np.float64) * depth_scale_m, np.nan)
    part, inside = depth, None
    if region is not None:
        part, intrinsics = region.crop(depth), region.intrinsics(intrinsics)
        inside = shrink(region_mask(region, depth.shape), blocks)
    valid = part > 0
    plane = None
    step = max(1, math.ceil(math.sqrt(valid.size / FIT_PIXELS)))
    v, u = (a * step for a in np.nonzero(valid[::step, ::step]))
    if u.size >= MIN_PIXELS:
        x = (u - intrinsics.cx) / intrinsics.fx  # normalised image coordinates (the pinhole's ray through the pixel)
        y = (v - intrinsics.cy) / intrinsics.fy
        try:
            plane = wall_plane(*fit_plane(part[v, u] * depth_scale_m, np.full(u.size, depth_scale_m ** 2 / 12), x, y),
                               math.nan, math.nan)
        except np.linalg.LinAlgError:  # every pixel with depth in one row or column: no plane
            plane = None
    return WallView(float(valid.mean()) if valid.size else math.nan, plane, shrink(z_m, blocks), inside)


def ir_view(ir: np.ndarray, full_scale_dn: int | None, blocks: tuple[int, int] = (48, 96),
            region: Region | None = None) -> IrView:
    """One IR image's mean level and share of saturated pixels, of `region` (else the whole image); the whole image
    in at most `blocks` blocks. Saturated: at or above `full_scale_dn` (None: the dtype's top), as a run counts them."""
    part = region.crop(ir) if region is not None else ir
    counted = MeanImageAccumulator(full_scale_dn)
    counted.add(part)
    saturated = None if counted.saturated is None else float(counted.saturated.mean())
    return IrView(float(np.mean(part, dtype=np.float64)), saturated, counted.full_scale_dn,
                  shrink(ir.astype(np.float64), blocks))


def frame_view(frame: Frame, info: CameraInfo, ir_full_scale_dn: int | None, region: Region | None = None,
               blocks: tuple[int, int] = (48, 96)) -> WallView:
    """A frame's depth (`wall_view`) and IR (`ir_view`, when the frame has an IR image) of a camera with `info`;
    `region` must fit its image (`Region.check_fits`)."""
    view = wall_view(frame.depth, info.intrinsics, info.depth_scale_m, blocks, region)
    ir = None if frame.ir is None else ir_view(frame.ir, ir_full_scale_dn, blocks, region)
    return dataclasses.replace(view, ir=ir, region=region.words() if region is not None else "")


def region_mask(region: Region, shape: tuple[int, int]) -> np.ndarray:
    """1.0 at the pixels of `region` in an image of `shape` (rows, columns), 0.0 elsewhere."""
    mask = np.zeros(shape)
    mask[region.y_px:region.y_px + region.height_px, region.x_px:region.x_px + region.width_px] = 1.0
    return mask


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
    """The numbers as (label, value) rows: the region, the fill, the wall's distance and its tilts with their standard
    errors, the IR level and its saturation."""
    rows = [("region", view.region)] if view.region else []
    fill = f"fill {100 * view.fill_rate:.1f} %"
    p = view.plane
    if p is None:
        rows.append(("wall", f"{fill}; too few pixels for a plane"))
    else:
        rows += [("wall", f"{p.distance_m:.4f} m +/- {1000 * p.distance_se_m:.2f} mm on the axis, {fill}"),
                 ("tilt", f"{p.tilt_deg:+.2f} +/- {p.tilt_se_deg:.2f} deg left-right"),  # about the vertical axis
                 ("", f"{p.tilt_x_deg:+.2f} +/- {p.tilt_x_se_deg:.2f} deg up-down")]
    return rows + [("IR", ir_words(view.ir))]


def ir_words(ir: IrView | None) -> str:
    """"mean 412 DN, 0.3 % saturated (at 1023 DN)"; "no IR image" without one."""
    if ir is None:
        return "no IR image"
    if ir.saturated is None:
        return f"mean {ir.mean_dn:.0f} DN; saturation not known (a float image)"
    return f"mean {ir.mean_dn:.0f} DN, {100 * ir.saturated:.1f} % saturated (at {ir.full_scale_dn} DN)"
