"""Empirical terms: when no physical effect explains what remains, a free-form shape fitted to it.

They are not physics. They describe the missing effect's shape (which the diagnosis plots) and
give a calibrated model before the physics is known: `active+empirical(radius)` on the command
line, `active + empirical("radius")` in Python.

  empirical(range|radius|slant|brightness|incidence)
      sigma multiplied by exp(g(c)), g a smooth monotone-preserving curve (PCHIP) through knots
      evenly spaced over the covariate's span, in ln c for range, slant and brightness (where
      physics gives power laws, straight lines in ln c), g = 0 at the first knot (the base model's k sets the level
      there); one free parameter per further knot (ln of the sigma multiplier there)
  empirical(position)
      sigma multiplied by exp(a x + b y + c x^2 + d x y + e y^2), x, y the normalised image
      coordinates (u - cx) / fx, (v - cy) / fy
  empirical(tails)
      the excess kurtosis, a smooth curve over ln Z through knots: heavier (or lighter) tails
      than the model's, without changing sigma; it shows in the kurtosis term of the likelihood
  empirical(time)
      the variance over frames of the frame's mean, multiplied by exp(a + b ln Z + c ln^2 Z) against
      what independent pixels give: noise shared by neighbouring pixels. The per-frame series
      is not part of the likelihood, so a and b are measured (least squares over the stops),
      not fitted, like the drift effect's wander
  empirical(fill)
      the fill rate multiplied by exp(f(ln Z)), f a smooth curve through knots, fitted (the fill
      rate by stop is part of the likelihood): samples lost for a reason the model does not know
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
from scipy.special import expit

from ..parts.component import Component, Effect
from ..data.model_data import ModelData
from ..fitting.likelihood import pixel_weights
from ..parts.parameters import Param
from .pchip import hermite_basis
from .pchip import smooth as _smooth
from .pchip import smooth_jacobian
from ..parts.prediction import EffectStage, Prediction
from ..parts.tangents import plus, scale

#: the covariates a sigma shape can follow, with their units and how each is read from the data
COVARIATES: dict[str, tuple[str, Callable[[ModelData], np.ndarray]]] = {
    "range": ("m", lambda d: d.z_m),
    "radius": ("tan of the off-axis angle", lambda d: np.sqrt(d.rho2)),
    "slant": ("m along the ray", lambda d: d.z_m * np.sqrt(1.0 + d.rho2)),
    "brightness": ("IR DN", lambda d: d.ir),
    "incidence": ("deg", lambda d: np.degrees(np.arccos(np.clip(d.cos_inc, -1.0, 1.0)))),
}
SHAPES = (*COVARIATES, "position", "tails", "time", "fill")
#: covariates whose shape is drawn in ln c
LOG_COVARIATES = ("range", "slant", "brightness")
KNOTS = 7
#: knots of the tails and fill shapes over ln Z
RANGE_KNOTS = 5


def empirical(covariate: str) -> Effect:
    """A new empirical term over `covariate` (one of SHAPES)."""
    if covariate in COVARIATES:
        return EmpiricalSigma(covariate)
    makers = {"position": EmpiricalPosition, "tails": EmpiricalTails, "time": EmpiricalFrameMean, "fill": EmpiricalFill}
    if covariate not in makers:
        raise ValueError(f"empirical({covariate}): the covariate must be one of {', '.join(SHAPES)}")
    return makers[covariate]()


def _spaced_knots(c: np.ndarray, n: int) -> np.ndarray:
    """n knots evenly spaced from the smallest to the largest finite value of c."""
    ok = c[np.isfinite(c)]
    if ok.size == 0:
        return np.array([0.0, 1.0])
    lo, hi = float(ok.min()), float(ok.max())
    if hi <= lo:
        return np.array([lo, lo + 1e-9])
    return np.linspace(lo, hi, n)


class EmpiricalSigma(Effect):
    """An empirical sigma multiplier, smooth in one covariate (see the module docstring)."""

    stage = EffectStage.EMPIRICAL

    def __init__(self, covariate: str, knots: int = KNOTS):
        self.covariate = covariate
        self.name = f"empirical({covariate})"  # type: ignore[misc]
        self.unit, self.read = COVARIATES[covariate]
        self.knots: np.ndarray | None = None
        self.params = tuple(  # type: ignore[misc]
            Param(f"g{i}", 0.0, -3.0, 3.0, "ln", f"ln of the sigma multiplier at knot {i} of {covariate}")
            for i in range(1, knots))
        self.signature = f"sigma measured / sigma model changes smoothly with {covariate}"  # type: ignore[misc]
        self.explanation = f"an empirical shape over {covariate}, not a physical effect"  # type: ignore[misc]

    def applicable(self, d: ModelData) -> str | None:
        c = self.read(d)
        if np.isfinite(c).sum() < 10 or np.nanmax(c) - np.nanmin(c) <= 0:
            return f"{self.name}: the data span no range of {self.covariate}"
        return None

    def _axis(self, c: np.ndarray) -> np.ndarray:
        """The covariate as the shape is drawn over it: ln c for LOG_COVARIATES, c otherwise (NaN where undefined)."""
        c = np.asarray(c, dtype=float)
        if self.covariate in LOG_COVARIATES:
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(c > 0, np.log(c), np.nan)
        return c

    def start(self, d: ModelData, pred: Prediction) -> dict[str, float]:
        if self.knots is None:  # from the pixels themselves, also when the fit runs on grouped nodes
            axis = self._axis(self.read(getattr(d, "full", d)))
            self.knots = np.exp(_spaced_knots(axis, len(self.params) + 1)) if self.covariate in LOG_COVARIATES \
                else _spaced_knots(axis, len(self.params) + 1)
        return {q.name: 0.0 for q in self.params}

    def log_multiplier(self, c: np.ndarray, p: Any) -> np.ndarray:
        """ln(sigma multiplier) at covariate values c."""
        knots = self.knots if self.knots is not None else np.linspace(0, 1, len(self.params) + 1)
        g = np.array([0.0, *self.own(p)])[: len(knots)]
        x = self._axis(c)
        return np.where(np.isfinite(x), _smooth(self._axis(knots), g, np.nan_to_num(x)), 0.0)

    def _rows(self, d: ModelData, knots: np.ndarray) -> tuple[np.ndarray, np.ndarray, Any]:
        """(the covariate's axis with NaN as 0, where it is defined, the Hermite basis at the knots' axis) for the
        rows of `d`, kept with `d`: they depend on the rows and the knots alone (`kept_basis`)."""
        def make():
            x = self._axis(self.read(d))
            clean, axis_knots = np.nan_to_num(x), self._axis(knots)
            return clean, np.isfinite(x), (hermite_basis(axis_knots, clean) if len(knots) >= 3 else None)
        return kept_basis(d, (self.name, knots.tobytes()), make)

    def apply(self, pred, p, d):
        knots = self.knots if self.knots is not None else np.linspace(0, 1, len(self.params) + 1)
        clean, ok, basis = self._rows(d, knots)
        g = _smooth(self._axis(knots), np.array([0.0, *self.own(p)])[: len(knots)], clean, basis)
        pred.var_m2 = pred.var_m2 * np.exp(2.0 * np.where(ok, g, 0.0))

    def apply_tangent(self, pred, p, d, t):
        # var *= exp(2 g): d var = exp(2 g) d var + 2 var exp(2 g) dg, dg / d g_i from the cubic (`pchip`)
        knots = self.knots if self.knots is not None else np.linspace(0, 1, len(self.params) + 1)
        g_at = np.array([0.0, *self.own(p)])[: len(knots)]
        clean, ok, basis = self._rows(d, knots)
        g, jac = smooth_jacobian(self._axis(knots), g_at, clean, basis)
        mult = np.exp(2.0 * np.where(ok, g, 0.0))
        pred.var_m2 = pred.var_m2 * mult
        knot = {q.name: j + 1 for j, q in enumerate(self.params)}  # parameter g_j is the value at knot j (knot 0: 0)
        own = [(i, 2.0 * pred.var_m2 * np.where(ok, jac[knot[name]], 0.0)) for i, name in t.own_rows(self)]
        t.var = plus(scale(t.var, mult), t.seeded(own))


class EmpiricalPosition(Effect):
    """An empirical sigma multiplier over the image: a quadratic surface in the normalised coordinates."""

    name = "empirical(position)"
    covariate = "position"
    stage = EffectStage.EMPIRICAL
    params = tuple(Param(n, 0.0, -10.0, 10.0, "ln", f"coefficient of {t} in ln(sigma multiplier)")
                   for n, t in (("a_x", "x"), ("a_y", "y"), ("a_xx", "x^2"), ("a_xy", "x y"), ("a_yy", "y^2")))
    signature = "sigma measured / sigma model changes smoothly across the image"
    explanation = "an empirical shape over the image, not a physical effect"

    def applicable(self, d):
        return None if d.x_norm is not None else "empirical(position): the data carry no image coordinates"

    def log_multiplier(self, x: np.ndarray, y: np.ndarray, p: Any) -> np.ndarray:
        """ln(sigma multiplier) at (x, y), `p` its parameters (`own`, or a model's values by qualified name)."""
        p = self.own(p)
        return p.a_x * x + p.a_y * y + p.a_xx * x * x + p.a_xy * x * y + p.a_yy * y * y

    def apply(self, pred, p, d):
        pred.var_m2 = pred.var_m2 * np.exp(2.0 * self.log_multiplier(d.x_norm, d.y_norm, p))

    def apply_tangent(self, pred, p, d, t):
        mult = np.exp(2.0 * self.log_multiplier(d.x_norm, d.y_norm, p))
        pred.var_m2 = pred.var_m2 * mult
        x, y = d.x_norm, d.y_norm
        terms = {"a_x": x, "a_y": y, "a_xx": x * x, "a_xy": x * y, "a_yy": y * y}
        own = [(i, 2.0 * pred.var_m2 * terms[name]) for i, name in t.own_rows(self)]
        t.var = plus(scale(t.var, mult), t.seeded(own))


class _RangeShape(Effect):
    """A smooth curve over ln Z through RANGE_KNOTS knots evenly spaced over the data's ranges (PCHIP)."""

    stage = EffectStage.TAILS
    knots: np.ndarray | None = None

    def start(self, d, pred):
        if self.knots is None:  # from the pixels themselves, also when the fit runs on grouped nodes
            self.knots = _spaced_knots(np.log(getattr(d, "full", d).z0_m), len(self.params))
        return {q.name: q.value for q in self.params}

    def _at(self, z_m: np.ndarray, d: ModelData | None) -> tuple[np.ndarray, np.ndarray, Any]:
        """(ln Z, the knots, their Hermite basis or None): kept with `d` when given (z_m is then its rows' z0_m)."""
        def make():
            lz = np.log(np.asarray(z_m, dtype=float))
            knots = self.knots if self.knots is not None else _spaced_knots(lz, len(self.params))
            return lz, knots, (hermite_basis(knots, lz) if len(knots) >= 3 else None)
        if d is None or self.knots is None:
            return make()
        return kept_basis(d, (self.name, self.knots.tobytes()), make)

    def curve(self, z_m: np.ndarray, p: Any, d: ModelData | None = None) -> np.ndarray:
        """The curve at ranges `z_m`; given `d` (whose rows' true ranges `z_m` are), with the basis kept with it."""
        lz, knots, basis = self._at(z_m, d)
        return _smooth(knots, np.array(self.own(p))[: len(knots)], lz, basis)

    def curve_tangent(self, z_m: np.ndarray, p: Any, t: Any, d: ModelData | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """The curve and its derivative with respect to the parameters `t` differentiates, (m, rows) or None."""
        lz, knots, basis = self._at(z_m, d)
        g, jac = smooth_jacobian(knots, np.array(self.own(p))[: len(knots)], lz, basis)
        index = {q.name: j for j, q in enumerate(self.params)}
        return g, t.seeded([(i, jac[index[name]]) for i, name in t.own_rows(self) if index[name] < len(knots)])


class EmpiricalTails(_RangeShape):
    """An empirical excess kurtosis over range, added to the model's (sigma unchanged)."""

    name = "empirical(tails)"
    covariate = "tails"
    params = tuple(Param(f"e{i}", 0.0, -1.5, 50.0, "1", f"excess kurtosis at range knot {i}") for i in range(RANGE_KNOTS))
    signature = "the measured kurtosis differs from the model's"
    explanation = "empirical tails: the errors' distribution is not the model's shape"

    def excess(self, z_m: np.ndarray, p: Any, d: ModelData | None = None) -> np.ndarray:
        return np.maximum(self.curve(z_m, p, d), -1.5)

    def apply(self, pred, p, d):
        k4 = self.excess(d.z0_m, p, d) * pred.var_m2**2
        pred.k4_m4 = k4 if pred.k4_m4 is None else pred.k4_m4 + k4

    def apply_tangent(self, pred, p, d, t):
        curve, dcurve = self.curve_tangent(d.z0_m, p, t, d)
        excess = np.maximum(curve, -1.5)
        var = pred.var_m2
        k4 = excess * var**2
        pred.k4_m4 = k4 if pred.k4_m4 is None else pred.k4_m4 + k4
        t.k4 = plus(t.k4, scale(t.var, 2.0 * excess * var), scale(dcurve, np.where(curve > -1.5, var**2, 0.0)))


class _MeasuredRangeGain(Effect):
    """A gain exp(a + b ln Z + c ln^2 Z) measured (not fitted) by least squares over the stops (a straight
    line in ln Z with fewer than five stops): see the subclasses."""

    stage = EffectStage.TAILS
    coefficients: tuple[float, ...] = (0.0,)

    def gain(self, z_m: np.ndarray) -> np.ndarray:
        lz = np.log(np.asarray(z_m, dtype=float))
        return np.exp(sum(c * lz**i for i, c in enumerate(self.coefficients)))

    def _measure(self, z: np.ndarray, log_ratio: np.ndarray, weight: np.ndarray) -> None:
        degree = 2 if len(z) >= 5 else 1
        if len(z) > degree and np.ptp(np.log(z)) > 0:
            self.coefficients = tuple(float(c) for c in np.polyfit(np.log(z), log_ratio, degree, w=np.sqrt(weight))[::-1])
        else:
            self.coefficients = ((float(np.average(log_ratio, weights=weight)) if len(z) else 0.0),)


class EmpiricalFrameMean(_MeasuredRangeGain):
    """Empirical noise shared by neighbouring pixels: the frame mean's variance exp(a + b ln Z + c ln^2 Z) times
    what independent pixels give, measured (not fitted: the per-frame series is not in the likelihood) from each
    stop's series against a prediction, once (`measure`; `start` measures against the model it joins)."""

    name = "empirical(time)"
    covariate = "time"
    signature = "the frame's mean depth wanders more (or less) than independent pixels allow"
    explanation = "empirical correlation between pixels: neighbours' errors move together"
    measured = False

    def applicable(self, d):
        if d.stops is None or not np.isfinite(d.stops.series_var_inv2).any():
            return "empirical(time): the recording has no per-frame series"
        return None

    def start(self, d, pred):
        if not self.measured:
            self.measure(pred, d)
        return {}

    def measure(self, pred: Prediction, d: ModelData) -> None:
        """Set the gain from the per-frame series of every stop against the prediction `pred`."""
        t = d.stops
        common = np.broadcast_to(np.asarray(pred.common_inv2, dtype=float), d.z_m.shape)
        independent = (pred.var_m2 - common * d.z_m**4) / d.z_m**4 * pixel_weights(d)
        z, ratio, weight = [], [], []
        for s in np.unique(d.stop):
            s = int(s)
            m = d.stop == s
            n_valid, measured, frames = t.n_valid[s], t.series_var_inv2[s], t.frames[s]
            expected_independent = float(np.sum(independent[m])) / n_valid**2
            excess = measured - float(np.mean(common[m]))
            if not (np.isfinite(excess) and excess > 0 and expected_independent > 0 and frames > 3):
                continue
            z.append(float(np.median(d.z_m[m])))
            ratio.append(np.log(excess / expected_independent))
            weight.append((frames - 1) / 2.0)
        self._measure(np.array(z), np.array(ratio), np.array(weight))
        self.measured = True

    def apply(self, pred, p, d):
        pred.frame_mean_gain = self.gain(d.z_m)

    def apply_tangent(self, pred, p, d, t):
        self.apply(pred, p, d)  # measured, and outside the likelihood: nothing to differentiate


class EmpiricalFill(_RangeShape):
    """Empirical sample loss: the fill rate times a kept share expit(g(ln Z)), fitted (the fill rate by stop
    is part of the likelihood). The curve is over the logit of the kept share, so a loss that grows over
    orders of magnitude with range (1e-7 at the near stops, 10 % at the far ones) is one smooth curve."""

    name = "empirical(fill)"
    covariate = "fill"
    params = tuple(Param(f"g{i}", 10.0, -6.0, 16.0, "logit", f"logit of the share kept at range knot {i}")
                   for i in range(RANGE_KNOTS))
    signature = "the fill rate differs from the model's"
    explanation = "empirical sample loss: the camera drops samples for a reason the model does not know"

    def gain(self, z_m: np.ndarray, p: Any, d: ModelData | None = None) -> np.ndarray:
        return expit(self.curve(z_m, p, d))

    def apply(self, pred, p, d):
        fill = pred.fill if pred.fill is not None else np.ones(len(d))
        pred.fill = fill * self.gain(d.z0_m, p, d)

    def apply_tangent(self, pred, p, d, t):
        fill = pred.fill if pred.fill is not None else 1.0
        curve, dcurve = self.curve_tangent(d.z0_m, p, t, d)
        gain = expit(curve)
        pred.fill = fill * gain
        t.fill = plus(scale(t.fill, gain), scale(dcurve, fill * gain * (1.0 - gain)))


def kept_basis(d: ModelData, key: tuple, make: Any) -> Any:
    """`make()`, kept with `d` under `key`: what an empirical shape computes from its rows and knots alone (the
    axis and the Hermite basis), made once for the hundreds of evaluations of a fit."""
    kept = d.__dict__.setdefault("empirical_rows", {})
    if key not in kept:
        kept[key] = make()
    return kept[key]


def is_empirical(e: Component) -> bool:
    return isinstance(e, (EmpiricalSigma, EmpiricalPosition, _RangeShape, _MeasuredRangeGain))
