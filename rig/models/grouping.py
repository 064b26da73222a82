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

Rounding to the depth unit (the quantization effect) also turns on where each pixel's mean sits between two
depth levels, which is not smooth within a tile: for models with it, the pixels whose spread is under
OFFSET_SPREAD depth units (where that matters: above it the rounded variance changes by less than 2e-8 with
the offset) are kept apart in OFFSET_BINS bins of the offset, and each group's nodes carry its mean offset.
"""

from __future__ import annotations

import math

import numpy as np

from .data import ModelData
from .group_sums import group_sums

#: nodes the grouping aims at, in all (7 per tile)
TARGET_NODES = 60_000
#: data with fewer pixel-stops are fitted as they are
MIN_ROWS = 100_000
#: the smallest tile side, px (smaller tiles, with 7 nodes each, save too little to pay)
MIN_TILE_PX = 6
#: spread (depth units) below which a pixel's rounded variance depends on its mean's offset between levels
OFFSET_SPREAD = 1.0
#: bins of the offset's size, over 0 to 1/2 depth unit, for those pixels
OFFSET_BINS = 50
#: a pixel whose mean is this many of its standard errors off its tile's plane of range stays a pixel
OFF_MEAN = 4.0
#: so does a pixel that makes this share of its tile's spread of range
DOMINANT = 0.2


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
    """The tile side (px) that makes about TARGET_NODES nodes of the data, between MIN_TILE_PX and 32 px; 0 (no grouping)
    for data under MIN_ROWS pixel-stops, which are quick to fit as they are, or without positions and sources."""
    if len(d) < MIN_ROWS or d.sources is None or d.calibration is None or not np.isfinite(d.u_px).all():
        return 0
    return int(min(max(math.ceil(math.sqrt(7 * len(d) / TARGET_NODES)), MIN_TILE_PX), 32))


def group(d: ModelData, tile_px: int, *, by_offset: bool = False) -> GroupedData:
    """Nodes for `d` with tiles of tile_px x tile_px pixels (see the module docstring); with `by_offset`, the
    pixels of small spread kept apart by their offset between depth levels, which is then a fourth axis of the
    quadrature. A group of no more pixels than nodes keeps its pixels as they are."""
    from .likelihood import gamma_constant, likelihood_weights, prepare

    prepare(d)
    a, b, kw, _ = likelihood_weights(d)
    u, v = d.u_px.astype(np.float64), d.v_px.astype(np.float64)
    rg = d.range_group
    tu, tv = (u // tile_px).astype(np.int64), (v // tile_px).astype(np.int64)
    key = ((d.stop.astype(np.int64) * (int(rg.max() - rg.min()) + 1) + (rg - rg.min())) * (int(tv.max()) + 1) + tv) \
        * (int(tu.max()) + 1) + tu
    offset = np.abs(d.grid_offset)
    if by_offset:
        neighbours, _ = d.neighbour_variance
        spread = np.sqrt(np.where(np.isfinite(neighbours), neighbours, d.s2_m2)) / d.depth_unit_m
        fbin = np.where(spread < OFFSET_SPREAD, np.minimum((offset * 2 * OFFSET_BINS).astype(np.int64), OFFSET_BINS - 1),
                        OFFSET_BINS)
        key = key * (OFFSET_BINS + 1) + fbin
    _, tile, count = np.unique(key, return_inverse=True, return_counts=True)
    dims = 4 if by_offset else 3
    pooled = (count[tile] > 1 + 2 * dims) & ~_mean_off(d, tile, a)
    _, tile = np.unique(tile[pooled], return_inverse=True)
    rows = {"a": a, "b": b, "kw": kw, "pw": np.ones(len(d)), "u": u, "v": v, "lz": np.log(d.z0_m),
            "ratio": d.z_m / d.z0_m, "n": d.n, "offset": offset, "stop": d.stop, "rg": rg}
    nodes = _nodes({k: x[pooled] for k, x in rows.items()}, tile, dims)
    alone = ~pooled
    parts = [nodes, {k: x[alone] for k, x in rows.items()}]
    parts[1]["z0"] = d.z0_m[alone]
    out = {k: np.concatenate([p[k] for p in parts]) for k in ("a", "b", "kw", "pw", "u", "v", "z0", "ratio", "n", "offset", "stop", "rg")}
    g = GroupedData(z_m=out["z0"] * out["ratio"], m2_m2=np.full(len(out["z0"]), np.nan), m4_m4=np.full(len(out["z0"]), np.nan),
                    n=out["n"], stop=out["stop"], u_px=out["u"], v_px=out["v"], fb_px_m=d.fb_px_m,
                    depth_unit_m=d.depth_unit_m, n_dropped_zero=d.n_dropped_zero, stops=d.stops, sources=d.sources,
                    calibration=d.calibration)
    g.__dict__["z0_m"] = out["z0"]
    g.__dict__["grid_offset"] = out["offset"]
    g.__dict__["range_group"] = out["rg"]
    g.__dict__["kurtosis_by_range"] = d.kurtosis_by_range
    g.weights = (out["a"], out["b"], out["kw"], out["pw"])
    g.constant = gamma_constant(d)
    _, measured, se = d.fill_by_stop
    g.fill_table = (np.unique(d.stop), measured, se)
    g.full = d
    g.tile_px = tile_px
    return g


def _nodes(r: dict[str, np.ndarray], tile: np.ndarray, dims: int) -> dict[str, np.ndarray]:
    """The 1 + 2 dims nodes of every group (rows `r` of its pixels, `tile` their group): positions, ranges,
    offsets and the four kinds of weight (module docstring)."""
    a, u, v, lz = r["a"], r["u"], r["v"], r["lz"]
    # the tile's centre (a-weighted), the spread of its positions and the plane of ln Z0 over them
    _, s = group_sums(tile, [a, a * u, a * v, a * u * u, a * v * v, a * u * v, a * lz, a * u * lz, a * v * lz,
                             a * np.log(r["ratio"]), a * r["n"], a * r["offset"]])
    A = s[:, 0]
    uc, vc, lzc = s[:, 1] / A, s[:, 2] / A, s[:, 6] / A
    gu, gv = _plane_slopes(s, A, uc, vc, lzc)
    offset_mean = s[:, 11] / A
    du, dv = u - uc[tile], v - vc[tile]
    e = lz - lzc[tile] - gu[tile] * du - gv[tile] * dv
    xi = [du, dv, e, r["offset"] - offset_mean[tile]][:dims]
    moments = [group_sums(tile, [w, *(w * x for x in xi), *(w * x * x for x in xi)])[1]
               for w in (a, r["b"], r["kw"], r["pw"])]
    h = np.sqrt(dims * moments[0][:, 1 + dims:] / A[:, None])  # (groups, dims): the a-weights' centre node weighs 0
    count = 1 + 2 * dims  # the centre, then -h and +h along each axis
    steps = np.zeros((count, dims))
    for i in range(dims):
        steps[1 + 2 * i, i], steps[2 + 2 * i, i] = -1.0, 1.0
    at = steps[None, :, :] * h[:, None, :]  # (groups, nodes, dims)
    first = _first_rows(tile, len(A))  # any pixel of the group: its stop and range window

    def each(x: np.ndarray) -> np.ndarray:
        return np.repeat(x, count)

    wa, wb, wk, wp = (_node_weights(m, h).ravel() for m in moments)
    return {"a": wa, "b": wb, "kw": wk, "pw": wp, "u": (uc[:, None] + at[:, :, 0]).ravel(),
            "v": (vc[:, None] + at[:, :, 1]).ravel(),
            "z0": np.exp(lzc[:, None] + gu[:, None] * at[:, :, 0] + gv[:, None] * at[:, :, 1] + at[:, :, 2]).ravel(),
            "ratio": each(np.exp(s[:, 9] / A)), "n": each(s[:, 10] / A),
            "offset": (offset_mean[:, None] + (at[:, :, 3] if dims > 3 else 0.0)).ravel(),
            "stop": each(r["stop"][first]), "rg": each(r["rg"][first])}


def _mean_off(d: ModelData, tile: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Pixels whose measured mean is further from their tile's plane of ln Z0 than OFF_MEAN times the larger of
    their mean's standard error and the spread of their stop's pixels about their planes (robust: 1.4826 x the
    median absolute deviation; the wall's relief is part of it): mismatched samples pulled the mean and raised
    the variance together, so such a pixel's range and variance co-vary in a heavy tail a second-order
    expansion does not follow. They stay pixels."""
    u, v, lz = d.u_px.astype(np.float64), d.v_px.astype(np.float64), np.log(d.z0_m)
    e = _plane_residual(tile, a, u, v, lz)
    neighbours, _ = d.neighbour_variance
    scale = np.sqrt(np.where(np.isfinite(neighbours), neighbours, d.s2_m2) / d.n) / d.z0_m
    slices = d.stop_slices() or [np.flatnonzero(d.stop == s) for s in np.unique(d.stop)]
    for rows in slices:
        es = e[rows]
        spread = 1.4826 * np.median(np.abs(es - np.median(es)))
        scale[rows] = np.maximum(scale[rows], spread)
    off = np.abs(e) > OFF_MEAN * scale
    # and a pixel that alone makes DOMINANT of its tile's spread of range sets the tile's nodes: it stays a pixel too
    share = a * e * e
    _, total = group_sums(tile, [np.where(off, 0.0, share)])
    return off | (share > DOMINANT * total[tile, 0])


def _plane_residual(tile: np.ndarray, a: np.ndarray, u: np.ndarray, v: np.ndarray, lz: np.ndarray) -> np.ndarray:
    """Each pixel's ln Z0 less its tile's a-weighted least-squares plane over (u, v)."""
    _, s = group_sums(tile, [a, a * u, a * v, a * u * u, a * v * v, a * u * v, a * lz, a * u * lz, a * v * lz])
    A = s[:, 0]
    uc, vc, lzc = s[:, 1] / A, s[:, 2] / A, s[:, 6] / A
    gu, gv = _plane_slopes(s, A, uc, vc, lzc)
    return lz - lzc[tile] - gu[tile] * (u - uc[tile]) - gv[tile] * (v - vc[tile])


def _plane_slopes(s: np.ndarray, A: np.ndarray, uc: np.ndarray, vc: np.ndarray, lzc: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The slopes of ln Z0 over u and v per tile, from the sums of `_plane_residual` (columns 3-8)."""
    suu, svv, suv = s[:, 3] / A - uc * uc, s[:, 4] / A - vc * vc, s[:, 5] / A - uc * vc
    sul, svl = s[:, 7] / A - uc * lzc, s[:, 8] / A - vc * lzc
    det = suu * svv - suv * suv
    ok = det > 1e-12 * np.maximum(suu * svv, 1e-300)
    gu = np.where(ok, (svv * sul - suv * svl) / np.where(ok, det, 1.0), np.where(suu > 0, sul / np.maximum(suu, 1e-300), 0.0))
    gv = np.where(ok, (suu * svl - suv * sul) / np.where(ok, det, 1.0), np.where(svv > 0, svl / np.maximum(svv, 1e-300), 0.0))
    return gu, gv


def _node_weights(m: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Node weights (tiles, 1 + 2 dims) reproducing, per tile, W = m[:, 0], M1 = m[:, 1:1+dims] and
    M2 = m[:, 1+dims:] (module docstring)."""
    dims = h.shape[1]
    W, M1, M2 = m[:, 0], m[:, 1:1 + dims], m[:, 1 + dims:]
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = np.where(h > 0, M2 / h**2, 0.0)
        tilt = np.where(h > 0, M1 / h, 0.0)
    out = np.empty((len(W), 1 + 2 * dims))
    out[:, 0] = W - spread.sum(axis=1)
    for i in range(dims):
        out[:, 1 + 2 * i] = (spread[:, i] - tilt[:, i]) / 2
        out[:, 2 + 2 * i] = (spread[:, i] + tilt[:, i]) / 2
    return out


def _first_rows(tile: np.ndarray, tiles: int) -> np.ndarray:
    """For each tile, the index of one of its rows."""
    first = np.empty(tiles, np.int64)
    first[tile[::-1]] = np.arange(len(tile))[::-1]
    return first
