"""Where the bias model fails and which effect is missing: the loop of the noise diagnosis, for the depth's bias.

Each stop's pixels are split into image regions (REGIONS: 4 x 3); each region gives the mean of Z - t (the curvature
of f b / d taken out, `stop_figures.curvature_free_m`) with its standard error, its mean rho^2 and its stop's time. A model is the
wall's offset plus effects (`bias_effects`), fitted by generalised least squares (maximum likelihood for normal
errors) with two variances beside the regions' own: tau^2 shared by a stop's regions (the stage's repeatability: its
position is off by the same at every pixel) and kappa^2 shared by a region over the stops (the wall's own relief,
the same at every stop), both profiled out by maximum likelihood. BIC counts them.

The loop: from the offset alone, each effect not in the model is fitted with it; the one that lowers BIC most is
added while it lowers BIC by more than 10 (very strong evidence, as for noise effects); the model it stops at is
within noise when its residuals, each region's less its stop's mean, agree with their errors by radius and by
position (chi^2, p >= 0.001), and, where the stage's tolerance is known, by range: each stop's mean residual against
its error and the stage's tolerance (the distance the stage may be off before the runner refuses to capture, taken as
one standard deviation), so the stage's scatter cannot take a bias far larger than any stage's error. A model the path
went on from is beyond noise by the evidence of the effect it added. Each step's RMS misfit (the regions' residuals,
in mm) shows the error falling. Without a clock (a folder import) every stop's time is 0 and a bias that changes with
time cannot be found; `has_clock` says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..models import ModelData
from ..models.data.model_data import stops_of
from ..models.data.stop_checks import stage_info
from ..models.parts.result import chi2_sf
from .bias import model_bias
from .bias_effects import BIAS_EFFECTS, BiasEffect
from .stop_figures import curvature_free_m

#: image regions (columns, rows) each stop's pixels are split into
REGIONS = (4, 3)
SIGNIFICANT_DBIC = -10.0
ALPHA = 1e-3


@dataclass(frozen=True)
class BiasGroups:
    """The regions of every stop (one row each): truth t (m), mean bias y (m) and its error se (m), rho2, time_s,
    the stop's index and the region's, and the region's mean normalised position x = (u - cx) / fx, y_norm."""

    t: np.ndarray
    y: np.ndarray
    se: np.ndarray
    rho2: np.ndarray
    time_s: np.ndarray
    stop: np.ndarray
    region: np.ndarray
    fb_px_m: float
    x: np.ndarray | None = None
    y_norm: np.ndarray | None = None
    stage_tolerance_m: float | None = None  # the check by range's scale (module docstring); None: no check by range
    has_clock: bool = True  # the stops' times are known

    def __len__(self) -> int:
        return len(self.y)


def bias_groups(d: ModelData, stage_tolerance_m: float | None = None) -> BiasGroups | None:
    """The regions of the stops whose truth is known (None with fewer than three such stops); `stage_tolerance_m`:
    the recording's stage's (`stage_tolerance`), for the check by range."""
    table = d.stops
    if table is None or table.truth_m is None:
        return None
    u, v = np.asarray(d.u_px, float), np.asarray(d.v_px, float)
    if not (np.isfinite(u).all() and np.isfinite(v).all()):
        return None
    cols = np.minimum((REGIONS[0] * u / (u.max() + 1)).astype(int), REGIONS[0] - 1)
    rows = np.minimum((REGIONS[1] * v / (v.max() + 1)).astype(int), REGIONS[1] - 1)
    region = rows * REGIONS[0] + cols
    dev = curvature_free_m(d) - np.asarray(table.truth_m, float)[d.stop]
    rho2, xn, yn = np.asarray(d.rho2, float), np.asarray(d.x_norm, float), np.asarray(d.y_norm, float)
    out = {k: [] for k in ("t", "y", "se", "rho2", "time_s", "stop", "region", "x", "y_norm")}
    stops = [s for s in stops_of(d).tolist() if math.isfinite(table.truth_m[s]) and table.truth_m[s] > 0]
    if len(stops) < 3:
        return None
    t0 = np.nanmin(table.time_s[stops]) if np.isfinite(table.time_s[stops]).any() else 0.0
    for s in stops:
        at = d.stop == s
        for r in range(REGIONS[0] * REGIONS[1]):
            m = at & (region == r) & np.isfinite(dev)
            n = int(m.sum())
            if n < 3:
                continue
            x = dev[m]
            out["t"].append(float(table.truth_m[s]))
            out["y"].append(float(x.mean()))
            out["se"].append(float(x.std(ddof=1) / math.sqrt(n)) or 1e-9)
            out["rho2"].append(float(rho2[m].mean()))
            out["x"].append(float(xn[m].mean()))
            out["y_norm"].append(float(yn[m].mean()))
            time = table.time_s[s] - t0
            out["time_s"].append(float(time) if math.isfinite(time) else 0.0)
            out["stop"].append(s)
            out["region"].append(r)
    a = {k: np.array(v) for k, v in out.items()}
    clock = bool(np.isfinite(table.time_s[stops]).any())
    return BiasGroups(a["t"], a["y"], a["se"], a["rho2"], a["time_s"], a["stop"].astype(int), a["region"].astype(int),
                      d.fb_px_m, a["x"], a["y_norm"], stage_tolerance_m, clock)


def stage_tolerance(recording) -> float | None:
    """The tolerance of the stage an open `Recording` was made with, m (drivers.stage.Stage.tolerance_m), or None."""
    tol = stage_info(recording).get("tolerance_m")
    ok = isinstance(tol, (int, float)) and not isinstance(tol, bool) and math.isfinite(tol) and tol > 0
    return float(tol) if ok else None


def predicted_bias(g: BiasGroups, effects: tuple[BiasEffect, ...], p: dict[str, float]) -> np.ndarray:
    """Z - t of every region under the model (the module docstring's equation)."""
    s_total, delta = 0.0, 0.0
    for e in effects:
        ds, dd = e.add(p, g)
        s_total, delta = s_total + ds, delta + dd
    return model_bias(g.t, {"offset_m": p["offset_m"], "scale": s_total, "disparity_offset_px": delta}, g.fb_px_m)


@dataclass
class BiasModelFit:
    effects: tuple[BiasEffect, ...]
    values: dict[str, float]
    errors: dict[str, float]
    loglik: float
    bic: float
    tau_m: float
    kappa_m: float
    residual_m: np.ndarray
    checks: dict[str, tuple[float, int, float]] = field(default_factory=dict)  # family: (chi2, dof, p)

    @property
    def name(self) -> str:
        return "+".join(["offset", *(e.name for e in self.effects)])

    @property
    def within_noise(self) -> bool:
        return all(p >= ALPHA for _, _, p in self.checks.values())

    @property
    def rms_mm(self) -> float:
        return float(1e3 * np.sqrt(np.mean(self.residual_m**2)))


def _covariance(g: BiasGroups, tau2: float, kappa2: float) -> np.ndarray:
    same_stop = g.stop[:, None] == g.stop[None, :]
    same_region = g.region[:, None] == g.region[None, :]
    return np.diag(g.se**2) + tau2 * same_stop + kappa2 * same_region


def _gls(g, effects, names, start, cov) -> tuple[dict[str, float], np.ndarray, float]:
    """Gauss-Newton for the values under the covariance `cov`: the values, their covariance and the log-likelihood."""
    chol = np.linalg.cholesky(cov)
    logdet = 2.0 * float(np.sum(np.log(np.diag(chol))))
    whiten = np.linalg.inv(chol)  # once: every residual below is whitened by a product, not a solve
    p = dict(start)

    def whitened(q):
        return whiten @ (g.y - predicted_bias(g, effects, q))

    bounds = {q.name: (q.low, q.high) for e in effects for q in e.params}
    bounds["offset_m"] = (-1.0, 1.0)
    for _ in range(60):
        r = whitened(p)
        jac = np.empty((len(g), len(names)))
        for i, n in enumerate(names):
            h = 1e-6 * max(abs(p[n]), 1e-3)
            up, down = dict(p), dict(p)
            up[n] += h
            down[n] -= h
            jac[:, i] = (whitened(down) - whitened(up)) / (2 * h)  # d prediction / d p, whitened
        step, *_ = np.linalg.lstsq(jac, r, rcond=None)
        new = {n: float(np.clip(p[n] + s, *bounds[n])) for n, s in zip(names, step)}
        new = {**p, **new}
        if np.sum(whitened(new) ** 2) > np.sum(r**2):  # a step that overshoots: halve it
            for _ in range(20):
                step = step / 2
                new = {**p, **{n: float(np.clip(p[n] + s, *bounds[n])) for n, s in zip(names, step)}}
                if np.sum(whitened(new) ** 2) <= np.sum(r**2):
                    break
        done = np.all(np.abs(step) <= 1e-10 * (1.0 + np.abs([p[n] for n in names])))
        p = new
        if done:
            break
    r = whitened(p)
    try:
        cov_p = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        cov_p = np.full((len(names), len(names)), np.nan)
    loglik = -0.5 * (float(r @ r) + logdet + len(g) * math.log(2 * math.pi))
    return p, cov_p, loglik


def fit_bias_model(g: BiasGroups, effects: tuple[BiasEffect, ...],
                   variances: tuple[float, float] | None = None) -> BiasModelFit:
    """The model offset + `effects` fitted to `g`, the two variances (tau^2, kappa^2) profiled out by maximum
    likelihood: a search over each in turn, on a log scale, from `variances` (a fit's, to start near) or the regions'
    median error."""
    names = ["offset_m", *(q.name for e in effects for q in e.params)]
    first = {"offset_m": 0.0, **{q.name: q.start for e in effects for q in e.params}}
    starts = [first, *({**first, **s} for e in effects for s in e.starts)]
    floor = 1e-6 * float(np.median(g.se**2))  # a variance this small is none
    tau2, kappa2 = variances or (float(np.median(g.se**2)),) * 2
    tau2, kappa2 = max(tau2, floor), max(kappa2, floor)
    best = max((_gls(g, effects, names, st, _covariance(g, tau2, kappa2)) for st in starts), key=lambda x: x[2])
    for factor in (16.0, 4.0, 2.0, 1.25):
        moved = True
        while moved:
            moved = False
            for which in (0, 1):
                for f in (factor, 1 / factor):
                    t2, k2 = (tau2 * f, kappa2) if which == 0 else (tau2, kappa2 * f)
                    if max(t2, k2) > 1e6 * float(np.var(g.y) + np.max(g.se**2)) or min(t2, k2) < floor:
                        continue
                    trial = _gls(g, effects, names, best[0], _covariance(g, t2, k2))
                    if trial[2] > best[2] + 1e-9:
                        best, tau2, kappa2, moved = trial, t2, k2, True
                        break
    p, cov_p, ll = best
    k = len(names) + (tau2 > 10 * floor) + (kappa2 > 10 * floor)
    residual = g.y - predicted_bias(g, effects, p)
    fit = BiasModelFit(tuple(effects), p, {n: float(math.sqrt(cov_p[i, i])) for i, n in enumerate(names)}, ll,
                       -2 * ll + k * math.log(len(g)), math.sqrt(tau2), math.sqrt(kappa2), residual)
    fit.checks = _checks(g, residual, kappa2)
    if g.stage_tolerance_m is not None:
        fit.checks["by range"] = _range_check(g, residual, len(names))
    return fit


def _range_check(g: BiasGroups, r: np.ndarray, n_params: int) -> tuple[float, int, float]:
    """Each stop's weighted mean residual against its error and the stage's tolerance (module docstring)."""
    w = 1.0 / g.se**2
    chi2, stops = 0.0, np.unique(g.stop)
    for s in stops:
        m = g.stop == s
        chi2 += float((np.sum(w[m] * r[m]) / np.sum(w[m])) ** 2 / (1.0 / np.sum(w[m]) + g.stage_tolerance_m**2))
    dof = max(len(stops) - n_params, 1)
    return chi2, dof, chi2_sf(chi2, dof)


def _checks(g: BiasGroups, r: np.ndarray, kappa2: float) -> dict[str, tuple[float, int, float]]:
    """Each region's residual less its stop's weighted mean (the stage's error cancels), pooled by radius (three
    bins) and by region over the stops, against its error (the regions' own and the wall's relief, kappa^2)."""
    w = 1.0 / g.se**2
    out = {}
    centred = np.empty_like(r)
    var = np.empty_like(r)
    for s in np.unique(g.stop):
        m = g.stop == s
        mean = np.sum(w[m] * r[m]) / np.sum(w[m])
        centred[m] = r[m] - mean
        var[m] = g.se[m] ** 2 * (1 - w[m] / np.sum(w[m]))
    edges = np.quantile(g.rho2, [1 / 3, 2 / 3])
    families = {"by radius": np.digitize(g.rho2, edges), "by position": g.region}
    for name, key in families.items():
        chi2, dof = 0.0, 0
        for b in np.unique(key):
            m = key == b
            stops = len(np.unique(g.stop[m]))
            v = np.sum(var[m]) / m.sum() ** 2 + kappa2 * (stops / m.sum()) ** 2 * (name == "by position")
            chi2 += float(np.mean(centred[m]) ** 2 / v) if v > 0 else 0.0
            dof += 1
        out[name] = (chi2, dof, chi2_sf(chi2, dof))
    return out


@dataclass
class BiasDiagnosis:
    steps: list[BiasModelFit]
    candidates: list[list[tuple[str, float]]]  # per step: (effect, dBIC) of each tried
    stopped: str
    stage_tolerance_m: float | None = None  # BiasGroups'
    has_clock: bool = True

    @property
    def added(self) -> list[str]:
        return [s.effects[-1].name for s in self.steps[1:]]

    @property
    def final(self) -> BiasModelFit:
        return self.steps[-1]


def diagnose_bias(g: BiasGroups, catalogue: dict[str, BiasEffect] | None = None) -> BiasDiagnosis:
    """The loop of the module docstring, from the offset alone."""
    catalogue = catalogue or BIAS_EFFECTS
    steps = [fit_bias_model(g, ())]
    tried: list[list[tuple[str, float]]] = []
    while True:
        current = steps[-1]
        have = {e.name for e in current.effects}
        fits = [fit_bias_model(g, (*current.effects, e), (current.tau_m**2, current.kappa_m**2))
                for e in catalogue.values() if e.name not in have]
        ranked = sorted(((f.effects[-1].name, f.bic - current.bic, f) for f in fits), key=lambda x: x[1])
        tried.append([(n, db) for n, db, _ in ranked])
        if not ranked or ranked[0][1] >= SIGNIFICANT_DBIC:
            stopped = "no bias effect lowers BIC by more than 10" if ranked else "every bias effect is in"
            break
        steps.append(ranked[0][2])
    return BiasDiagnosis(steps, tried, stopped, g.stage_tolerance_m, g.has_clock)
