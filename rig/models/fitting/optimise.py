"""Maximum likelihood for any composed model: bounded parameters mapped to free ones, L-BFGS-B with the
likelihood's analytic gradient (`rig.models.parts.tangents`; central differences for an effect without one), stopped
when a Newton step would gain less than 1e-6 nats (`rig.models.fitting.stopping`), with a Nelder-Mead polish on flat
ridges, started from the paper's closed-form power-law fit, and Cramer-Rao standard errors from a finite-difference
Hessian of the log-likelihood. Large data are fitted on grouped nodes (`rig.models.fitting.grouping`)."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ..data.independence import error_inflation
from ..data.model_data import ModelData
from ..parts.error_notes import error_notes
from ..parts.parameters import Param
from ..parts.result import ModelFit
from ..parts.tangents import analytic
from .closed_form import power_law_mle
from .grouping import group, rounding_matters, tile_size
from .likelihood import model_loglik_gradient
from .stopping import NewtonStop

if TYPE_CHECKING:
    from ..parts.component import ComposedModel

#: the Nelder-Mead polish's budget of objective evaluations, per free parameter (plus one)
NM_EVALUATIONS_PER_PARAMETER = 100
#: the polish runs only when a Newton step from L-BFGS-B's end promises more than this many nats (log-likelihood
#: units), and stops when its simplex's log-likelihoods agree to it: one standard error from the optimum costs 0.5,
#: so the parameters then sit within ~0.01 standard error of it. (It always ran, and stopped on
#: a 1e-8 step in the free coordinates before: on the demo's recording 287 evaluations, 4.2 s of a 14 s
#: diagnosis, to gain 4e-13 of the scaled objective after L-BFGS-B ended on its line search's rounding.)
NM_FATOL_NATS = 1e-4
#: L-BFGS-B stops when a step changes the (scaled) log-likelihood by less than this relative amount: at the
#: precision of the arithmetic, because looser stops (1e-12) left flat ridges (outliers) short of the optimum
FTOL = 1e-15


def _to_free(x: float, p: Param) -> float:
    lo, hi = p.min, p.max
    if math.isfinite(lo) and math.isfinite(hi):
        t = (min(max(x, lo), hi) - lo) / (hi - lo)
        t = min(max(t, 1e-9), 1 - 1e-9)
        return math.log(t / (1 - t))
    return x


def _from_free(y: float, p: Param) -> float:
    lo, hi = p.min, p.max
    if math.isfinite(lo) and math.isfinite(hi):
        return lo + (hi - lo) / (1 + math.exp(-min(max(y, -700.0), 700.0)))  # a wild step must not overflow
    return y


def _free_slope(y: float, p: Param) -> float:
    """d x / d y of `_from_free`: (hi - lo) s (1 - s) for a bounded parameter (s the logistic of y), 1 otherwise."""
    if math.isfinite(p.min) and math.isfinite(p.max):
        if abs(y) >= 700.0:
            return 0.0
        s = 1.0 / (1.0 + math.exp(-y))
        return (p.max - p.min) * s * (1.0 - s)
    return 1.0


def _free_slopes(free: list, y: np.ndarray) -> np.ndarray:
    """d x / d y for each free parameter at its free coordinate: k enters as ln k (x = e^y, as `fit_model` unpacks
    it), the others by `_free_slope`."""
    return np.array([math.exp(min(max(yi, -700.0), 700.0)) if n == "k" else _free_slope(yi, p)
                     for (n, p), yi in zip(free, y)])


def _newton_gain_nats(r, scale: float) -> float:
    """What a Newton step from L-BFGS-B's end point would still gain, in nats: 0.5 g' H^-1 g (the Newton decrement's
    half square; g the objective's gradient there, H^-1 L-BFGS-B's own inverse-Hessian estimate), times `scale`, the
    objective's divisor. Where L-BFGS-B ends on its line search's rounding this is ~1e-8 (nothing to polish); short
    of a flat ridge's optimum it is not. Infinite when the result carries no gradient or estimate."""
    try:
        g = np.asarray(r.jac, dtype=float)
        gain = 0.5 * float(g @ np.asarray(r.hess_inv.dot(g), dtype=float)) * scale
    except (AttributeError, TypeError, ValueError):
        return math.inf
    return gain if math.isfinite(gain) else math.inf


def _hessian(f, x: np.ndarray, steps: np.ndarray, *, diagonal: bool = False) -> np.ndarray:
    """Central differences: each second derivative from f at x +- the steps (the diagonal alone: 2n + 1 values)."""
    n = len(x)
    h = np.zeros((n, n))
    f0 = f(x)
    for i in range(n):
        ei = np.zeros(n)
        ei[i] = steps[i]
        h[i, i] = (f(x + ei) - 2 * f0 + f(x - ei)) / steps[i] ** 2
        for j in range(i + 1, n if not diagonal else i + 1):
            ej = np.zeros(n)
            ej[j] = steps[j]
            h[i, j] = h[j, i] = (f(x + ei + ej) - f(x + ei - ej) - f(x - ei + ej) + f(x - ei - ej)) / (4 * steps[i] * steps[j])
    return h


def fit_model(model: ComposedModel, d: ModelData, start: dict[str, float] | None = None, *, errors: bool = True,
              hold: frozenset[str] = frozenset(), grouped: bool = True, exact_loglik: bool = True,
              warm: ModelFit | None = None) -> ModelFit:
    """Maximum likelihood over all pixels; standard errors from the inverse Hessian (Cramer-Rao), unless
    `errors` is False (ranking candidates needs only the likelihood; `with_errors` adds them later).
    Parameters named in `hold` stay at their `start` values (a quick conditional fit).

    `warm`: the same model's fit to nearly the same data (a held-out fold's whole data). The fit then goes from its
    values alone (not also from the physical exponent), in coordinates whitened by its curvature (its Cramer-Rao
    covariance, else its optimiser's estimate, `ModelFit.metric`; none when a parameter sits on its bound:
    `_whitening`): there the likelihood is nearly round, so L-BFGS-B's first steps are Newton's and the stopping
    rule trusts that curvature from the first step (`NewtonStop`'s prior).

    Large data are fitted on their grouped nodes (`rig.models.fitting.grouping`, a second-order expansion of the
    likelihood about each small tile), when every effect of the model is smooth within a tile and `grouped`
    is true; the log-likelihood reported is then evaluated on every pixel at the optimum (with `exact_loglik`
    False, the nodes' value is reported: a held-out fold needs only the parameters)."""
    model.check(d)
    work = fit_data(model, d) if grouped else d
    values = {n: p.value for n, p in model.parameters()}
    # the base alone has a closed-form fit (the paper's): start there
    base_fit = _paper_fit(d, model.base.lam)
    values["k"], values["lambda"] = base_fit.k, base_fit.lam
    partial = type(model)(model.base)
    for e in model.effects:
        pred = partial.predict(values, work)
        for k, v in e.start(work, pred).items():
            values[f"{e.name}.{k}" if "." not in k else k] = v
        partial = partial + e
    if warm is not None:  # its values of this model's free parameters (a fixed one keeps this model's value)
        free_here = dict(model.free())
        start = {**{n: v for n, v in warm.values.items() if n in free_here}, **(start or {})}
    if start:
        values.update({k: v for k, v in start.items() if k in values})
    free = [(n, p) for n, p in model.free() if n not in hold]
    names = [n for n, _ in free]
    # k enters as log k: its scale varies over decades
    def unpack(y: np.ndarray) -> dict[str, float]:
        v = dict(values)
        for (n, p), yi in zip(free, y):
            v[n] = math.exp(min(max(yi, -700.0), 700.0)) if n == "k" else _from_free(yi, p)
        return v

    def pack(v: dict[str, float]) -> np.ndarray:
        return np.array([math.log(v[n]) if n == "k" else _to_free(v[n], p) for n, p in free])

    scale = abs(base_fit.loglik) + 1.0

    def objective(y: np.ndarray) -> float:
        try:
            ll = model.loglik(unpack(y), work)
        except FloatingPointError:
            return 1e30
        return -ll / scale if np.isfinite(ll) else 1e30

    def objective_and_gradient(y: np.ndarray) -> tuple[float, np.ndarray]:
        """The objective and its analytic gradient (`rig.models.parts.tangents`), by the chain rule through `unpack`."""
        v = unpack(y)
        try:
            ll, g = model_loglik_gradient(model, v, work, names)
        except FloatingPointError:
            return 1e30, np.zeros(len(y))
        if not (np.isfinite(ll) and np.all(np.isfinite(g))):
            return 1e30, np.zeros(len(y))
        return -ll / scale, -g * _free_slopes(free, y) / scale

    gradient = analytic(model)

    starts = [pack(values)]
    # the optimiser's coordinates x: y = y_ref + R x, R R' the warm fit's inverse-Hessian estimate (identity without)
    y_ref = starts[0]
    whiten = _whitening(warm, names, y_ref, free, scale) if warm is not None and not hold else None

    def to_y(x: np.ndarray) -> np.ndarray:
        return x if whiten is None else y_ref + whiten @ x

    def objective_x(x: np.ndarray) -> float:
        return objective(to_y(x))

    def objective_and_gradient_x(x: np.ndarray) -> tuple[float, np.ndarray]:
        f, g = objective_and_gradient(to_y(x))
        g_x = g if whiten is None else whiten.T @ g
        stop.seen(x, g_x)  # the current start's stopping rule (made below)
        return f, g_x

    if model.effects and model.base.lam is None and "lambda" not in hold and warm is None:
        # effects trade off against lambda: also start from the physical exponent (paper: 3 with
        # the projector on, 2 off) with k refitted for it
        lam_phys = 3.0 if d.projector_on.mean() > 0.5 else 2.0
        alt = dict(values, **{"lambda": lam_phys, "k": _paper_fit(d, lam_phys).k})
        starts.append(pack(alt))
    summary = dict(n_obs=len(d), n_samples=d.n_samples, dof=float(d.nu.sum()), z_range_m=(float(d.z_m.min()), float(d.z_m.max())))
    if not free:
        return ModelFit(model, values, {}, model.loglik(values, d), converged=True, message="nothing to fit", **summary)
    from scipy.optimize import minimize  # here, not at the top: 0.34 s of imports that `rig fit` (power law) never uses

    res = None
    with np.errstate(all="ignore"):
        for y0 in starts:
            x0 = y0 if whiten is None else np.zeros(len(y0))
            # central differences: forward ones are too coarse on the flat ridges effects make (outliers' fraction
            # against their width), where they stopped L-BFGS-B several standard errors short of the optimum
            if gradient:
                # stops L-BFGS-B once a Newton step would gain < 1e-6 nats
                stop = NewtonStop(scale, prior=None if whiten is None else np.eye(len(y0)))
                r = minimize(objective_and_gradient_x, x0, method="L-BFGS-B", jac=True, callback=stop,
                             options={"maxiter": 500, "ftol": FTOL, "gtol": 1e-10})
                if stop.stopped and _newton_gain_nats(r, scale) <= NM_FATOL_NATS:
                    r.success, r.message = True, f"CONVERGENCE: a Newton step would gain {stop.gain_nats:.1e} nats"
            else:
                r = minimize(objective_x, x0, method="L-BFGS-B", jac="3-point",
                             options={"maxiter": 500, "ftol": FTOL, "gtol": 1e-10})
            # polish with Nelder-Mead when L-BFGS-B stops early on a flat ridge; bounded, because every
            # evaluation visits every pixel (unbounded, a diagnosis could spend an hour polishing candidates)
            if not r.success and len(y0) > 1 and _newton_gain_nats(r, scale) > NM_FATOL_NATS:
                budget = NM_EVALUATIONS_PER_PARAMETER * (len(y0) + 1)
                r2 = minimize(objective_x, r.x, method="Nelder-Mead",
                              options={"maxiter": budget, "maxfev": budget, "xatol": math.inf, "fatol": NM_FATOL_NATS / scale})
                if r2.fun <= r.fun:
                    r = r2
            if res is None or r.fun < res.fun:
                res = r
    y0 = starts[0]
    best = unpack(to_y(res.x))
    ll = model.loglik(best, d if exact_loglik else work)
    se, cov, notes = _standard_errors(model, best, work, names) if errors else ({}, None, {})
    return ModelFit(model, best, se, ll, converged=bool(res.success) or res.fun < objective(y0), message=str(res.message),
                    covariance=cov, error_notes=notes, metric=_metric(res, whiten, names), **summary)


def _metric(res, whiten: np.ndarray | None, names: list[str]) -> tuple[tuple[str, ...], np.ndarray] | None:
    """L-BFGS-B's inverse-Hessian estimate at its end, in the free coordinates y (`fit_model`), with the names of
    the parameters it is over; None when the fit ended elsewhere (a Nelder-Mead polish) or the estimate is unusable."""
    try:
        h = np.asarray(res.hess_inv.todense(), dtype=float)
    except AttributeError:
        return None
    if whiten is not None:
        h = whiten @ h @ whiten.T
    return (tuple(names), h) if h.shape == (len(names), len(names)) and np.all(np.isfinite(h)) else None


def _whitening(warm: ModelFit | None, names: list[str], y: np.ndarray, free: list, scale: float) -> np.ndarray | None:
    """R with R R' the inverse Hessian of the objective (-log-likelihood / `scale`) in the free coordinates `y`,
    from the warm fit of the same free parameters: its Cramer-Rao covariance when it has one (the Hessian itself, by
    differences at its optimum, carried to the free coordinates), else its optimiser's estimate (`_metric`). None:
    no warm fit, other parameters free, or neither positive definite."""
    if warm is None or [n for n, _ in warm.model.free()] != names:
        return None
    if any(p.at_bound(warm.values[n]) for n, p in free):
        # a parameter on its bound is at the end of its free coordinate, where the objective is flat to
        # rounding: any estimate there is huge along it (4e11 for outliers.fraction at 0 on the sweep), and the
        # whitened refits crawled (393 gradients for 11 folds against 164 unwhitened)
        return None
    cov = warm.covariance
    if cov is not None and cov.shape == (len(names), len(names)) and np.all(np.isfinite(cov)):
        slope = _free_slopes(free, y)
        if np.all(slope > 0):
            try:
                return np.linalg.cholesky(0.5 * (cov + cov.T) / np.outer(slope, slope) * scale)
            except np.linalg.LinAlgError:
                pass
    metric = warm.metric
    if metric is None or list(metric[0]) != names:
        return None
    try:
        return np.linalg.cholesky(0.5 * (metric[1] + metric[1].T))
    except np.linalg.LinAlgError:
        return None


def fit_data(model: ComposedModel, d: ModelData) -> ModelData:
    """What `model` is fitted on: the grouped nodes of `d` (made once, kept with `d`; apart by grid offset where the
    model rounds to the depth unit) when the data are large enough and every effect of the model is smooth within
    a tile (`Effect.groupable`); else `d` itself."""

    if isinstance(getattr(d, "weights", None), tuple) or not all(getattr(e, "groupable", True) for e in model.effects):
        return d
    by_offset = any(getattr(e, "by_grid_offset", False) for e in model.effects)
    by_offset = by_offset and tile_size(d) > 0 and bool(rounding_matters(d).any())  # else the plain nodes serve
    key = "grouped_by_offset" if by_offset else "grouped"
    if key not in d.__dict__:
        t = tile_size(d)
        d.__dict__[key] = group(d, t, by_offset=by_offset) if t else d
    return d.__dict__[key]


def _paper_fit(d: ModelData, lam: float | None):
    """The paper's closed-form fit of the power law (lambda free, or fixed at `lam`), kept with `d`."""
    cache = d.__dict__.setdefault("paper_fits", {})
    if lam not in cache:
        cache[lam] = power_law_mle(d.z_m, d.m2_m2, d.n, lam=lam)
    return cache[lam]


def with_errors(fit: ModelFit, d: ModelData) -> ModelFit:
    """`fit` with its Cramer-Rao standard errors and covariance (computed if it was fitted without them), from the
    data it was fitted on (grouped nodes where `fit_model` would use them)."""
    names = [n for n, _ in fit.model.free()]
    if not names or all(n in fit.errors for n in names):
        return fit
    se, cov, notes = _standard_errors(fit.model, fit.values, fit_data(fit.model, d), names)
    return replace(fit, errors=se, covariance=cov, error_notes=notes)


def loglik_on_nodes_of(fit: ModelFit, model: ComposedModel, d: ModelData) -> ModelFit:
    """`fit` with its log-likelihood on what `model` is fitted on (`fit_data`: the grouped nodes of `d`, or `d` itself):
    what a fit of `model` that reports its nodes' log-likelihood (`exact_loglik=False`) is compared with."""
    nodes = fit_data(model, d)
    return fit if nodes is d else replace(fit, loglik=fit.model.loglik(fit.values, nodes))


def with_exact_loglik(fit: ModelFit, d: ModelData) -> ModelFit:
    """`fit` with the log-likelihood of every pixel of `d` where it was fitted on grouped nodes and reported theirs
    (`exact_loglik=False`: a diagnosis's candidates); the same value `fit_model` reports by default."""
    if fit_data(fit.model, d) is d:
        return fit
    return replace(fit, loglik=fit.model.loglik(fit.values, d))


def _standard_errors(model: ComposedModel, values: dict[str, float], d: ModelData,
                     names: list[str]) -> tuple[dict[str, float], np.ndarray | None, dict[str, str]]:
    """Cramer-Rao standard errors from the inverse of the observed information (minus the Hessian), the covariance,
    and for each error that could not be had, why (`rig.models.parts.error_notes`).

    The Hessian is taken by central differences twice: first its diagonal, with steps of 1e-4 of each value, then
    the whole with steps of a fifth of each parameter's error with the others held, 1 / sqrt(-H_ii) (kept inside the
    parameters' bounds):
    the curvature at the scale of the uncertainty itself, which is what the errors describe where the likelihood
    is not quadratic over the first steps (outliers' fraction and width: the first steps gave errors 2x too small).
    With k and lambda both free, k is taken at the data's middle range, k_ref = k z_ref^lambda, as the paper's fit
    does (`closed_form`): k and lambda are nearly collinear (corr -0.9999 on one tilted stop), so their Hessian is
    nearly singular and its inverse would magnify the differences' rounding; the covariance is carried back by
    the Jacobian of k = k_ref z_ref^-lambda."""
    if not names:
        return {}, None, {}
    x = np.array([values[n] for n in names])
    params = dict(model.parameters())
    reparam = "k" in names and "lambda" in names
    ik, il = (names.index("k"), names.index("lambda")) if reparam else (0, 0)
    log_ref = _log_middle_range(getattr(d, "full", d)) if reparam else 0.0

    def to_x(u: np.ndarray) -> np.ndarray:
        xx = np.array(u, dtype=float)
        if reparam:
            xx[ik] = u[ik] * math.exp(-u[il] * log_ref)
        return xx

    u0 = np.array(x, dtype=float)
    if reparam:
        u0[ik] = x[ik] * math.exp(x[il] * log_ref)
    room = np.array([np.inf if reparam and i == ik else min(v - params[n].min, params[n].max - v)
                     for i, (n, v) in enumerate(zip(names, x))])
    steps = np.array([1e-4 * max(abs(v), 1e-6) for v in u0])

    def f(u: np.ndarray) -> float:
        v = dict(values)
        v.update(zip(names, to_x(u)))
        return model.loglik(v, d)

    se, cov = np.full(len(names), np.nan), None
    jac = np.eye(len(names))
    if reparam:
        jac[ik, ik] = math.exp(-x[il] * log_ref)
        jac[ik, il] = -x[ik] * log_ref
    with np.errstate(all="ignore"):
        for first in (True, False):
            # the first pass needs only the diagonal (each parameter's error with the others held), for the steps
            h = _hessian(f, u0, steps, diagonal=first and len(names) > 1)
            if first and len(names) > 1:
                held = 1.0 / np.sqrt(np.where(-np.diag(h) > 0, -np.diag(h), np.nan))
                if not np.all(np.isfinite(held)):
                    h = _hessian(f, u0, steps)  # a flat or wrong-signed direction: the errors say so, from the whole
                else:
                    steps = np.minimum(0.2 * held, np.where(room > 0, 0.5 * room, steps))
                    continue
            try:
                c = jac @ np.linalg.inv(-h) @ jac.T
            except np.linalg.LinAlgError:
                break
            s = np.sqrt(np.where(np.diag(c) > 0, np.diag(c), np.nan))
            se, cov = s, c
            # a fifth of each parameter's error with the others held (not its marginal error: along a ridge of
            # correlated parameters that would step far off the ridge)
            held = 1.0 / np.sqrt(np.where(-np.diag(h) > 0, -np.diag(h), np.nan))
            if not (np.all(np.isfinite(s)) and np.all(np.isfinite(held))):
                break
            steps = np.minimum(0.2 * held, np.where(room > 0, 0.5 * room, steps))
    if any(params[n].at_bound(v) for n, v in zip(names, x)):
        # a maximum on a bound is no stationary point: its curvature (one-sided, from steps squeezed into the room
        # left, or none when the fit sits exactly on it) is no error, for that parameter or, jointly, the others
        # (rig.models.parts.error_notes says which and why); decided here, not by whether the differences happen to fail
        se, cov = np.full(len(names), np.nan), None
    # frames measured not independent hold fewer independent samples: widen by sqrt(n / n_eff) (rig.models.data.independence)
    grow = error_inflation(d)
    if grow != 1.0:
        se, cov = se * grow, (cov * grow**2 if cov is not None else None)
    return dict(zip(names, map(float, se))), cov, error_notes(names, values, params, h, se)


def _log_middle_range(d: ModelData) -> float:
    """ln of the degrees-of-freedom-weighted geometric mean range (the paper's fit's z_ref), kept with `d`."""
    if "log_middle_range" not in d.__dict__:
        d.__dict__["log_middle_range"] = float(np.sum(d.nu * np.log(d.z_m)) / np.sum(d.nu))
    return d.__dict__["log_middle_range"]
