"""A region of interest: the part of the image the wall fills, when a target does not fill the frame.

A run with `region_px = [x, y, width, height]` (a capture setting of every protocol: `rig run --region-px
100,60,200,120`, an experiment file's `region_px`, the TUI's form) records only that rectangle of the depth and IR
images, in pixels of the camera's image (x the column, y the row of its top-left corner). The recording's camera is
then the cropped one: width and height the region's, the principal point moved by (x, y) so that each pixel's ray is
the same as in the whole image (pinhole: u - cx is unchanged when both shift by x). The fit, the diagnosis, the
accuracy, `rig check`, the exports and the reports read that recording and so see the region only; the header keeps
the region and the camera's whole image (`camera_info.extra`). `[]` (the default) records the whole image.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np

from drivers.camera import CameraInfo, CameraSettings, DepthCamera, Frame, Intrinsics
from drivers.errors import CameraError

from .plan_values import numbers, whole

#: a region's side must hold a 7x7 neighbourhood (the models' brightness window and the kurtosis' square)
MIN_SIDE_PX = 8


def check_region(where: str, name: str, value: Any) -> list[int]:
    """[] or [x, y, width, height]: whole pixels, x and y from 0, each side at least MIN_SIDE_PX (the plan's check;
    whether it fits the camera's image is known only when the camera is open: `Region.check_fits`)."""
    values = numbers(where, name, value)
    if not values:
        return []
    if len(values) != 4:
        raise ValueError(f"{where}: {name} = {value!r} must be 4 whole numbers in px, x, y, width, height (the "
                         "top-left corner's column and row and the size), e.g. 100, 60, 200, 120; or empty for the "
                         "whole image")
    x, y = (whole(where, f"{name}'s {k}", v, 0, 100_000) for k, v in zip(("x", "y"), values[:2]))
    w, h = (whole(where, f"{name}'s {k}", v, MIN_SIDE_PX, 100_000, f"a side of at least {MIN_SIDE_PX} px holds the "
                  "7x7 neighbourhoods the models use") for k, v in zip(("width", "height"), values[2:]))
    return [x, y, w, h]


@dataclass(frozen=True)
class Region:
    """A rectangle of the image in px: the top-left corner's column `x_px` and row `y_px`, its size."""

    x_px: int
    y_px: int
    width_px: int
    height_px: int

    @classmethod
    def of(cls, values: Any) -> "Region | None":
        """The region a plan's `region_px` gives ([] or None: the whole image)."""
        return cls(*(int(v) for v in values)) if values else None

    def as_list(self) -> list[int]:
        return [self.x_px, self.y_px, self.width_px, self.height_px]

    def words(self) -> str:
        """"40x24 px at column 10, row 5"."""
        return f"{self.width_px}x{self.height_px} px at column {self.x_px}, row {self.y_px}"

    def check_fits(self, width_px: int, height_px: int) -> None:
        """ValueError in one line when the region reaches outside a `width_px` x `height_px` image."""
        if self.x_px + self.width_px > width_px or self.y_px + self.height_px > height_px:
            raise ValueError(f"the region {', '.join(map(str, self.as_list()))} px (x, y, width, height) reaches "
                             f"beyond the camera's {width_px}x{height_px} image (to column {self.x_px + self.width_px}"
                             f", row {self.y_px + self.height_px}); give a region inside it, or none for the whole "
                             "image")

    def crop(self, image: np.ndarray) -> np.ndarray:
        """The region of `image` (rows, columns), as a contiguous array."""
        return np.ascontiguousarray(image[self.y_px:self.y_px + self.height_px, self.x_px:self.x_px + self.width_px])

    def intrinsics(self, i: Intrinsics) -> Intrinsics:
        """The whole image's intrinsics `i` for the region: its size, the principal point in its pixels (cx - x,
        cy - y), so that each pixel keeps its ray (pinhole: u - cx is unchanged)."""
        return dataclasses.replace(i, width=self.width_px, height=self.height_px, cx=i.cx - self.x_px,
                                   cy=i.cy - self.y_px)

    def info(self, info: CameraInfo) -> CameraInfo:
        """`info` for the region: its `intrinsics`, the whole image and the region kept in `extra`."""
        i = info.intrinsics
        extra = {**info.extra, "region_px": self.as_list(), "full_image_px": [i.width, i.height]}
        return dataclasses.replace(info, intrinsics=self.intrinsics(i), extra=extra)


def region_words(camera: dict) -> str:
    """"40x24 px at column 10, row 5 of the camera's 64x36 image" for a recording's camera description (its
    `extra` holds the region a run recorded), or "" for the whole image."""
    extra = camera.get("extra") if isinstance(camera, dict) else None
    region, full = (extra.get(k) if isinstance(extra, dict) else None for k in ("region_px", "full_image_px"))
    if not (isinstance(region, list) and len(region) == 4 and isinstance(full, list) and len(full) == 2):
        return ""
    return f"{Region(*region).words()} of the camera's {full[0]}x{full[1]} image"


def through_region(camera: DepthCamera, region_px: Any) -> DepthCamera:
    """`camera`, or a RegionCamera when `region_px` (a plan's) names a region."""
    region = Region.of(region_px)
    return RegionCamera(camera, region) if region else camera


class RegionCamera(DepthCamera):
    """`camera` seen through `region`: its info and frames cropped; everything else is the camera's own."""

    def __init__(self, camera: DepthCamera, region: Region):
        self.inner, self.region = camera, region
        self.name = camera.name
        self.plays_back = camera.plays_back
        self.ir_full_scale_dn = camera.ir_full_scale_dn

    def __getattr__(self, name: str) -> Any:  # what a kind of camera adds (a simulated one's wall, ...)
        return getattr(self.inner, name)

    def open(self) -> None:
        self.inner.open()
        i = self.inner.info().intrinsics
        try:
            self.region.check_fits(i.width, i.height)
        except ValueError as e:
            self.inner.close()
            raise CameraError(f"{self.name}: {e}") from None

    def close(self) -> None:
        self.inner.close()

    def info(self) -> CameraInfo:
        return self.region.info(self.inner.info())

    def configure(self, settings: CameraSettings) -> CameraSettings:
        return self.inner.configure(settings)

    def read_settings(self) -> CameraSettings:
        return self.inner.read_settings()

    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        for frame in self.inner.frames(n, ir=ir):
            yield dataclasses.replace(frame, depth=self.region.crop(frame.depth),
                                      ir=self.region.crop(frame.ir) if frame.ir is not None else None)

    def true_distance_m(self) -> float | None:
        return self.inner.true_distance_m()
