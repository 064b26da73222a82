"""The residuals' families (range, radius, range x coarse radius, image tile, brightness, incidence), row by row in
compiled passes: each pixel's bin in every family (`row_labels`) and, in the same pass, its share of every
family's sums (`residual_sums`).

A pixel's bin in each family is what numpy's digitize, round-half-to-even and float32 arithmetic give
(tests/test_residual_bins.py); the incidence angle is the C library's acos, which may differ from numpy's arccos in
its last bits, so an angle within 3 ulps of an edge may fall on either side of it. Its per-pixel columns (`rig.diagnosis.bins.pixel_columns`) are summed over runs
of pixels that fall in the same bin of every family (on a sweep, a run is about 30 pixels of an image row), and
each run's sums are then added into its bin of each family: once per run, not once per pixel and family.

The families have fixed places (FAMILIES); one the data cannot have (no positions, no IR, one incidence angle)
gets no bin (-1) in every row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..models.data.model_data import RANGE_BIN_M
from .bins import COLUMNS, add_run, pixel_columns, plus_columns

#: the families, in the places the compiled passes give them
FAMILIES = ("range", "radius", "range_radius", "position", "brightness", "incidence")
#: image tiles for the position family (columns, rows)
POSITION_TILES = (8, 6)


@dataclass
class FamilyRows:
    """Each family's bin label per row (-1: not in the family) and covariate, a row per family (`names`), with the
    smallest label and the span of labels each uses."""

    names: list[str]
    labels: np.ndarray  # (families, rows) int64
    covariate: np.ndarray  # (families, rows)
    lo: np.ndarray
    size: np.ndarray

    def __getitem__(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        i = self.names.index(name)
        return self.labels[i], self.covariate[i]


@njit(cache=True, nogil=True, inline="always")
def _count_at_or_below(edges, x):  # pragma: no cover - compiled
    """np.digitize(x, edges) for increasing `edges`: how many are <= x (NaN: all of them, as numpy sorts it last)."""
    if x != x:
        return edges.size
    k = 0
    while k < edges.size and edges[k] <= x:
        k += 1
    return k


@njit(cache=True, nogil=True, inline="always")
def row_labels(z, rho2, u, v, ir, cos, rho_inner, radius_inner, tiles, ir_inner, angle_inner):  # pragma: no cover
    """One row's bin in each of FAMILIES (-1: none) and covariate there, from its range `z` (m), squared normalised
    radius, pixel position (float32), brightness and incidence cosine: range (0.25 m windows, `range_bin_index`),
    radius, range x coarse radius (RADIUS_EDGES), then, where given (a non-empty `tiles`, `ir_inner`,
    `angle_inner`; their rows are then placeholders), image tile (POSITION_TILES of `tiles` = largest u and v + 1, in float32 as the positions are),
    brightness (none where not finite) and incidence angle (deg, `residuals._degrees`). Scalars in, a tuple out:
    the passes call it once a row, and a call that took the arrays cost more than the labels."""
    nx, ny = POSITION_TILES
    r_bin = np.int64(np.rint(z / RANGE_BIN_M))
    rho = np.sqrt(rho2)
    tile, bright, incidence = np.int64(-1), np.int64(-1), np.int64(-1)
    c_tile, c_bright, c_angle = 0.0, 0.0, 0.0
    if tiles.size > 0:
        tx = min(max(np.int64(u / tiles[0] * np.float32(nx)), 0), nx - 1)
        ty = min(max(np.int64(v / tiles[1] * np.float32(ny)), 0), ny - 1)
        tile = ty * nx + tx
        c_tile = float(tile)
    if ir_inner.size > 0 and np.isfinite(ir):
        bright = np.int64(min(_count_at_or_below(ir_inner, ir), 5))
        c_bright = ir
    if angle_inner.size > 0:
        angle = np.degrees(np.arccos(min(max(cos, -1.0), 1.0)))
        incidence = np.int64(_count_at_or_below(angle_inner, angle))
        c_angle = angle
    return (r_bin, np.int64(_count_at_or_below(rho_inner, rho)), r_bin * 10 + _count_at_or_below(radius_inner, rho),
            tile, bright, incidence, z, rho, z, c_tile, c_bright, c_angle)


@njit(cache=True, nogil=True)
def family_labels(z, rho2, u, v, ir, cos, rho_inner, radius_inner, tiles, ir_inner, angle_inner, labels, cov, lo,
                  hi):  # pragma: no cover - compiled
    """`row_labels` of every row into `labels` and `cov` (a row per family of FAMILIES), with each family's smallest
    and largest label `lo`, `hi` (hi < lo: none)."""
    for i in range(z.size):
        r = row_labels(z[i], rho2[i], u[i], v[i], ir[i], cos[i],
                       rho_inner, radius_inner, tiles, ir_inner, angle_inner)
        labs, covs = (r[0], r[1], r[2], r[3], r[4], r[5]), (r[6], r[7], r[8], r[9], r[10], r[11])  # runtime-indexable
        for f in range(6):
            g = labs[f]
            labels[f, i], cov[f, i] = g, covs[f]
            if g >= 0:
                if hi[f] < lo[f]:
                    lo[f], hi[f] = g, g
                else:
                    lo[f], hi[f] = min(lo[f], g), max(hi[f], g)


@njit(cache=True, nogil=True)
def residual_sums(z, rho2, u, v, ir, cos, rho_inner, radius_inner, tiles, ir_inner, angle_inner, nu, m2, var, k4,
                  has_k4, usable, beta, n, gain, lo, size, out, counts):  # pragma: no cover - compiled
    """Every row into every family's bins at once: `out[f, g]` gains the COLUMNS of the rows in bin lo[f] + g of
    family f of FAMILIES (`row_labels`), then nu times the family's covariate; `counts[f, g]` their number. Rows in
    the same bin of every family as the row before them are summed together first (module docstring); the sums
    are tuples, which stay in registers."""
    run = np.full(6, -2, np.int64)  # the current run's bin in each family (-2: no run yet)
    zero15 = (0.0,) * 15
    zero6 = (0.0,) * 6
    a, cv = zero15, zero6
    count = 0
    for i in range(z.size):
        r = row_labels(z[i], rho2[i], u[i], v[i], ir[i], cos[i],
                       rho_inner, radius_inner, tiles, ir_inner, angle_inner)
        if count == 0 or r[0] != run[0] or r[1] != run[1] or r[2] != run[2] or r[3] != run[3] or r[4] != run[4] \
                or r[5] != run[5]:
            if count > 0:
                _flush(run, lo, size, a, cv, count, out, counts)
            run[0], run[1], run[2], run[3], run[4], run[5] = r[0], r[1], r[2], r[3], r[4], r[5]
            a, cv, count = zero15, zero6, 0
        x = pixel_columns(nu[i], m2[i], var[i], k4[i] if has_k4 else 0.0, has_k4, usable[i], beta[i], n[i],
                          gain[i] if gain.size > 1 else gain[0])
        a = plus_columns(a, x)
        w = nu[i]
        cv = (cv[0] + w * r[6], cv[1] + w * r[7], cv[2] + w * r[8], cv[3] + w * r[9], cv[4] + w * r[10],
              cv[5] + w * r[11])
        count += 1
    if count > 0:
        _flush(run, lo, size, a, cv, count, out, counts)


@njit(cache=True, nogil=True, inline="always")
def _flush(run, lo, size, a, cv, count, out, counts):  # pragma: no cover - compiled
    """A run's sums into its bin of each family (a label outside the family's span, or -1, is left out)."""
    for f in range(6):
        g = run[f] - lo[f]
        if run[f] < 0 or g < 0 or g >= size[f]:
            continue
        counts[f, g] += count
        add_run(out[f, g], a, cv[f])


def new_sums(size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Empty (out, counts) for `residual_sums`: every family's bins (`size` of each), COLUMNS and nu x covariate."""
    width = max(int(size.max()), 1)
    return np.zeros((len(FAMILIES), width, len(COLUMNS) + 1)), np.zeros((len(FAMILIES), width), np.int64)
