"""Where a fitted model fails: measured against predicted sigma by range, radius, image position, IR
brightness and incidence, kurtosis by range, fill rate by stop and the frame mean over time; and the
verdict on all of them (`rig.diagnosis.consistency`).

Everything is a sum per bin, so the data are visited stop by stop, twice: once for what the bins
are (the largest radius, the brightness quantiles, the span of incidence angles), once for the
model's prediction, added into every family's sums at once. No array larger than a stop is made.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable

import numpy as np

from ..models import ModelData, ModelFit, Prediction
from ..models.data.group_sums import group_sums
from ..models.data.model_data import range_bin_index
from ..models.data.order_statistics import quantiles
from .bins import RADIUS_EDGES, BinComparison, BinSums, pixel_inputs, range_labels
from .consistency import Check, Consistency, fill_check, frame_mean_check, kurtosis_check, lag1_check, sigma_check
from .family_sums import FAMILIES, POSITION_TILES, FamilyRows, family_labels, new_sums, residual_sums
from .stop_sums import StopSums


@dataclass
class Residuals:
    """Measured against predicted statistics of one fitted model, and the verdict on them."""

    by_range: BinComparison
    by_radius: BinComparison
    by_position: BinComparison | None
    by_brightness: BinComparison | None
    by_incidence: BinComparison | None
    consistency: Consistency
    by_range_radius: BinComparison | None = None  # the headline's bins (`rig.diagnosis.scores`)

    @property
    def image_map(self) -> np.ndarray:
        """ln(measured / predicted sigma) on the POSITION_TILES grid of the image (all stops pooled); NaN where empty."""
        nx, ny = POSITION_TILES
        out = np.full((ny, nx), np.nan)
        b = self.by_position
        if b is not None:
            for lab, lr in zip(b.labels, b.log_ratio):
                k = int(lab)
                out[k // nx, k % nx] = lr
        return out

    @property
    def fill_by_stop(self) -> list[tuple[str, float, float]]:
        """(stop, measured fill, predicted fill) per stop."""
        c = self.consistency.find("fill rate", "stop")
        return [] if c is None else [(lab, float(m), float(p)) for lab, m, p in zip(c.labels, c.measured, c.predicted)]


def position_label(label: str) -> str:
    nx, _ = POSITION_TILES
    k = int(label)
    return f"image tile column {k % nx + 1} of {nx}, row {k // nx + 1}"


@dataclass
class _Layout:
    """What the bins are, from a first pass over the data."""

    rho_edges: np.ndarray
    tiles: tuple[float, float] | None  # largest u and v + 1, px (None: positions unknown)
    ir_edges: np.ndarray | None  # brightness quantiles (None: no IR)
    angle_edges: np.ndarray | None  # incidence angles, deg (None: all rays meet the wall at about one angle)
    range_windows: set

    @classmethod
    def of(cls, d: ModelData) -> "_Layout":
        """The bins of `d`, kept with it: a diagnosis compares several fits with the same data."""
        kept = d.__dict__.get("residual_layout")
        if kept is None:
            kept = d.__dict__["residual_layout"] = cls._of(d)
        return kept

    @classmethod
    def _of(cls, d: ModelData) -> "_Layout":
        rho_max, u_max, v_max, a_lo, a_hi, windows = 0.0, -np.inf, -np.inf, np.inf, -np.inf, set()
        ir_all, n_ir = np.empty(len(d), np.float32), 0  # the finite brightnesses, filled in place: one copy of them
        for c in d.pass_pieces(neighbours=False):
            if len(c) == 0:
                continue
            rho_max = max(rho_max, float(np.sqrt(np.max(c.rho2))))
            u_max, v_max = max(u_max, float(np.nanmax(c.u_px))), max(v_max, float(np.nanmax(c.v_px)))
            cos = c.cos_inc  # the angle's extremes are those of its cosine (arccos decreases): no angle per pixel here
            a_lo, a_hi = min(a_lo, float(_degrees(cos.max()))), max(a_hi, float(_degrees(cos.min())))
            rb = range_bin_index(c.z_m)
            windows.update(range(int(rb.min()), int(rb.max()) + 1))  # labels; empty windows have no bin
            ir = c.ir
            ir = ir[np.isfinite(ir)]
            ir_all[n_ir:n_ir + len(ir)] = ir
            n_ir += len(ir)
        positions = len(d) and np.isfinite(d.u_px).all() and np.isfinite(d.v_px).all()
        # np.quantile's values, by a histogram selection (rig.models.data.order_statistics): no partition of every brightness
        ir_edges = quantiles(ir_all[:n_ir], np.linspace(0, 1, 7)).astype(np.float64) if n_ir > 100 else None
        del ir_all
        angle_edges = np.linspace(a_lo, a_hi + 1e-9, 6) if a_hi - a_lo > 1 else None
        return cls(np.linspace(0, rho_max + 1e-9, 6), (u_max + 1, v_max + 1) if positions else None, ir_edges,
                   angle_edges, windows)

    def names(self) -> list[str]:
        """The families the data have (of FAMILIES: positions, IR and a span of incidence angles are needed)."""
        present = {"position": self.tiles is not None, "brightness": self.ir_edges is not None,
                   "incidence": self.angle_edges is not None}
        return [name for name in FAMILIES if present.get(name, True)]

    @cached_property
    def spans(self) -> tuple[np.ndarray, np.ndarray]:
        """Each family's smallest label and number of labels (FAMILIES order; 0 for one the data lack): every label
        a row can have (made once: every piece's pass uses them)."""
        windows = sorted(self.range_windows) or [0]
        spans = {"range": (windows[0], windows[-1] - windows[0] + 1), "radius": (0, len(self.rho_edges) - 1),
                 "range_radius": (windows[0] * 10, (windows[-1] - windows[0]) * 10 + len(RADIUS_EDGES) - 1),
                 "position": (0, POSITION_TILES[0] * POSITION_TILES[1]), "brightness": (0, 6),
                 "incidence": (0, 0 if self.angle_edges is None else len(self.angle_edges) - 1)}
        names = self.names()
        lo, size = zip(*(spans[name] if name in names else (0, 0) for name in FAMILIES))
        return np.array(lo, np.int64), np.array(size, np.int64)

    @cached_property
    def _edges(self) -> tuple:
        """The bins' inner edges (and the tiles) as `row_labels` takes them; empty for a family the data lack."""
        none = np.zeros(0)
        return (np.ascontiguousarray(self.rho_edges[1:-1]), np.asarray(RADIUS_EDGES[1:-1], dtype=float),
                np.zeros(0, np.float32) if self.tiles is None else np.asarray(self.tiles, dtype=np.float32),
                none if self.ir_edges is None else np.ascontiguousarray(self.ir_edges[1:-1]),
                none if self.angle_edges is None else np.ascontiguousarray(self.angle_edges[1:-1]))

    def _row_inputs(self, c: ModelData) -> tuple:
        """What `row_labels` reads of chunk `c`, then the bins' edges."""
        # a family the data lack gets a column of placeholders, not an empty one: a test for it in every row of
        # the compiled pass cost a third of the pass
        return (np.ascontiguousarray(c.z_m, dtype=float), np.ascontiguousarray(c.rho2, dtype=float),
                np.ascontiguousarray(c.u_px, dtype=np.float32), np.ascontiguousarray(c.v_px, dtype=np.float32),
                np.full(len(c), np.nan) if self.ir_edges is None else np.ascontiguousarray(c.ir, dtype=float),
                np.ones(len(c)) if self.angle_edges is None else np.ascontiguousarray(c.cos_inc, dtype=float),
                *self._edges)

    def families(self, c: ModelData) -> FamilyRows:
        """Every family's bin label (-1: not in the family) and covariate for each row of chunk `c`, in one compiled
        pass (`rig.diagnosis.family_sums.family_labels`): the bins `add` puts each row in, to look at (the tests hold
        them to numpy's digitize and rounding; `add` itself never makes them as arrays)."""
        labels, cov = np.empty((len(FAMILIES), len(c)), np.int64), np.empty((len(FAMILIES), len(c)))
        lo, hi = np.zeros(len(FAMILIES), np.int64), np.full(len(FAMILIES), -1, np.int64)
        family_labels(*self._row_inputs(c), labels, cov, lo, hi)
        names = self.names()
        at = [FAMILIES.index(name) for name in names]
        return FamilyRows(names, labels[at], cov[at], lo[at], np.maximum(hi - lo + 1, 0)[at])

    def add(self, out: np.ndarray, counts: np.ndarray, c: ModelData, pred: Prediction) -> None:
        """Chunk `c` and its prediction into every family's sums (`new_sums`), in one compiled pass
        (`rig.diagnosis.family_sums.residual_sums`)."""
        if len(c) == 0:
            return
        residual_sums(*self._row_inputs(c), *pixel_inputs(c, pred), *self.spans, out, counts)

    def bin_sums(self, out: np.ndarray, counts: np.ndarray) -> dict[str, BinSums]:
        """The sums `add` made, as each family's BinSums (bins no row fell in left out)."""
        lo, _ = self.spans
        sums = {}
        for name in self.names():
            f = FAMILIES.index(name)
            sums[name] = BinSums()
            for g in np.flatnonzero(counts[f]).tolist():
                sums[name].sums[int(lo[f]) + g] = out[f, g].copy()
        return sums

    def labels(self) -> dict[str, dict[int, str]]:
        e = self.rho_edges
        out = {"range": range_labels(self.range_windows), "radius": {i: f"rho {e[i]:.2f}-{e[i + 1]:.2f}" for i in range(5)}}
        r_labels, rr = out["range"], {}
        for rb in self.range_windows:
            for qb in range(len(RADIUS_EDGES) - 1):
                hi = RADIUS_EDGES[qb + 1]
                rr[int(rb) * 10 + qb] = f"{r_labels[rb]}, rho {RADIUS_EDGES[qb]:.1f}-" + ("" if np.isinf(hi) else f"{hi:.1f}")
        out["range_radius"] = rr
        if self.ir_edges is not None:
            q = self.ir_edges
            out["brightness"] = {i: f"IR {q[i]:.0f}-{q[i + 1]:.0f} DN" for i in range(6)}
        if self.angle_edges is not None:
            a = self.angle_edges
            out["incidence"] = {i: f"{a[i]:.0f}-{a[i + 1]:.0f} deg" for i in range(5)}
        return out


def _degrees(cos):
    """The incidence angle, deg, of a cosine (or an array of them)."""
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def residuals(fit: ModelFit, d: ModelData, pred: Prediction | None = None) -> Residuals:
    """Every comparison of `fit` with the data, and the verdict on them. With `pred` (the prediction for every
    row of `d`), in one piece; otherwise stop by stop."""
    layout = _Layout.of(d)
    out, counts = new_sums(layout.spans[1])
    stops = StopSums()
    for c, p in ([(d, pred)] if pred is not None else ((c, fit.predict(c)) for c in d.pass_pieces())):
        layout.add(out, counts, c, p)
        stops.add(c, p)
    sums = layout.bin_sums(out, counts)
    labels = layout.labels()
    done = {name: sums[name].finish(labels.get(name)) for name in sums if sums[name].sums}
    checks: list[Check] = [sigma_check(done["range"], "range"), sigma_check(done["radius"], "radius")]
    by_position = done.get("position")
    if by_position is not None:
        check = sigma_check(by_position, "position")
        check.labels = [position_label(lab) for lab in check.labels]
        checks.append(check)
    for name in ("brightness", "incidence"):
        if name in done:
            checks.append(sigma_check(done[name], name))
    kurt = kurtosis_check(done["range"])
    if kurt is not None:
        checks.append(kurt)
    checks.append(fill_check(d, stops))
    for extra in (frame_mean_check(d, stops), lag1_check(d, stops)):
        if extra is not None:
            checks.append(extra)
    return Residuals(done["range"], done["radius"], by_position, done.get("brightness"), done.get("incidence"),
                     Consistency(checks), done.get("range_radius"))


def compare_along(fit: ModelFit, d: ModelData, groups_of: Callable[[ModelData], np.ndarray],
                  covariate_of: Callable[[ModelData], np.ndarray], labels: dict[int, str] | None = None,
                  others: tuple[ModelFit, ...] = ()) -> tuple[BinComparison, list[dict[int, float]]]:
    """`fit` against the data in the bins `groups_of` gives each row (negative: left out), along `covariate_of`,
    stop by stop; and, per bin, the summed predicted variance of `fit` and of each of `others` (for ratios of
    models in the same bins)."""
    sums = BinSums()
    totals: list[dict[int, float]] = [{} for _ in range(1 + len(others))]
    for c in d.pass_pieces():
        groups, p = groups_of(c), fit.predict(c)
        sums.add(c, p, groups, covariate_of(c))
        for k, f in enumerate((fit, *others)):
            var = p.var_m2 if k == 0 else f.predict(c).var_m2
            keys, s = group_sums(groups, [var], skip_below=0)
            for key, total in zip(keys.tolist(), s[:, 0]):
                totals[k][key] = totals[k].get(key, 0.0) + float(total)
    return sums.finish(labels), totals


def consistency(fit: ModelFit, d: ModelData) -> Consistency:
    """The verdict on every statistic `fit` predicts (see `rig.diagnosis.consistency`)."""
    return residuals(fit, d).consistency
