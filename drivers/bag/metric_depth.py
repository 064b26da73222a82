"""Depth in metres (32FC1, REP 118) as the integer counts rig's statistics fold in (protocols/stats.py: uint16 counts
times a depth unit, summed exactly in integers).

The unit is chosen from the whole stream before the first frame is folded in (`MetricDepthScan`):

- when every valid value lies on a grid of one of `UNITS_M` (depth_image_proc publishes 16UC1 millimetres as
  count * 0.001f; a simulator may round too), that grid's step, the coarsest such: the counts are the data exactly;
- otherwise the finest of `UNITS_M` that still holds the farthest valid depth in 16 bits (z_max / 65535 or more):
  the values are rounded to it, which adds q^2 / 12 of variance (Sheppard), as rounding to the depth unit does for
  any camera (the `quantization` effect models it from the recorded unit).

No depth: NaN, +/-inf, 0 and negative values (REP 118), and a value that rounds to 0 counts.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: depth units tried, coarse to fine, in m: a 1-2-5 series from 1 cm to 1 um
UNITS_M = (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5, 5e-6, 2e-6, 1e-6)
MAX_COUNT = 65535
#: a float32 value z lies on the grid of q when |z - n q| <= GRID_ULPS float32 spacings at z: making it from an
#: integer n takes at most two roundings of half a spacing each (q to float32, then the product; or the quotient)
GRID_ULPS = 4


class DepthRangeError(ValueError):
    """A depth that no 16-bit count of the unit holds; the text is one line (the caller adds where)."""


@dataclass
class MetricDepthScan:
    """The farthest valid depth of a stream of float frames (m), and the units whose grid every valid value lies on."""

    max_m: float = 0.0
    n_valid: int = 0
    on_grid: list[float] = field(default_factory=lambda: list(UNITS_M))

    def add(self, z_m: np.ndarray) -> None:
        z = np.asarray(z_m, np.float32)
        valid = z[np.isfinite(z) & (z > 0)]
        if valid.size == 0:
            return
        self.n_valid += int(valid.size)
        self.max_m = max(self.max_m, float(valid.max()))
        z64 = valid.astype(np.float64)
        tolerance = GRID_ULPS * np.spacing(valid).astype(np.float64)
        self.on_grid = [q for q in self.on_grid if bool(np.all(np.abs(z64 - np.rint(z64 / q) * q) <= tolerance))]

    @classmethod
    def merged(cls, scans: list["MetricDepthScan"]) -> "MetricDepthScan":
        """One scan of all these streams' frames (the bags of one import share one unit)."""
        return cls(max((s.max_m for s in scans), default=0.0), sum(s.n_valid for s in scans),
                   [q for q in UNITS_M if all(q in s.on_grid for s in scans)])

    def unit(self) -> tuple[float, bool]:
        """(the unit in m, whether the counts hold the values exactly); DepthRangeError if none holds the farthest."""
        fits = [q for q in UNITS_M if self.max_m / q <= MAX_COUNT]
        if not fits:
            raise DepthRangeError(f"depth up to {self.max_m:.4g} m, more than 65535 counts of {UNITS_M[0]:g} m hold")
        exact = [q for q in self.on_grid if q in fits]
        return (exact[0], True) if exact and self.n_valid else (fits[-1], False)


def to_counts(z_m: np.ndarray, unit_m: float) -> np.ndarray:
    """Float depth in m as uint16 counts of `unit_m`, rounded to nearest; 0 where there is no depth (z = n q, n = rint(z / q))."""
    z = np.asarray(z_m, np.float64)
    valid = np.isfinite(z) & (z > 0)
    n = np.rint(np.where(valid, z, 0.0) / unit_m)
    if n.max(initial=0) > MAX_COUNT:
        raise DepthRangeError(f"depth {float(np.nanmax(np.where(valid, z, np.nan))):.4g} m is more than 65535 counts of "
                              f"{unit_m:g} m; pass a coarser --depth-unit-m")
    return n.astype(np.uint16)
