"""Range-error models that compose, lmfit-style: a base power law plus physical effects.

    from rig.models import active, slant_range, noise_floor, parse_model
    model = active + slant_range + noise_floor          # or parse_model("active+slant_range+noise_floor")
    result = model.fit(data)                             # data: ModelData.from_recording(path)
    print(result.report())

A model predicts, for every pixel of every stop, the variance of its range samples (m^2) and
their fourth cumulant (m^4, zero for a normal distribution). Effects join at fixed stages,
whatever order they are written in (see `Stage`), so adding one never requires changing another:

  base          shot-noise variance k^2 Z^(2 lambda)          (paper, eq. error_prop_*)
  (all models)  the deepest range the depth format holds (65535 units): farther samples are missing
  (all models)  the curvature of Z = f b / d to second order: var *= 1 + 8 var / Z^2
  ILLUMINATION  multiply it: the light falls faster than 1/Z^2 at some pixels
  IMAGE_NOISE   add image noise relative to the pattern's shot noise: var *= 1 + terms
  DISPARITY     add disparity noise independent of light
  DRIFT         add the variance of the stop's mean over time
  CENSOR        truncate the disparity error (the camera drops unconfident matches)
  QUANTIZE      add rounding: q^2 / 12
  OUTLIERS      mix in uniform mismatches

The likelihood (see `ModelData.loglik`): each pixel's sample variance s2 = M2 / (n - 1) is
Gamma-distributed with mean sigma^2 and var(s2) = sigma^4 (2/(n-1) + excess/n), excess = k4 /
sigma^4. With excess = 0 this is exactly the paper's Gaussian likelihood of the samples about
the pixel means; heavy tails or truncation change the scatter of s2 across pixels, which is
how outliers and censoring are told apart from effects that only change the variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, ClassVar

import numpy as np
from scipy.optimize import minimize
from scipy.special import gammaln, ndtr
from scipy.stats import chi2

from .samples import PixelSamples


class Stage(IntEnum):
    ILLUMINATION = 10
    IMAGE_NOISE = 20
    DISPARITY = 30
    DRIFT = 40
    CENSOR = 50
    QUANTIZE = 60
    OUTLIERS = 70


@dataclass(frozen=True)
class Param:
    """A model parameter with its unit, bounds and starting value."""

    name: str
    value: float
    min: float
    max: float
    unit: str
    doc: str
    vary: bool = True


# ---------------------------------------------------------------------------------------------
# data


@dataclass
class ModelData:
    """What models are fitted to: per-pixel sample variances and covariates, plus the camera's f*b and depth unit."""

    z_m: np.ndarray
    s2_m2: np.ndarray  # sample variance M2 / (n - 1), m^2
    n: np.ndarray
    rho2: np.ndarray
    cos_inc: np.ndarray
    ambient_ratio: np.ndarray
    drift_var_m2: np.ndarray
    projector_on: np.ndarray
    fill: np.ndarray
    stop: np.ndarray
    u_px: np.ndarray
    v_px: np.ndarray
    ir: np.ndarray
    m4_m4: np.ndarray
    fb_px_m: float  # focal length (px) times baseline (m)
    depth_unit_m: float
    n_dropped_zero: int = 0  # pixels left out because all their samples were equal (s2 = 0)
    _alpha0: np.ndarray = field(default=None, repr=False)  # type: ignore[assignment]
    _const0: float = field(default=0.0, repr=False)

    def __post_init__(self) -> None:
        self.nu = self.n - 1.0
        self._alpha0 = self.nu / 2.0
        self._log_s2 = np.log(self.s2_m2)
        a = self._alpha0
        self._const0 = float(np.sum(a * np.log(a) - gammaln(a) + (a - 1) * self._log_s2))

    @classmethod
    def from_samples(cls, s: PixelSamples, *, fb_px_m: float, depth_unit_m: float) -> "ModelData":
        keep = (s.n >= 2) & (s.m2_m2 > 0)
        s2 = s.m2_m2[keep] / (s.n[keep] - 1.0)
        return cls(
            z_m=s.z_m[keep], s2_m2=s2, n=s.n[keep], rho2=s.rho2[keep], cos_inc=s.cos_inc[keep],
            ambient_ratio=s.ambient_ratio[keep], drift_var_m2=s.drift_var_m2[keep],
            projector_on=s.projector_on[keep].astype(bool), fill=s.fill[keep], stop=s.stop[keep],
            u_px=s.u_px[keep], v_px=s.v_px[keep], ir=s.ir[keep], m4_m4=s.m4_m4[keep],
            fb_px_m=fb_px_m, depth_unit_m=depth_unit_m, n_dropped_zero=int(np.sum(~keep)),
        )

    @classmethod
    def from_recording(cls, path: Any) -> "ModelData":
        from .recording import Recording
        from .samples import load_samples

        with Recording(path) as rec:
            samples = load_samples(rec)
            cal = rec.calibration
        return cls.from_samples(samples, fb_px_m=cal.fx * cal.baseline_m, depth_unit_m=cal.depth_scale_m)

    def select(self, mask: np.ndarray) -> "ModelData":
        arrays = {k: getattr(self, k)[mask] for k in (
            "z_m", "s2_m2", "n", "rho2", "cos_inc", "ambient_ratio", "drift_var_m2", "projector_on", "fill",
            "stop", "u_px", "v_px", "ir", "m4_m4")}
        return ModelData(**arrays, fb_px_m=self.fb_px_m, depth_unit_m=self.depth_unit_m)

    def __len__(self) -> int:
        return len(self.z_m)

    @property
    def n_samples(self) -> int:
        return int(self.n.sum())

    def disparity_to_range(self, var_px2: np.ndarray | float) -> np.ndarray:
        """Variance in px^2 of disparity -> m^2 of range: (Z^2 / (f b))^2 var_d (paper, eq. error_prop_unassisted)."""
        return (self.z_m**2 / self.fb_px_m) ** 2 * var_px2

    def loglik_terms(self, var: np.ndarray, k4: np.ndarray | None) -> np.ndarray:
        """Per-pixel log-likelihood of the sample variances under the Gamma law of the module docstring."""
        if k4 is None:
            a = self._alpha0
            return -a * np.log(var) - a * self.s2_m2 / var
        excess = k4 / var**2
        a = 1.0 / np.maximum(2.0 / self.nu + excess / self.n, 1e-12)
        a = np.maximum(a, 0.5)
        return a * np.log(a) - gammaln(a) + (a - 1) * self._log_s2 - a * np.log(var) - a * self.s2_m2 / var

    def loglik(self, var: np.ndarray, k4: np.ndarray | None) -> float:
        t = self.loglik_terms(var, k4)
        if k4 is None:
            return float(np.sum(t)) + self._const0
        return float(np.sum(t))


# ---------------------------------------------------------------------------------------------
# prediction state


@dataclass
class Prediction:
    """Per-pixel prediction, built stage by stage."""

    shot_m2: np.ndarray  # shot-noise variance of the base model
    illum: np.ndarray  # multiplier of the shot variance from illumination effects (1 / relative light)
    image_terms: np.ndarray  # image noise relative to the pattern's shot noise
    var_m2: np.ndarray | None = None
    k4_m4: np.ndarray | None = None  # fourth cumulant; None = normal
    fill: np.ndarray | None = None  # predicted fraction of frames with a valid sample

    def add(self, var_m2: np.ndarray | float, k4_m4: np.ndarray | float | None = None) -> None:
        """Add an independent component of variance (and fourth cumulant)."""
        self.var_m2 = self.var_m2 + var_m2
        if k4_m4 is not None:
            self.k4_m4 = (self.k4_m4 if self.k4_m4 is not None else 0.0) + k4_m4


# ---------------------------------------------------------------------------------------------
# components


class Component:
    """Base models and effects: a name, parameters, and how they change the prediction."""

    name: ClassVar[str] = "component"
    params: ClassVar[tuple[Param, ...]] = ()

    def __add__(self, other: "Component") -> "Model":
        return Model.of(self) + other

    def __repr__(self) -> str:
        return self.name


class Base(Component):
    """sigma_Z = k * Z^lambda (paper, eq. error_prop_*); lambda free or fixed."""

    def __init__(self, name: str, lam: float | None, doc: str):
        self.name = name  # type: ignore[misc]
        self.lam = lam
        self.doc = doc
        self.params = (  # type: ignore[misc]
            Param("k", 0.002, 1e-9, 10.0, "m^(1-lambda)", "scale of the range error"),
            Param("lambda", 3.0 if lam is None else lam, -2.0, 8.0, "", "exponent of range", vary=lam is None),
        )

    def shot(self, p: dict[str, float], d: ModelData) -> np.ndarray:
        return p["k"] ** 2 * d.z_m ** (2 * p["lambda"])


power_law = Base("power_law", None, "the paper's model: k and lambda free")
passive = Base("passive", 2.0, "passive stereo: lambda fixed at 2 (constant light)")
active = Base("active", 3.0, "active stereo: lambda fixed at 3 (projected light falls as 1/Z^2)")
BASES = {b.name: b for b in (power_law, passive, active)}


class Effect(Component):
    """A physical effect the base model leaves out.

    stage: where it joins (see `Stage`); needs: the covariates it uses; signature: the residual
    pattern it explains, in plain words; explanation: what it means physically.
    """

    stage: ClassVar[Stage]
    needs: ClassVar[tuple[str, ...]] = ()
    signature: ClassVar[str] = ""
    explanation: ClassVar[str] = ""

    def applicable(self, d: ModelData) -> str | None:
        """None if the effect can be fitted to these data, else why not (one line)."""
        return None

    def apply(self, pred: Prediction, p: dict[str, float], d: ModelData) -> None:
        raise NotImplementedError

    def start(self, d: ModelData, pred: Prediction) -> dict[str, float]:
        """Starting values (may depend on the data and the base prediction)."""
        return {q.name: q.value for q in self.params}


def _need_projector(d: ModelData, what: str) -> str | None:
    return None if d.projector_on.any() else f"{what} needs the projector on (it changes the projected light)"


class NoiseFloor(Effect):
    """Disparity noise independent of brightness (matcher / subpixel limit), added in quadrature.

    var_Z += (Z^2 / (f b))^2 sigma_px^2 (eq. error_prop_unassisted): it grows as Z^2 in range.
    """

    name = "noise_floor"
    stage = Stage.DISPARITY
    params = (Param("sigma_px", 0.01, 0.0, 5.0, "px", "disparity noise floor (RMS)"),)
    signature = "the measured error exceeds k Z^lambda most at short range, where the projected light is brightest"
    explanation = "a noise floor in disparity that does not depend on brightness (the matcher's subpixel limit)"

    def apply(self, pred, p, d):
        pred.add(d.disparity_to_range(p["noise_floor.sigma_px"] ** 2))


class ReadNoise(Effect):
    """Sensor read noise, independent of light, added to the photon noise of the image.

    var_shot *= 1 + r^2 / I with I the pattern's photo-electrons; with the projector on
    I ~ 1 / (Z^2 h) (h: other illumination losses), so the term is ratio_at_1m * Z^2 * h.
    """

    name = "read_noise"
    stage = Stage.IMAGE_NOISE
    params = (Param("ratio_at_1m", 0.05, 0.0, 1e3, "1", "read-noise variance / pattern shot-noise variance at 1 m on axis"),)
    signature = "the error grows faster than k Z^lambda at long range, where the projected light is faint"
    explanation = "sensor read noise: noise that does not fall with the light, so its share grows as the pattern fades"

    def applicable(self, d):
        return _need_projector(d, "read_noise") or None

    def apply(self, pred, p, d):
        term = p["read_noise.ratio_at_1m"] * d.z_m**2 * pred.illum
        pred.image_terms = pred.image_terms + np.where(d.projector_on, term, 0.0)


class Ambient(Effect):
    """Ambient light adds photon noise but no pattern contrast: var_shot *= 1 + A / P.

    A / P (ambient over pattern brightness) is measured per pixel from the frames captured with
    the projector off; no free parameter.
    """

    name = "ambient"
    stage = Stage.IMAGE_NOISE
    needs = ("ambient_ratio",)
    signature = "the error is larger where the ambient light (measured with the projector off) is strong against the pattern"
    explanation = "ambient light: it adds photon noise to the image but no pattern contrast to match on"

    def applicable(self, d):
        if not np.isfinite(d.ambient_ratio).any():
            return "ambient needs frames with the projector off at each stop (capture them with ambient_frames > 0)"
        return _need_projector(d, "ambient")

    def apply(self, pred, p, d):
        r = np.where(np.isfinite(d.ambient_ratio) & d.projector_on, d.ambient_ratio, 0.0)
        pred.image_terms = pred.image_terms + r


class SlantRange(Effect):
    """The projected light falls with the slant range r along each ray, not with Z.

    I ~ 1/r^2 = 1 / (Z^2 (1 + rho^2)), rho^2 = ((u-cx)/fx)^2 + ((v-cy)/fy)^2 (paper, "Further
    effects"), so the shot variance is multiplied by 1 + rho^2. No free parameter.
    """

    name = "slant_range"
    stage = Stage.ILLUMINATION
    signature = "the error grows with distance from the image centre"
    explanation = "the illumination falls with the slant range along each pixel's ray, not with Z"

    def applicable(self, d):
        return _need_projector(d, "slant_range")

    def apply(self, pred, p, d):
        pred.illum = pred.illum * np.where(d.projector_on, 1.0 + d.rho2, 1.0)


class Incidence(Effect):
    """A matte wall returns the projected light as cos(incidence): the shot variance is divided by it.

    The angle is between each pixel's ray and the normal of a plane fitted to the stop's mean depth. No free parameter.
    """

    name = "incidence"
    stage = Stage.ILLUMINATION
    signature = "the error grows with the angle at which the rays meet the wall"
    explanation = "the wall returns the projected light as the cosine of the incidence angle (a matte surface)"

    def applicable(self, d):
        return _need_projector(d, "incidence")

    def apply(self, pred, p, d):
        pred.illum = pred.illum * np.where(d.projector_on, 1.0 / np.clip(d.cos_inc, 0.05, 1.0), 1.0)


class Drift(Effect):
    """The mean depth wanders during a stop (warm-up): var += D, measured from the per-frame series. No free parameter."""

    name = "drift"
    stage = Stage.DRIFT
    needs = ("drift_var_m2",)
    signature = "the mean depth wanders during a stop: per-pixel variance exceeds the model by what the per-frame series moves"
    explanation = "drift: the camera's depth scale changes during a stop (warm-up), adding the wander to every pixel's variance"

    def applicable(self, d):
        return None if (d.drift_var_m2 > 0).any() else "drift: the per-frame series shows no wander beyond noise"

    def apply(self, pred, p, d):
        pred.add(d.drift_var_m2)


def _format_limit(pred: "Prediction", d: "ModelData") -> None:
    """Samples beyond 65535 depth units read as no data: the disparity error is cut below
    a = (f b / Z_max - f b / Z) / sigma_d. For N(0,1) kept above a: lam = phi(a) / (1 - Phi(a)),
    var = 1 + a lam - lam^2, kept fraction 1 - Phi(a)."""
    z_max = MAX_DEPTH_UNITS * d.depth_unit_m
    sigma_d = np.sqrt(pred.var_m2) * d.fb_px_m / d.z_m**2
    a = (d.fb_px_m / z_max - d.fb_px_m / d.z_m) / sigma_d
    near = a > -8.0  # elsewhere the cut is more than 8 sigma away: nothing is lost
    if not near.any():
        return
    an = np.minimum(a[near], 8.0)
    kept = ndtr(-an)
    lam = np.exp(-0.5 * an * an) / SQRT_2PI / np.maximum(kept, 1e-300)
    factor = np.ones_like(a)
    factor[near] = np.maximum(1 + an * lam - lam**2, 1e-6)
    pred.var_m2 = pred.var_m2 * factor
    fill = np.ones_like(a)
    fill[near] = kept
    pred.fill = (pred.fill if pred.fill is not None else 1.0) * fill


def truncated_normal_moments(c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For N(0,1) truncated to [-c, c]: (fraction kept, E[x^2], E[x^4])."""
    kept = np.maximum(2 * ndtr(c) - 1, 1e-300)
    phi = np.exp(-0.5 * c * c) / SQRT_2PI
    m2 = 1 - 2 * c * phi / kept
    m4 = 3 - 2 * phi * (c**3 + 3 * c) / kept
    return kept, m2, m4


class Censoring(Effect):
    """The camera invalidates matches with a large matching error: the disparity error is truncated at +-threshold.

    With c = threshold / sigma_d: var *= E[x^2 | |x| < c], fill = 2 Phi(c) - 1, and the
    distribution becomes lighter-tailed (a truncated normal).
    """

    name = "censoring"
    stage = Stage.CENSOR
    params = (Param("threshold_px", 0.3, 0.005, 20.0, "px", "largest disparity error the camera keeps"),)
    signature = "the error grows slower than k Z^lambda at long range while the fill rate falls"
    explanation = "censoring: the camera discards the matches it is least sure of, so at long range the worst samples are missing"

    def start(self, d, pred):
        sigma_d = np.sqrt(pred.var_m2) * d.fb_px_m / d.z_m**2
        return {"threshold_px": float(2.0 * np.quantile(sigma_d, 0.95))}

    def apply(self, pred, p, d):
        sigma_d = np.sqrt(pred.var_m2) * d.fb_px_m / d.z_m**2
        c = p["censoring.threshold_px"] / sigma_d
        kept, m2, m4 = truncated_normal_moments(c)
        var = pred.var_m2
        k4_old = pred.k4_m4 if pred.k4_m4 is not None else 0.0
        pred.var_m2 = var * m2
        pred.k4_m4 = var**2 * (m4 - 3 * m2**2) + k4_old * m2**2
        pred.fill = kept


class Quantization(Effect):
    """Rounding to the depth unit q (and to the matcher's disparity step, if given) adds q^2 / 12.

    A uniform rounding error has fourth cumulant -q^4 / 120. The depth unit comes from the
    recording, so there is no free parameter.
    """

    name = "quantization"
    stage = Stage.QUANTIZE
    params = (Param("step_px", 0.0, 0.0, 1.0, "px", "disparity step of the matcher (0: continuous)", vary=False),)
    signature = "the error levels off at short range near the size of the depth unit"
    explanation = "quantization: depth is rounded to the depth unit (and disparity to the matcher's step), adding q^2/12"

    def apply(self, pred, p, d):
        q2 = d.depth_unit_m**2
        step2 = d.disparity_to_range(p.get("quantization.step_px", 0.0) ** 2)
        pred.add(q2 / 12 + step2 / 12, -(q2**2) / 120 - step2**2 / 120)


#: the largest value a uint16 depth image holds; 0 means no data
MAX_DEPTH_UNITS = 65535
SQRT_2PI = math.sqrt(2 * math.pi)


class Outliers(Effect):
    """Mismatches: a fraction of samples is uniform within +-width_px of the true disparity (Gaussian + uniform mixture).

    An outlier's range is Z_o = f b / (d0 + u), u uniform on [-w, w], d0 = f b / Z, so exactly
    E[Z_o] = f b ln((d0 + w) / (d0 - w)) / (2 w) and E[Z_o^2] = (f b)^2 / (d0^2 - w^2) (eq. dist_to_disp).
    Mixture about its mean: var = (1 - f) (var0 + (Z - m)^2) + f (var_o + (E[Z_o] - m)^2),
    m = (1 - f) Z + f E[Z_o]. The fourth moment uses the linearised outlier spread a = w Z^2 / (f b):
    E[x^4] = (1 - f) (3 var0^2 + k4) + f a^4 / 5, scaled to the exact variance. Outliers beyond
    the deepest range the depth format can hold (65535 depth units) are missing, not recorded.
    """

    name = "outliers"
    stage = Stage.OUTLIERS
    params = (
        Param("fraction", 0.005, 0.0, 0.5, "1", "fraction of samples that are mismatches"),
        Param("width_px", 1.0, 0.01, 50.0, "px", "half-width of the mismatch distribution"),
    )
    signature = "the errors are heavy-tailed: pixel variances scatter more than a normal distribution allows (kurtosis above 3)"
    explanation = "outliers: occasional mismatches far from the true disparity (the paper's kurtosis of 4-8)"

    def apply(self, pred, p, d):
        f, w = p["outliers.fraction"], p["outliers.width_px"]
        fb, z = d.fb_px_m, d.z_m
        d0 = fb / z
        # mismatches beyond the deepest range the depth format holds (65535 units) read as no data
        u_lo = np.maximum(-w, fb / (MAX_DEPTH_UNITS * d.depth_unit_m) - d0)
        u_lo = np.minimum(u_lo, w - 1e-9)
        span = w - u_lo
        mean_o = fb * np.log((d0 + w) / (d0 + u_lo)) / span
        var_o = fb**2 * (1 / (d0 + u_lo) - 1 / (d0 + w)) / span - mean_o**2
        kept = span / (2 * w)
        f_all = f
        f = f_all * kept / (1 - f_all + f_all * kept)
        pred.fill = (pred.fill if pred.fill is not None else 1.0) * (1 - f_all + f_all * kept)
        w_eff = span / 2
        m = (1 - f) * z + f * mean_o
        var0 = pred.var_m2
        var = (1 - f) * (var0 + (z - m) ** 2) + f * (var_o + (mean_o - m) ** 2)
        a2 = d.disparity_to_range(w_eff**2)
        k40 = pred.k4_m4 if pred.k4_m4 is not None else 0.0
        m4_lin = (1 - f) * (3 * var0**2 + k40) + f * a2**2 / 5
        var_lin = (1 - f) * var0 + f * a2 / 3
        pred.var_m2 = var
        pred.k4_m4 = m4_lin * (var / var_lin) ** 2 - 3 * var**2


EFFECTS: dict[str, Effect] = {e.name: e for e in (
    NoiseFloor(), ReadNoise(), Ambient(), SlantRange(), Incidence(), Outliers(), Quantization(), Drift(), Censoring())}
noise_floor, read_noise, ambient, slant_range, incidence, outliers, quantization, drift, censoring = EFFECTS.values()


# ---------------------------------------------------------------------------------------------
# models


@dataclass(frozen=True)
class Model:
    """A base model plus effects. Compose with `+`; fit with `.fit(data)`."""

    base: Base
    effects: tuple[Effect, ...] = ()

    @classmethod
    def of(cls, c: Component) -> "Model":
        if isinstance(c, Model):
            return c
        if isinstance(c, Base):
            return cls(c)
        raise TypeError(f"a model starts from a base model ({', '.join(BASES)}), not {c!r}")

    def __add__(self, other: Any) -> "Model":
        if isinstance(other, Base):
            raise ValueError(f"{self.name} already has a base model; add effects, not {other.name}")
        if not isinstance(other, Effect):
            raise TypeError(f"cannot add {other!r} to a model; add an effect such as noise_floor")
        if other.name in (e.name for e in self.effects):
            return self
        return Model(self.base, tuple(sorted((*self.effects, other), key=lambda e: e.stage)))

    @property
    def name(self) -> str:
        return "+".join([self.base.name, *(e.name for e in self.effects)])

    def parameters(self) -> list[tuple[str, Param]]:
        """(qualified name, Param) for every parameter: base ones plain, effect ones as effect.param."""
        out = [(p.name, p) for p in self.base.params]
        for e in self.effects:
            out += [(f"{e.name}.{p.name}", p) for p in e.params]
        return out

    def free(self) -> list[tuple[str, Param]]:
        return [(n, p) for n, p in self.parameters() if p.vary]

    def predict(self, values: dict[str, float], d: ModelData) -> Prediction:
        pred = Prediction(self.base.shot(values, d), np.ones(len(d)), np.zeros(len(d)))
        for e in self.effects:
            if e.stage < Stage.DISPARITY:
                e.apply(pred, values, d)
        pred.var_m2 = pred.shot_m2 * pred.illum * (1.0 + pred.image_terms)
        for e in self.effects:
            if Stage.DISPARITY <= e.stage <= Stage.CENSOR:
                e.apply(pred, values, d)
        _format_limit(pred, d)
        # Z = f b / d is curved: to second order var Z = var_lin (1 + 8 var_lin / Z^2) (eq. dist_to_disp
        # expanded one order beyond eq. error_prop_*); 0.7 % at 3 m for a 3 % error
        pred.var_m2 = pred.var_m2 * (1.0 + 8.0 * pred.var_m2 / d.z_m**2)
        for e in self.effects:
            if e.stage > Stage.CENSOR:
                e.apply(pred, values, d)
        return pred

    def loglik(self, values: dict[str, float], d: ModelData) -> float:
        pred = self.predict(values, d)
        return d.loglik(pred.var_m2, pred.k4_m4)

    def check(self, d: ModelData) -> None:
        for e in self.effects:
            why = e.applicable(d)
            if why:
                raise ValueError(why)

    def fit(self, d: ModelData, start: dict[str, float] | None = None) -> "ModelFit":
        return fit_model(self, d, start)


def parse_model(text: str) -> Model:
    """'active+slant_range+noise_floor' -> Model."""
    parts = [p.strip() for p in text.replace(" ", "").split("+") if p.strip()]
    if not parts or parts[0] not in BASES:
        raise ValueError(f"model {text!r} must start with a base model ({', '.join(BASES)}), e.g. active+slant_range")
    m = Model(BASES[parts[0]])
    for name in parts[1:]:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r} in model {text!r}; effects: {', '.join(EFFECTS)}")
        m = m + EFFECTS[name]
    return m


# ---------------------------------------------------------------------------------------------
# fitting


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
        return lo + (hi - lo) / (1 + math.exp(-y))
    return y


@dataclass
class ModelFit:
    """A fitted model: values, Cramer-Rao standard errors, likelihood and information criteria."""

    model: Model
    values: dict[str, float]
    errors: dict[str, float]
    loglik: float
    n_obs: int  # pixels (each contributes one sample variance)
    n_samples: int
    converged: bool
    message: str = ""

    @property
    def n_free(self) -> int:
        return len(self.model.free())

    @property
    def bic(self) -> float:
        return -2 * self.loglik + self.n_free * math.log(self.n_obs)

    @property
    def aic(self) -> float:
        return -2 * self.loglik + 2 * self.n_free

    def predict(self, d: ModelData) -> Prediction:
        return self.model.predict(self.values, d)

    def report(self) -> str:
        lines = [f"[[Model: {self.model.name}]]",
                 f"    {self.n_samples:,} samples in {self.n_obs:,} pixel-stops; log-likelihood {self.loglik:.6g}; "
                 f"BIC {self.bic:.6g}" + ("" if self.converged else f"  (NOT CONVERGED: {self.message})")]
        for name, p in self.model.parameters():
            v = self.values[name]
            if p.vary:
                se = self.errors.get(name, float("nan"))
                at = "  (at bound)" if (abs(v - p.min) < 1e-6 * max(1, abs(p.min)) or abs(v - p.max) < 1e-6 * max(1, abs(p.max))) else ""
                lines.append(f"    {name:<26} = {v:.6g} +/- {se:.2g} {p.unit}{at}")
            else:
                lines.append(f"    {name:<26} = {v:.6g} {p.unit} (fixed)")
        for e in self.model.effects:
            if not e.params or not any(p.vary for p in e.params):
                lines.append(f"    {e.name:<26}   (no free parameter: {e.explanation})")
        return "\n".join(lines)


def _hessian(f, x: np.ndarray, steps: np.ndarray) -> np.ndarray:
    n = len(x)
    h = np.zeros((n, n))
    f0 = f(x)
    for i in range(n):
        ei = np.zeros(n)
        ei[i] = steps[i]
        h[i, i] = (f(x + ei) - 2 * f0 + f(x - ei)) / steps[i] ** 2
        for j in range(i + 1, n):
            ej = np.zeros(n)
            ej[j] = steps[j]
            h[i, j] = h[j, i] = (f(x + ei + ej) - f(x + ei - ej) - f(x - ei + ej) + f(x - ei - ej)) / (4 * steps[i] * steps[j])
    return h


def fit_model(model: Model, d: ModelData, start: dict[str, float] | None = None) -> ModelFit:
    """Maximum likelihood over all pixels; standard errors from the inverse Hessian (Cramer-Rao)."""
    from .fit import fit_power_law
    from .samples import PixelSamples

    model.check(d)
    values = {n: p.value for n, p in model.parameters()}
    # the base alone has a closed-form fit: start there
    nan = np.full(len(d), np.nan)
    ps = PixelSamples(z_m=d.z_m, m2_m2=d.s2_m2 * d.nu, m4_m4=nan, n=d.n, stop=d.stop, u_px=nan, v_px=nan, ir=nan,
                      fill=d.fill, rho2=d.rho2, cos_inc=d.cos_inc, ambient_ratio=nan, drift_var_m2=nan,
                      projector_on=d.projector_on)
    base_fit = fit_power_law(ps, lam=model.base.lam)
    values["k"], values["lambda"] = base_fit.k, base_fit.lam
    partial = Model(model.base)
    for e in model.effects:
        pred = partial.predict(values, d)
        for k, v in e.start(d, pred).items():
            values[f"{e.name}.{k}" if "." not in k else k] = v
        partial = partial + e
    if start:
        values.update({k: v for k, v in start.items() if k in values})
    free = model.free()
    names = [n for n, _ in free]
    # k enters as log k: its scale varies over decades
    def unpack(y: np.ndarray) -> dict[str, float]:
        v = dict(values)
        for (n, p), yi in zip(free, y):
            v[n] = math.exp(yi) if n == "k" else _from_free(yi, p)
        return v

    def pack(v: dict[str, float]) -> np.ndarray:
        return np.array([math.log(v[n]) if n == "k" else _to_free(v[n], p) for n, p in free])

    scale = abs(base_fit.loglik) + 1.0

    def objective(y: np.ndarray) -> float:
        try:
            ll = model.loglik(unpack(y), d)
        except FloatingPointError:
            return 1e30
        return -ll / scale if np.isfinite(ll) else 1e30

    starts = [pack(values)]
    if model.effects and model.base.lam is None:
        # effects trade off against lambda: also start from the physical exponent (paper: 3 with
        # the projector on, 2 off) with k refitted for it
        lam_phys = 3.0 if d.projector_on.mean() > 0.5 else 2.0
        alt = dict(values, **{"lambda": lam_phys, "k": fit_power_law(ps, lam=lam_phys).k})
        starts.append(pack(alt))
    res = None
    with np.errstate(all="ignore"):
        for y0 in starts:
            r = minimize(objective, y0, method="L-BFGS-B", options={"maxiter": 500, "ftol": 1e-15, "gtol": 1e-10})
            # polish with Nelder-Mead when L-BFGS-B stops early on a flat ridge
            if not r.success and len(y0) > 1:
                r2 = minimize(objective, r.x, method="Nelder-Mead", options={"maxiter": 2000, "xatol": 1e-8, "fatol": 1e-14})
                if r2.fun <= r.fun:
                    r = r2
            if res is None or r.fun < res.fun:
                res = r
    y0 = starts[0]
    best = unpack(res.x)
    ll = model.loglik(best, d)
    errors = _standard_errors(model, best, d, names)
    return ModelFit(model, best, errors, ll, len(d), d.n_samples, bool(res.success) or res.fun < objective(y0), str(res.message))


def _standard_errors(model: Model, values: dict[str, float], d: ModelData, names: list[str]) -> dict[str, float]:
    if not names:
        return {}
    x = np.array([values[n] for n in names])
    steps = np.array([1e-4 * max(abs(v), 1e-6) for v in x])

    def f(xx: np.ndarray) -> float:
        v = dict(values)
        v.update(zip(names, xx))
        return model.loglik(v, d)

    with np.errstate(all="ignore"):
        h = _hessian(f, x, steps)
        try:
            cov = np.linalg.inv(-h)
            se = np.sqrt(np.where(np.diag(cov) > 0, np.diag(cov), np.nan))
        except np.linalg.LinAlgError:
            se = np.full(len(names), np.nan)
    return dict(zip(names, map(float, se)))


def likelihood_ratio(base: ModelFit, extended: ModelFit) -> tuple[float, int, float]:
    """(2 * delta loglik, degrees of freedom, p-value). Effects without free parameters count as one."""
    stat = max(0.0, 2 * (extended.loglik - base.loglik))
    df = max(1, extended.n_free - base.n_free)
    return stat, df, float(chi2.sf(stat, df))
