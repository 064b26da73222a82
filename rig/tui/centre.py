"""Fill rate and range statistics at the image centre, folded in frame by frame.

The same quantities the runner reports when a stop is done (`ProgressEvent.summary`), computed
the same way (`rig.image_regions.center_box`, `rig.stats.PixelMomentAccumulator`), so the live
numbers on the Run screen and the test capture on the Devices screen agree with the recording.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.image_regions import center_box
from protocols.stats import PixelMomentAccumulator


class CentreStats:
    def __init__(self, shape: tuple[int, int], depth_scale_m: float):
        self.box = center_box(shape)
        cy, cx = self.box
        self.acc = PixelMomentAccumulator((cy.stop - cy.start, cx.stop - cx.start), depth_scale_m)
        self.frames = 0
        self._valid = 0.0

    def add(self, depth: np.ndarray) -> None:
        self.frames += 1
        self._valid += np.count_nonzero(depth) / depth.size
        self.acc.add(depth[self.box])

    @property
    def fill_rate(self) -> float:
        """Mean fraction of pixels with a depth sample."""
        return float(self._valid / self.frames) if self.frames else math.nan

    def centre(self) -> tuple[float, float]:
        """(mean range, sigma) at the image centre in m; NaN where there are too few samples."""
        if self.frames == 0:
            return math.nan, math.nan
        stats = self.acc.result()
        ok = stats.count > 0
        mean = float(np.mean(stats.mean_m[ok])) if ok.any() else math.nan
        two = stats.count > 1
        sigma = float(np.sqrt(np.mean(stats.variance_m2[two]))) if two.any() else math.nan
        return mean, sigma
