"""Pixels grouped, for fast fits: each small tile of a stop stands in for its pixels by 7 weighted nodes.

Every part of the likelihood (`rig.models.likelihood`) is a weighted sum over pixels of a smooth
function of the pixel's prediction: sum_p a_p ln V_p, sum_p b_p / V_p (b = a s2), sum_p kw_p K_p / V_p^2,
sum_p fill_p. Within a tile of t x t pixels of one stop and one range window, the prediction depends on the
pixel through its position (u, v) and its range Z; write xi = (du, dv, e) for the offsets from the tile's
centre, e the part of ln Z0 that the position does not explain (its least-squares residual on du, dv:
wall roughness and the noise of the measured mean). Each weighted sum over the tile is replaced by a
quadrature on 7 nodes, xi = 0 and xi = +-h_i along each axis, with node weights that reproduce, for each
kind of weight w, the tile's sum of w, of w xi_i and of w xi_i^2:

    c(+-i) = (M2_i / h_i^2 +- M1_i / h_i) / 2,   c(0) = W - sum_i M2_i / h_i^2

(M1_i = sum w xi_i, M2_i = sum w xi_i^2, W = sum w; h_i = sqrt(3 M2_i / A) from the Gamma weights a, so
their c(0) is 0). The sums are then exact for a prediction quadratic in xi within the tile, and off by
third-order terms otherwise: a second-order expansion of the likelihood about each tile's centre
(`tests/test_grouping.py` shows grouped and ungrouped fits agreeing within a small fraction of a
standard error). Nodes carry positions and ranges, so covariates that are formulas of them (radius,
incidence, drift) are exact at the node, and image covariates (brightness, ambient) are read there.

Effects that depend on a pixel's own grid offset from the depth unit (quantization) are not smooth
within a tile: models with them are fitted on the pixels themselves (`Effect.groupable`).
"""

from __future__ import annotations

import math

import numpy as np

from .data import ModelData
from .group_sums import group_sums

#: tiles per stop the grouping aims at (each becomes 7 nodes)
TILES_PER_STOP = 1000
#: grouping is used only when a tile holds at least this many pixels (below, the nodes save little)
MIN_TILE_PX = 36


class GroupedData(ModelData):
    """Quadrature nodes standing in for the pixels of `full` (see the module docstring). The likelihood reads
    `weights` (a, b, kurtosis weight, pixels per node), `constant` and the measured kurtosis and fill of the
    whole data; models read the nodes' covariates as they read pixels'."""

    weights: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    constant: float
    fill_table: tuple[np.ndarray, np.ndarray, np.ndarray]
    full: ModelData
    tile_px: int

    def chunks(self):
        yield self

    def pixel_weights(self) -> np.ndarray:
        return self.weights[3]


def tile_size(d: ModelData) -> int:
    """The tile side (px) for TILES_PER_STOP tiles a stop, or 0 if tiles would be too small to pay."""
    if d.sources is None or d.calibration is None or not np.isfinite(d.u_px).all():
        return 0
    stops = max(len(np.unique(d.stop)), 1)
    t = int(math.sqrt(len(d) / stops / TILES_PER_STOP))
    return t if t * t >= MIN_TILE_PX else 0


def group(d: ModelData, tile_px: int) -> GroupedData:
    """Nodes for `d` with tiles of tile_px x tile_px pixels (see the module docstring)."""
    from .likelihood import gamma_constant, likelihood_weights, prepare

    prepare(d)
    a, b, kw, _ = likelihood_weights(d)
    u, v = d.u_px.astype(np.float64), d.v_px.astype(np.float64)
    rg = d.range_group
    tu, tv = (u // tile_px).astype(np.int64), (v // tile_px).astype(np.int64)
    key = ((d.stop.astype(np.int64) * (int(rg.max() - rg.min()) + 1) + (rg - rg.min())) * (int(tv.max()) + 1) + tv) \
        * (int(tu.max()) + 1) + tu
    _, tile = np.unique(key, return_inverse=True)
    lz = np.log(d.z0_m)
    # the tile's centre (a-weighted), the spread of its positions and the plane of ln Z0 over them
    _, s = group_sums(tile, [a, a * u, a * v, a * u * u, a * v * v, a * u * v, a * lz, a * u * lz, a * v * lz,
                             a * np.log(d.z_m / d.z0_m), a * d.n])
    A = s[:, 0]
    uc, vc, lzc = s[:, 1] / A, s[:, 2] / A, s[:, 6] / A
    suu, svv, suv = s[:, 3] / A - uc * uc, s[:, 4] / A - vc * vc, s[:, 5] / A - uc * vc
    sul, svl = s[:, 7] / A - uc * lzc, s[:, 8] / A - vc * lzc
    det = suu * svv - suv * suv
    ok = det > 1e-12 * np.maximum(suu * svv, 1e-300)
    gu = np.where(ok, (svv * sul - suv * svl) / np.where(ok, det, 1.0), np.where(suu > 0, sul / np.maximum(suu, 1e-300), 0.0))
    gv = np.where(ok, (suu * svl - suv * sul) / np.where(ok, det, 1.0), np.where(svv > 0, svl / np.maximum(svv, 1e-300), 0.0))
    ratio, n_mean = np.exp(s[:, 9] / A), s[:, 10] / A
    du, dv = u - uc[tile], v - vc[tile]
    e = lz - lzc[tile] - gu[tile] * du - gv[tile] * dv
    xi = (du, dv, e)
    moments = []
    for w in (a, b, kw, np.ones(len(d))):
        moments.append(group_sums(tile, [w, *(w * x for x in xi), *(w * x * x for x in xi)])[1])
    h = np.sqrt(3.0 * moments[0][:, 4:7] / A[:, None])  # (tiles, 3)
    # 7 nodes per tile: the centre, then -h and +h along each axis
    steps = np.zeros((7, 3))
    for i in range(3):
        steps[1 + 2 * i, i], steps[2 + 2 * i, i] = -1.0, 1.0
    offset = steps[None, :, :] * h[:, None, :]  # (tiles, 7, 3)
    node_u = uc[:, None] + offset[:, :, 0]
    node_v = vc[:, None] + offset[:, :, 1]
    node_lz = lzc[:, None] + gu[:, None] * offset[:, :, 0] + gv[:, None] * offset[:, :, 1] + offset[:, :, 2]
    weights = [_node_weights(m, h) for m in moments]
    first = _first_rows(tile, len(A))  # any pixel of the tile: its stop and range window
    z0 = np.exp(node_lz).ravel()
    g = GroupedData(z_m=z0 * np.repeat(ratio, 7), m2_m2=np.full(z0.size, np.nan), m4_m4=np.full(z0.size, np.nan),
                    n=np.repeat(n_mean, 7), stop=np.repeat(d.stop[first], 7), u_px=node_u.ravel(), v_px=node_v.ravel(),
                    fb_px_m=d.fb_px_m, depth_unit_m=d.depth_unit_m, n_dropped_zero=d.n_dropped_zero, stops=d.stops,
                    sources=d.sources, calibration=d.calibration)
    g.__dict__["z0_m"] = z0
    g.__dict__["range_group"] = np.repeat(rg[first], 7)
    g.__dict__["kurtosis_by_range"] = d.kurtosis_by_range
    g.weights = tuple(w.ravel() for w in weights)  # type: ignore[assignment]
    g.constant = gamma_constant(d)
    _, measured, se = d.fill_by_stop
    g.fill_table = (np.unique(d.stop), measured, se)
    g.full = d
    g.tile_px = tile_px
    return g


def _node_weights(m: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Node weights (tiles, 7) reproducing, per tile, W = m[:, 0], M1 = m[:, 1:4] and M2 = m[:, 4:7] (docstring)."""
    W, M1, M2 = m[:, 0], m[:, 1:4], m[:, 4:7]
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = np.where(h > 0, M2 / h**2, 0.0)
        tilt = np.where(h > 0, M1 / h, 0.0)
    out = np.empty((len(W), 7))
    out[:, 0] = W - spread.sum(axis=1)
    for i in range(3):
        out[:, 1 + 2 * i] = (spread[:, i] - tilt[:, i]) / 2
        out[:, 2 + 2 * i] = (spread[:, i] + tilt[:, i]) / 2
    return out


def _first_rows(tile: np.ndarray, tiles: int) -> np.ndarray:
    """For each tile, the index of one of its rows."""
    first = np.empty(tiles, np.int64)
    first[tile[::-1]] = np.arange(len(tile))[::-1]
    return first
