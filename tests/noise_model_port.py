"""A second evaluator of `rig.noise-model/1`, written from docs/noise-model.md alone, as a port would be.

It reads nothing of rig: plain Python (`math`), one sample at a time, each step as the page words it ("The formula
of every term", "Conventions", "The standard error"). Its agreement with the vectors `rig export --test-vectors`
writes, with the sigma maps and with `rig sigma-bag` is the check that the page is enough to port the model.
`rounding_bound` says how far two double-precision implementations of the page may be apart.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


class PortedModel:
    """`PortedModel(doc).sigma(z, u, v, **inputs)` -> (sigma, se) for one sample, in m."""

    def __init__(self, doc: dict[str, Any]) -> None:
        self.doc = doc
        self.values = {p["name"]: p["value"] for p in doc["parameters"]}
        self.errors = {p["name"]: p["error"] for p in doc["parameters"]}

    def variance(self, z: float, u: float, v: float, p: dict[str, float], inputs: dict[str, float]) -> float:
        cam = self.doc["camera"]
        k = cam["intrinsics"]
        x, y = (u - k["cx"]) / k["fx"], (v - k["cy"]) / k["fy"]  # "With x = (u - cx) / fx, y = (v - cy) / fy"
        rho2 = x * x + y * y
        fb = cam["fb_px_m"]
        on = self.doc["settings"]["projector_on"]
        names = {t["effect"]: t for t in self.doc["sigma_terms"]}
        shot = p["k"] ** 2 * z ** (2 * p["lambda"])  # 1. base: k^2 Z^(2 lambda)
        illum, image = 1.0, 0.0
        if "slant_range" in names and on:  # 2. illumination
            illum *= 1 + rho2
        if "incidence" in names and on:
            illum /= min(max(inputs["cos_incidence"], 0.05), 1.0)
        light = inputs.get("pattern_dn", math.nan)
        if "measured_light" in names and on and math.isfinite(light) and light > 0:  # "where ... finite and positive"
            illum *= (p["measured_light.pattern_ref_dn_m2"] / (z * z * light)) ** p["measured_light.exponent"]
        if "read_noise" in names and on:  # 3. image noise
            image += p["read_noise.ratio_at_1m"] * z * z * illum
        if "ambient" in names and on and math.isfinite(inputs["ambient_ratio"]):
            image += inputs["ambient_ratio"]
        var = shot * illum * (1 + image)  # 4.
        if "noise_floor" in names:  # 5. disparity
            var += (z * z / fb) ** 2 * p["noise_floor.sigma_px"] ** 2
        if "drift" in names:  # 6. drift
            var += inputs["drift_var_m2"]
        for name, t in names.items():  # 7. empirical shapes
            if name == "empirical(position)":
                a = {q: p[f"{name}.{q}"] for q in ("a_x", "a_y", "a_xx", "a_xy", "a_yy")}
                var *= math.exp(2 * (a["a_x"] * x + a["a_y"] * y + a["a_xx"] * x * x + a["a_xy"] * x * y
                                     + a["a_yy"] * y * y))
            elif name.startswith("empirical("):
                var *= math.exp(2 * self._shape(t, p, self._covariate(t["covariate"], z, rho2, inputs)))
        if "censoring" in names:  # 8. censoring: a normal truncated to +-c standard deviations
            c = p["censoring.threshold_px"] / (math.sqrt(var) * fb / (z * z))
            phi = math.exp(-c * c / 2) / math.sqrt(2 * math.pi)
            var *= 1 - 2 * c * phi / math.erf(c / math.sqrt(2))
        return var

    @staticmethod
    def _covariate(name: str, z: float, rho2: float, inputs: dict[str, float]) -> float:
        if name == "range":
            return z
        if name == "radius":
            return math.sqrt(rho2)
        if name == "slant":
            return z * math.sqrt(1 + rho2)
        if name == "brightness":
            return inputs["ir_dn"]
        return math.degrees(math.acos(inputs["cos_incidence"]))  # incidence, degrees

    @staticmethod
    def _shape(t: dict[str, Any], p: dict[str, float], c: float) -> float:
        """g(c): the cubic Hermite curve through (knots_axis, values), flat beyond the end knots; 0 where undefined."""
        if not math.isfinite(c) or (t["axis"] == "log" and c <= 0):
            return 0.0
        s = math.log(c) if t["axis"] == "log" else c
        xs = t["knots_axis"]
        g = [0.0 if n is None else p[n] for n in t["knot_parameters"]]
        g0 = [0.0 if n is None else t["knot_values"][i] for i, n in enumerate(t["knot_parameters"])]
        m = [t["slopes"][i] + sum(t["slopes_jacobian"][i][j] * (g[j] - g0[j]) for j in range(len(g)))
             for i in range(len(g))]
        s = min(max(s, xs[0]), xs[-1])
        i = max(j for j in range(len(xs) - 1) if xs[j] <= s) if s < xs[-1] else len(xs) - 2
        h = xs[i + 1] - xs[i]
        if len(xs) < 3:
            return g[i] + (g[i + 1] - g[i]) * (s - xs[i]) / h
        w = (s - xs[i]) / h
        return ((2 * w**3 - 3 * w**2 + 1) * g[i] + (w**3 - 2 * w**2 + w) * h * m[i] + (3 * w**2 - 2 * w**3) * g[i + 1]
                + (w**3 - w**2) * h * m[i + 1])

    def sigma_m(self, z: float, u: float, v: float, **inputs: float) -> float:
        """sigma alone: "9. sigma = sqrt(var)"."""
        return math.sqrt(self.variance(z, u, v, self.values, inputs))

    def gradient(self, z: float, u: float, v: float, inputs: dict[str, float]) -> tuple[float, float, list[float]]:
        """var, sigma and g_i = (var(p_i + h_i) - var(p_i - h_i)) / (4 h_i sigma) over `covariance.parameters`, with
        h_i = 1e-4 error, or 1e-7 max(|value|, 1e-12) for a parameter without one."""
        var = self.variance(z, u, v, self.values, inputs)
        sigma = math.sqrt(var)
        g = []
        for name in self.doc["covariance"]["parameters"]:
            e = self.errors[name]
            h = 1e-4 * e if e is not None else 1e-7 * max(abs(self.values[name]), 1e-12)
            up, down = dict(self.values), dict(self.values)
            up[name] += h
            down[name] -= h
            g.append((self.variance(z, u, v, up, inputs) - self.variance(z, u, v, down, inputs)) / (4 * h * sigma))
        return var, sigma, g

    def standard_error(self, g: list[float]) -> float:
        """se = sqrt(g' C g) ("The standard error"); NaN where a parameter without an error enters (its g_i is not 0)."""
        cov = self.doc["covariance"]
        names = cov["parameters"]
        if any(self.errors[n] is None and gi != 0 for n, gi in zip(names, g)):
            return math.nan
        se2 = sum(g[i] * cov["matrix"][i][j] * g[j] for i in range(len(names)) for j in range(len(names))
                  if self.errors[names[i]] is not None and self.errors[names[j]] is not None)
        return math.sqrt(max(se2, 0.0))

    def sigma(self, z: float, u: float, v: float, **inputs: float) -> tuple[float, float]:
        """(sigma, its standard error), m."""
        _, sigma, g = self.gradient(z, u, v, inputs)
        return sigma, self.standard_error(g)


def rounding_bound(evaluator: Any, z: np.ndarray, u: np.ndarray, v: np.ndarray,
                   inputs: dict[str, np.ndarray]) -> np.ndarray:
    """How far two implementations' sigma may be apart, relatively, row by row (`evaluator`: a rig.noise_model
    NoiseModel of the file). The two compute each term of the variance by the same formula in their own order, so
    each is held to the rounding of its operations, twice. u = eps / 2 is a correctly rounded operation's relative
    error; exp, log and pow are within 1 ulp (2 u).

    - the shot noise k^2 Z^(2 lambda), as exp(2 lambda ln Z) or a pow: ln Z's ulp and two products make an error of
      4 u |2 lambda ln Z| in the exponent, which exp turns into a relative one, plus its own ulp and k^2's rounding;
    - the measured light's (P_ref / (Z^2 P))^gamma, as exp(gamma ln r) or a pow: 4 u |gamma ln r| in the exponent and
      its ulp, the ratio's three roundings;
    - every other physical factor and term is positive (1 + rho^2, 1 / cos, r z^2, ambient, (z^2 / fb)^2 s^2, drift):
      at most 40 roundings in all, each u relatively;
    - an empirical shape multiplies by exp(2 g), g a cubic Hermite curve within 85 u S of another implementation of
      it (tests/test_models.py; S the size of its terms on an interval, here the largest over the knots), doubled in
      the exponent; the image shape's exponent 2 (a_x x + ... + a_yy y^2) has each term within 8 u;
    - censoring multiplies by F = 1 - A, A = 2 c phi(c) / erf(c / sqrt 2), c = T / sigma_d: A's relative error is
      |d ln A / d ln c| = |1 - c^2 - A| times c's (half the variance's before it, and 4 roundings) plus 6 u, and F's
      is A / F times A's: the cancellation where few samples are cut.
    sigma is the root: half the variance's error, and a rounding each."""
    unit = np.finfo(np.float64).eps / 2
    p, cam = evaluator.values, evaluator.doc["camera"]
    z = np.asarray(z, dtype=float)
    each = 4 * np.abs(2 * p["lambda"] * np.log(z)) + 4 + 40  # one implementation's variance, in u, before the shapes
    k = cam["intrinsics"]
    x, y = (np.asarray(u, float) - k["cx"]) / k["fx"], (np.asarray(v, float) - k["cy"]) / k["fy"]
    terms = evaluator.doc["sigma_terms"]
    for t in terms:
        name = t["effect"]
        if name == "measured_light":  # (P_ref / (Z^2 P))^gamma: the exponent's error, 4 u |gamma ln ratio|, and a pow
            light = np.asarray(inputs["pattern_dn"], dtype=float)
            with np.errstate(divide="ignore", invalid="ignore"):
                size = np.abs(p["measured_light.exponent"] * np.log(p["measured_light.pattern_ref_dn_m2"] / (z * z * light)))
            each = each + 4 * np.where(np.isfinite(size), size, 0.0) + 6
        elif name == "empirical(position)":
            q = {n: p[f"empirical(position).{n}"] for n in ("a_x", "a_y", "a_xx", "a_xy", "a_yy")}
            size = (np.abs(q["a_x"] * x) + np.abs(q["a_y"] * y) + np.abs(q["a_xx"] * x * x) + np.abs(q["a_xy"] * x * y)
                    + np.abs(q["a_yy"] * y * y))
            each = each + 2 * 8 * size + 4
        elif name.startswith("empirical("):
            g = np.abs([0.0 if n is None else p[n] for n in t["knot_parameters"]])
            slopes, h = np.abs(t["slopes"]), np.diff(t["knots_axis"])
            size = np.max(g[:-1] + g[1:] + h * (slopes[:-1] + slopes[1:])) if len(g) > 1 else np.max(g)
            each = each + 85 * size + 4  # this implementation's half of 85 u S, doubled by exp(2 g), and exp's ulp
    if "censoring" in [t["effect"] for t in terms]:
        kept = [t for t in terms if t["effect"] != "censoring"]
        uncensored = type(evaluator).from_dict({**evaluator.doc, "sigma_terms": kept})
        var = uncensored.variance(z, u, v, **{n: inputs[n] for n in uncensored.inputs})
        c = p["censoring.threshold_px"] / (np.sqrt(var) * cam["fb_px_m"] / z**2)
        erf = np.array([math.erf(w / math.sqrt(2)) for w in c.ravel()]).reshape(c.shape)
        a = 2 * c * np.exp(-0.5 * c * c) / math.sqrt(2 * math.pi) / erf
        each = each + a / (1 - a) * (np.abs(1 - c * c - a) * (each / 2 + 4) + 6) + 1
    return unit * (each + 2)  # two implementations' variances, each within `each`: sigma's half of both, and the roots


def se_bound(port: PortedModel, bound: float, var: float, sigma: float, g: list[float]) -> float:
    """How far two implementations' standard error may be apart at one sample, absolutely, m, when both difference the
    variance over the same steps h_i ("The standard error"; var, sigma and g from `PortedModel.gradient`): the
    truncation of the differences is then the same in both, and what differs is each variance's rounding. Each
    variance is within `bound` var of the exact one (`rounding_bound` bounds one implementation's variance as well as
    two sigmas' gap), so V+ - V- differs by at most 4 bound var, and g_i = (V+ - V-) / (4 h_i sigma) by
    bound var / (h_i sigma), plus bound |g_i| from sigma. se^2 = g' C g then moves by at most 2 |g|' |C| |dg| plus the
    quadratic form's rounding (n u of each of its terms), and se by half that over se, plus its root's rounding.
    Parameters without an error do not enter where se is finite."""
    unit = np.finfo(np.float64).eps / 2
    names = port.doc["covariance"]["parameters"]
    known = np.array([port.errors[n] is not None for n in names])
    cov = np.nan_to_num(np.array(port.doc["covariance"]["matrix"], dtype=float))  # null: a parameter not entering
    signed = np.where(known, g, 0.0)
    se = math.sqrt(max(float(signed @ cov @ signed), 0.0))
    h = np.array([1e-4 * port.errors[n] if port.errors[n] is not None else 1.0 for n in names])
    dg = np.where(known, bound * var / (h * sigma) + bound * np.abs(signed), 0.0)
    c, a = np.abs(cov), np.abs(signed)
    spread = 2 * a @ c @ dg + 2 * len(names) * unit * (a @ c @ a)
    return (spread / (2 * se) if se > 0 else math.sqrt(spread)) + 2 * unit * se
