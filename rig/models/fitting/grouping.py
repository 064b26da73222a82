"""Pixels grouped, for fast fits: each small tile of a stop stands in for its pixels by 7 weighted nodes.

Every part of the likelihood (`rig.models.fitting.likelihood`) is a weighted sum over pixels of a smooth
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
from numba import njit

from ..data.model_data import ModelData, stops_of
from .likelihood import gamma_constant, gamma_constant_by_stop, likelihood_weights, prepare

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

    def pieces(self, rows: int | None = None, *, neighbours: bool = True):
        yield self  # one piece: the nodes carry their own weights, which a plain slice would lose

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
    quadrature. A group of no more pixels than nodes keeps its pixels as they are. Sums over the pixels go in
    compiled passes (`_plane_sums`, `_residuals`, `_moments`)."""

    prepare(d)
    a, b, kw, _ = likelihood_weights(d)
    u, v = d.u_px.astype(np.float64), d.v_px.astype(np.float64)
    rg = d.range_group
    tu, tv = (u // tile_px).astype(np.int64), (v // tile_px).astype(np.int64)
    key = ((d.stop.astype(np.int64) * (int(rg.max() - rg.min()) + 1) + (rg - rg.min())) * (int(tv.max()) + 1) + tv) \
        * (int(tu.max()) + 1) + tu
    offset = np.abs(d.grid_offset)
    by_offset = by_offset and bool(rounding_matters(d).any())
    if by_offset:
        fbin = np.where(rounding_matters(d), np.minimum((offset * 2 * OFFSET_BINS).astype(np.int64), OFFSET_BINS - 1),
                        OFFSET_BINS)
        key = key * (OFFSET_BINS + 1) + fbin
    tile, count = _dense_index(key)
    dims = 4 if by_offset else 3
    lz = d.ln_z0_m  # made by prepare, with the rest of what every evaluation uses
    pooled = (count[tile] > 1 + 2 * dims) & ~_mean_off(d, tile, len(count), a, u, v, lz)
    tile, count = _dense_index(np.where(pooled, tile, -1))
    groups = len(count)
    s = _plane_sums(tile, a, u, v, lz, (np.log(d.z_m / d.z0_m), d.n, offset), groups)
    A = s[:, 0]
    uc, vc, lzc = s[:, 1] / A, s[:, 2] / A, s[:, 6] / A
    gu, gv = _plane_slopes(s, A, uc, vc, lzc)
    ratio, n_mean, offset_mean = np.exp(s[:, 9] / A), s[:, 10] / A, s[:, 11] / A
    e = _residuals(tile, u, v, lz, uc, vc, lzc, gu, gv)
    axes = (u, v, e, offset)[:dims]
    centre = np.stack([uc, vc, np.zeros(groups), offset_mean][:dims])
    moments = _moments(tile, (a, b, kw, np.ones(len(d))), axes, centre, groups)  # (4, groups, 1 + 2 dims)
    nodes = _nodes(moments, A, uc, vc, lzc, gu, gv, offset_mean, dims)
    each = 1 + 2 * dims
    first = _first_rows(np.where(pooled, tile, groups), groups + 1)[:-1]  # any pixel of the group
    nodes.update({"ratio": np.repeat(ratio, each), "n": np.repeat(n_mean, each), "stop": np.repeat(d.stop[first], each),
                  "rg": np.repeat(rg[first], each)})
    alone = ~pooled
    pixels = {"a": a[alone], "b": b[alone], "kw": kw[alone], "pw": np.ones(int(alone.sum())), "u": u[alone], "v": v[alone],
              "z0": d.z0_m[alone], "ratio": (d.z_m / d.z0_m)[alone], "n": d.n[alone], "offset": offset[alone],
              "stop": d.stop[alone], "rg": rg[alone]}
    out = {k: np.concatenate([nodes[k], pixels[k]]) for k in pixels}
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


def whole_stops(d: ModelData, mask: np.ndarray, *, statistics: bool = True) -> ModelData:
    """The rows of `d` where `mask` is true, which must be whole stops, with the grouped nodes of those stops
    (`rig.models.fitting.grouping.nodes_of_stops`: tiles never span stops) and the covariates computed so far. With
    `statistics`, also the per-pixel statistics computed so far (they are computed within a stop, so a stop's
    values do not depend on the other stops; the kurtosis by range window is the whole data's, shared only
    where a window holds two stops' pixels); without, only what a fit on the nodes reads of the pixels (the
    data-only constant and the fill by stop, from the whole data's per-stop sums), copying less. Held-out
    scores use it, fitting with some stops left out without measuring and grouping the rest again."""

    out = d._taken(mask, derived=statistics)
    out.__dict__["kurtosis_by_range"] = d.kurtosis_by_range
    if not statistics:
        stops, constants = gamma_constant_by_stop(d)
        kept = np.isin(stops, stops_of(out))
        out.__dict__["gamma_constant"] = float(constants[kept].sum())
        idx, measured, se = d.fill_by_stop
        out.__dict__["fill_by_stop"] = ((np.cumsum(kept) - 1)[idx[mask]], measured[kept], se[kept])
    for key in ("grouped", "grouped_by_offset"):
        g = d.__dict__.get(key)
        if g is not None:
            out.__dict__[key] = out if g is d else nodes_of_stops(g, out)
    return out


def nodes_of_stops(g: GroupedData, d: ModelData) -> GroupedData:
    """The nodes of `g` that stand for the stops of `d` (whole stops of the data `g` was grouped from, with their
    per-pixel statistics): what grouping `d` itself would give with g's tile size, since no tile spans two stops
    and every pixel's weights come from its own stop; the data-only constant and the fill table are d's."""

    stops = stops_of(d)
    keep = (np.bincount(stops, minlength=int(g.stop.max()) + 1) > 0)[g.stop]
    out = GroupedData(z_m=g.z_m[keep], m2_m2=g.m2_m2[keep], m4_m4=g.m4_m4[keep], n=g.n[keep], stop=g.stop[keep],
                      u_px=g.u_px[keep], v_px=g.v_px[keep], **{k: v[keep] for k, v in g._cols.items()}, **g._known())
    for name in ("z0_m", "grid_offset", "range_group"):
        out.__dict__[name] = g.__dict__[name][keep]
    out.__dict__["kurtosis_by_range"] = d.kurtosis_by_range
    out.weights = tuple(w[keep] for w in g.weights)
    out.constant = gamma_constant(d)
    _, measured, se = d.fill_by_stop
    out.fill_table = (stops, measured, se)
    out.full = d
    out.tile_px = g.tile_px
    return out


def rounding_matters(d: ModelData) -> np.ndarray:
    """The pixels whose rounded variance depends on where their mean sits between depth levels: a spread (the
    neighbours' variance, else their own) under OFFSET_SPREAD depth units. Kept with `d`."""
    if "rounding_matters" not in d.__dict__:
        neighbours, _ = d.neighbour_variance
        spread = np.sqrt(np.where(np.isfinite(neighbours), neighbours, d.s2_m2)) / d.depth_unit_m
        d.__dict__["rounding_matters"] = spread < OFFSET_SPREAD
    return d.__dict__["rounding_matters"]


def _nodes(moments: np.ndarray, A: np.ndarray, uc: np.ndarray, vc: np.ndarray, lzc: np.ndarray, gu: np.ndarray,
           gv: np.ndarray, offset_mean: np.ndarray, dims: int) -> dict[str, np.ndarray]:
    """The 1 + 2 dims nodes of every group: positions, ranges, offsets and the four kinds of weight (module
    docstring), from the groups' moments along each axis."""
    h = np.sqrt(dims * moments[0][:, 1 + dims:] / A[:, None])  # (groups, dims): the a-weights' centre node weighs 0
    count = 1 + 2 * dims  # the centre, then -h and +h along each axis
    steps = np.zeros((count, dims))
    for i in range(dims):
        steps[1 + 2 * i, i], steps[2 + 2 * i, i] = -1.0, 1.0
    at = steps[None, :, :] * h[:, None, :]  # (groups, nodes, dims)
    wa, wb, wk, wp = (_node_weights(m, h).ravel() for m in moments)
    return {"a": wa, "b": wb, "kw": wk, "pw": wp, "u": (uc[:, None] + at[:, :, 0]).ravel(),
            "v": (vc[:, None] + at[:, :, 1]).ravel(),
            "z0": np.exp(lzc[:, None] + gu[:, None] * at[:, :, 0] + gv[:, None] * at[:, :, 1] + at[:, :, 2]).ravel(),
            "offset": (offset_mean[:, None] + at[:, :, 3]).ravel() if dims > 3 else np.repeat(offset_mean, count)}


def _dense_index(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row's group as 0..G-1 in the order of `key` (negative keys: -1, in no group), and each group's rows.
    By a table over the keys' span when it is not much larger than the rows (no sort), else by np.unique."""
    ok = key >= 0
    if not ok.any():
        return np.full(len(key), -1, np.int64), np.zeros(0, np.int64)
    lo, hi = int(key[ok].min()), int(key[ok].max())
    if hi - lo < 4 * len(key) + 1024:
        counts = np.bincount(key[ok] - lo, minlength=hi - lo + 1)
        present = counts > 0
        index = np.cumsum(present) - 1
        return np.where(ok, index[np.where(ok, key - lo, 0)], -1), counts[present]
    _, inverse, counts = np.unique(key[ok], return_inverse=True, return_counts=True)
    out = np.full(len(key), -1, np.int64)
    out[ok] = inverse
    return out, counts


def _mean_off(d: ModelData, tile: np.ndarray, groups: int, a: np.ndarray, u: np.ndarray, v: np.ndarray,
              lz: np.ndarray) -> np.ndarray:
    """Pixels whose measured mean is further from their tile's plane of ln Z0 than OFF_MEAN times the larger of
    their mean's standard error and the spread of their stop's pixels about their planes (robust: 1.4826 x the
    median absolute deviation; the wall's relief is part of it): mismatched samples pulled the mean and raised
    the variance together, so such a pixel's range and variance co-vary in a heavy tail a second-order
    expansion does not follow. And a pixel that alone makes DOMINANT of its tile's spread of range sets the
    tile's nodes. They stay pixels."""
    none = (a,)  # no extra column needed here; one is summed and not read (numba types no empty tuple)
    s = _plane_sums(tile, a, u, v, lz, none, groups)
    A = s[:, 0]
    uc, vc, lzc = s[:, 1] / A, s[:, 2] / A, s[:, 6] / A
    gu, gv = _plane_slopes(s, A, uc, vc, lzc)
    e = _residuals(tile, u, v, lz, uc, vc, lzc, gu, gv)
    neighbours, _ = d.neighbour_variance
    scale = np.sqrt(np.where(np.isfinite(neighbours), neighbours, d.s2_m2) / d.n) / d.z0_m
    slices = d.stop_slices() or [np.flatnonzero(d.stop == s) for s in np.unique(d.stop)]
    for rows in slices:
        es = e[rows]
        spread = 1.4826 * np.median(np.abs(es - np.median(es)))
        scale[rows] = np.maximum(scale[rows], spread)
    off = np.abs(e) > OFF_MEAN * scale
    share = a * e * e
    total = _plane_sums(np.where(off, -1, tile), share, u, v, lz, none, groups)[:, 0]
    return off | (share > DOMINANT * total[np.maximum(tile, 0)])


def _plane_slopes(s: np.ndarray, A: np.ndarray, uc: np.ndarray, vc: np.ndarray, lzc: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The slopes of ln Z0 over u and v per tile, from the sums of `_plane_sums` (columns 3-8)."""
    suu, svv, suv = s[:, 3] / A - uc * uc, s[:, 4] / A - vc * vc, s[:, 5] / A - uc * vc
    sul, svl = s[:, 7] / A - uc * lzc, s[:, 8] / A - vc * lzc
    det = suu * svv - suv * suv
    ok = det > 1e-12 * np.maximum(suu * svv, 1e-300)
    gu = np.where(ok, (svv * sul - suv * svl) / np.where(ok, det, 1.0), np.where(suu > 0, sul / np.maximum(suu, 1e-300), 0.0))
    gv = np.where(ok, (suu * svl - suv * sul) / np.where(ok, det, 1.0), np.where(svv > 0, svl / np.maximum(svv, 1e-300), 0.0))
    return gu, gv


@njit(cache=True, nogil=True)
def _plane_sums(tile, a, u, v, lz, extra, groups):  # pragma: no cover - compiled
    """Per group (rows with tile < 0 left out): sum a, a u, a v, a u^2, a v^2, a u v, a lz, a u lz, a v lz, then
    a x for each array x of the tuple `extra`."""
    k = len(extra)
    s = np.zeros((groups, 9 + k))
    for i in range(tile.size):
        t = tile[i]
        if t < 0:
            continue
        w, x, y, z = a[i], u[i], v[i], lz[i]
        s[t, 0] += w
        s[t, 1] += w * x
        s[t, 2] += w * y
        s[t, 3] += w * x * x
        s[t, 4] += w * y * y
        s[t, 5] += w * x * y
        s[t, 6] += w * z
        s[t, 7] += w * x * z
        s[t, 8] += w * y * z
        for j in range(k):
            s[t, 9 + j] += w * extra[j][i]
    return s


@njit(cache=True, nogil=True)
def _residuals(tile, u, v, lz, uc, vc, lzc, gu, gv):  # pragma: no cover - compiled
    """Each pixel's ln Z0 less its tile's plane over (u, v) (0 for rows in no tile)."""
    e = np.zeros(tile.size)
    for i in range(tile.size):
        t = tile[i]
        if t >= 0:
            e[i] = lz[i] - lzc[t] - gu[t] * (u[i] - uc[t]) - gv[t] * (v[i] - vc[t])
    return e


@njit(cache=True, nogil=True)
def _moments(tile, weights, axes, centre, groups):  # pragma: no cover - compiled
    """For each kind of weight w and group: sum w, then sum w xi_i and sum w xi_i^2 along each axis, xi the pixel's
    offset from the group's centre along it (e, the range residual, has centre 0)."""
    kinds, dims = len(weights), len(axes)
    m = np.zeros((kinds, groups, 1 + 2 * dims))
    for i in range(tile.size):
        t = tile[i]
        if t < 0:
            continue
        for q in range(kinds):
            w = weights[q][i]
            m[q, t, 0] += w
            for j in range(dims):
                x = axes[j][i] - centre[j, t]
                m[q, t, 1 + j] += w * x
                m[q, t, 1 + dims + j] += w * x * x
    return m


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
