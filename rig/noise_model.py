"""Evaluate a noise model that `rig export` wrote (docs/noise-model.md), with numpy as the only dependency.

    from rig.noise_model import NoiseModel            # or copy this one file into your project
    model = NoiseModel.load("camera-noise.json")
    sigma_m = model.sigma(z_m, u_px, v_px)            # any shapes that broadcast together
    sigma_m, se_m = model.sigma(z_m, u_px, v_px, with_error=True)

sigma is the standard deviation of one depth sample at true range z_m (m) in pixel (u_px, v_px), as the fitted model
predicts it before the depth file: before the rounding to the depth unit and the outliers, which the file lists
apart (docs/noise-model.md, "After sigma"). Terms that need more than (z, u, v) name their input, and refuse to run
without it: `cos_incidence` (incidence, empirical(incidence)), `ir_dn` (empirical(brightness)), `ambient_ratio`
(ambient), `drift_var_m2` (drift), `pattern_dn` (measured_light). The standard error is the delta method over the file's covariance.

This module imports numpy, json and math, and nothing of rig: it is the reference a C++ or ROS port is checked
against (the formulas: docs/noise-model.md; rig's own prediction: `rig.models.Model.predict_noise`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

SCHEMA = "rig.noise-model/1"
#: the terms of sigma this evaluator knows, each with the inputs beyond (z, u, v) it needs
TERMS = {"slant_range": (), "incidence": ("cos_incidence",), "read_noise": (), "ambient": ("ambient_ratio",),
         "noise_floor": (), "drift": ("drift_var_m2",), "censoring": (), "empirical(range)": (),
         "empirical(radius)": (), "empirical(slant)": (), "empirical(brightness)": ("ir_dn",),
         "empirical(incidence)": ("cos_incidence",), "empirical(position)": (), "measured_light": ("pattern_dn",)}


class NoiseModelError(ValueError):
    """A file this evaluator cannot use, or an input a term needs and did not get: one line, naming the fix."""


_erf = np.vectorize(math.erf, otypes=[float])


@dataclass(frozen=True)
class NoiseModel:
    """An exported model: `doc` is the file's JSON (docs/noise-model.schema.json)."""

    doc: dict[str, Any]
    source: str = "<dict>"

    @classmethod
    def load(cls, path: str | Path) -> "NoiseModel":
        try:
            doc = json.loads(Path(path).read_text())
        except (OSError, ValueError) as e:
            raise NoiseModelError(f"cannot read the noise model {path}: {e}; give a file that rig export wrote") from None
        return cls.from_dict(doc, str(path))

    @classmethod
    def from_dict(cls, doc: dict[str, Any], source: str = "<dict>") -> "NoiseModel":
        if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
            found = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
            family, _, number = str(found).partition("/")
            if family == SCHEMA.split("/")[0] and number.isdigit() and int(number) > int(SCHEMA.split("/")[1]):
                raise NoiseModelError(f"{source} is a {found} file, newer than this evaluator's {SCHEMA}; update rig "
                                      "(pip install -U rig) or take rig/noise_model.py from the rig that wrote it")
            raise NoiseModelError(f"{source} is not a {SCHEMA} file (schema: {found!r}); export the model with rig export")
        terms = doc.get("sigma_terms")
        if not isinstance(terms, list) or not all(isinstance(t, dict) and isinstance(t.get("effect"), str) for t in terms):
            raise NoiseModelError(f"{source} is damaged: sigma_terms is not a list of terms; export the model again "
                                  "with rig export")
        for term in terms:
            if term["effect"] not in TERMS:
                where = f" (from {term['user_file']})" if term.get("user_file") else ""
                raise NoiseModelError(f"{source}: sigma has the term {term['effect']!r}{where}, which this evaluator "
                                      f"does not know; evaluate it with rig (rig.models), or export a model without it")
        params = doc.get("parameters")
        if not isinstance(params, list) or not all(isinstance(q, dict) and isinstance(q.get("name"), str) for q in params):
            raise NoiseModelError(f"{source} is damaged: parameters is not a list of named values; export the model "
                                  "again with rig export")
        for q in params:
            value = q.get("value")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise NoiseModelError(f"{source}: parameter {q['name']} is {value!r}, not a finite number; export the "
                                      "model again with rig export")
        model = cls(doc, source)
        model._try()
        return model

    def _try(self) -> None:
        """sigma and its error at the middle of the valid ranges: a file whose parts are missing or of the wrong kind
        fails here, in one NoiseModelError, not later in a KeyError of its user's program."""
        try:
            mid = [0.5 * (lo + hi) if lo is not None and hi is not None else 1.0 for lo, hi in
                   (self.doc["valid"][key] for key in ("z_m", "u_px", "v_px"))]
            sigma, _ = self.sigma(*mid, with_error=True, **dict.fromkeys(self.inputs, 1.0))
        except NoiseModelError:
            raise
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
            what = f"{type(e).__name__}: {e}" if not isinstance(e, KeyError) else f"it has no {e}"
            raise NoiseModelError(f"{self.source} is damaged or not written by rig export ({what}); export the model "
                                  "again with rig export") from None
        if not np.isfinite(sigma) or sigma <= 0:
            raise NoiseModelError(f"{self.source}: sigma is {float(sigma)!r} m inside its valid range; export the model "
                                  "again with rig export")

    # -- what the file holds ---------------------------------------------------------------------
    @property
    def values(self) -> dict[str, float]:
        """Every parameter's fitted value, by qualified name ("k", "lambda", "noise_floor.sigma_px", ...)."""
        return {p["name"]: float(p["value"]) for p in self.doc["parameters"]}

    @property
    def inputs(self) -> tuple[str, ...]:
        """The inputs beyond (z_m, u_px, v_px) that `sigma` needs for this model."""
        return tuple(dict.fromkeys(n for t in self.doc["sigma_terms"] for n in TERMS[t["effect"]]))

    def valid(self, z_m: Any, u_px: Any, v_px: Any) -> np.ndarray:
        """True where (z, u, v) lies within what the fitted data covered (`valid` in the file)."""
        out = np.ones(np.broadcast_shapes(*(np.shape(a) for a in (z_m, u_px, v_px))), dtype=bool)
        for key, a in (("z_m", z_m), ("u_px", u_px), ("v_px", v_px)):
            lo, hi = self.doc["valid"][key]  # null: the recording did not say (pixel positions of an import)
            a = np.asarray(a, dtype=float)
            out &= (a >= (-np.inf if lo is None else lo)) & (a <= (np.inf if hi is None else hi))
        return out

    # -- the depth correction ----------------------------------------------------------------------
    def corrected_depth(self, z_m: Any, *, with_error: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """The true depth, m, of a depth the camera reported as z_m, with its calibration bias taken out:
        1 / ((1 + scale) / Z - disparity_offset_px / fb_px_m) (docs/noise-model.md, "The depth correction"); with
        `with_error`, also its standard error over the two parameters' covariance (the delta method, exact
        derivatives). A one-line NoiseModelError when the file carries no bias."""
        b = self.doc.get("bias")
        if not b:
            raise NoiseModelError(f"{self.source} carries no depth correction; export it with rig export from a "
                                  "perpendicular recording whose stops' distances are known (a stage, or the plan)")
        p = {q["name"]: float(q["value"]) for q in b["parameters"]}
        fb = float(b["fb_px_m"])
        z = np.asarray(z_m, dtype=float)
        inverse = (1.0 + p["scale"]) / z - p["disparity_offset_px"] / fb
        t = 1.0 / inverse
        if not with_error:
            return t
        g = {"scale": -t * t / z, "disparity_offset_px": t * t / fb}  # dT/dp = -T^2 d(1/T)/dp
        names = b["covariance"]["parameters"]
        c = np.asarray(b["covariance"]["matrix"], dtype=float)
        var = sum(g[a] * g[bb] * c[i, j] for i, a in enumerate(names) for j, bb in enumerate(names))
        return t, np.sqrt(np.maximum(var, 0.0))

    # -- sigma -----------------------------------------------------------------------------------
    def sigma(self, z_m: Any, u_px: Any, v_px: Any, *, with_error: bool = False,
              **inputs: Any) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """sigma of a depth sample, m, at true range z_m and pixel (u_px, v_px); with `with_error`, also its standard
        error (the delta method: sqrt(g' C g), g the derivative over the free parameters, C their covariance), NaN
        wherever a parameter the data do not determine (`error` null) enters sigma."""
        var = self.variance(z_m, u_px, v_px, **inputs)
        sigma = np.sqrt(var)
        if not with_error:
            return sigma
        cov = self.doc["covariance"]
        names = cov["parameters"]
        c = np.array([[np.nan if x is None else x for x in row] for row in cov["matrix"]], dtype=float)
        c = c.reshape(len(names), len(names))  # null (NaN): the row and column of an undetermined parameter
        values = self.values
        errors = {p["name"]: p["error"] for p in self.doc["parameters"]}
        determined = np.array([errors.get(n) is not None and np.isfinite(c[i, i]) and c[i, i] > 0
                               for i, n in enumerate(names)], dtype=bool)
        grads = []
        for i, name in enumerate(names):
            h = 1e-4 * errors[name] if determined[i] else 1e-7 * max(abs(values[name]), 1e-12)
            up, down = dict(values), dict(values)
            up[name] += h
            down[name] -= h
            dvar = (self.variance(z_m, u_px, v_px, values=up, **inputs)
                    - self.variance(z_m, u_px, v_px, values=down, **inputs)) / (2 * h)
            grads.append(dvar / (2 * sigma))
        if not grads:
            return sigma, np.zeros_like(sigma)
        g = np.stack(grads)
        known = np.where(np.outer(determined, determined), c, 0.0)
        se = np.sqrt(np.maximum(np.einsum("i...,ij,j...->...", g, known, g), 0.0))
        enters = np.any(g[~determined] != 0, axis=0) if not determined.all() else np.zeros(se.shape, dtype=bool)
        return sigma, np.where(enters, np.nan, se)

    def variance(self, z_m: Any, u_px: Any, v_px: Any, *, values: dict[str, float] | None = None,
                 **inputs: Any) -> np.ndarray:
        """sigma^2, m^2: the stages of docs/noise-model.md in order (base, illumination, image noise, disparity,
        drift, empirical shapes, censoring); `values` replaces the file's parameter values."""
        p = self.values if values is None else values
        missing = [n for n in self.inputs if inputs.get(n) is None]
        if missing:
            raise NoiseModelError(f"{self.source}: the model's terms need {', '.join(missing)} as well as (z, u, v); "
                                  f"pass {', '.join(f'{n}=...' for n in missing)} to sigma()")
        unknown = set(inputs) - set(self.inputs)
        if unknown:
            raise NoiseModelError(f"{self.source}: this model takes no {', '.join(sorted(unknown))}; "
                                  f"its inputs are z_m, u_px, v_px{''.join(', ' + n for n in self.inputs)}")
        arrays = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (z_m, u_px, v_px, *inputs.values())))
        z, u, v = arrays[:3]
        given = dict(zip(inputs, arrays[3:]))
        cam = self.doc["camera"]
        k = cam["intrinsics"]
        x, y = (u - k["cx"]) / k["fx"], (v - k["cy"]) / k["fy"]
        rho2 = x * x + y * y
        fb = cam["fb_px_m"]
        on = bool(self.doc["settings"]["projector_on"])
        shot = p["k"] ** 2 * np.exp(2.0 * p["lambda"] * np.log(z))  # k^2 Z^(2 lambda) (paper, eq. error_prop_*)
        illum, image = np.ones_like(z), np.zeros_like(z)
        terms = self.doc["sigma_terms"]
        for t in terms:
            name = t["effect"]
            if name == "slant_range" and on:  # light falls with the slant range: 1 + rho^2
                illum = illum * (1.0 + rho2)
            elif name == "incidence" and on:  # a matte wall returns cos(incidence)
                illum = illum / np.clip(given["cos_incidence"], 0.05, 1.0)
            elif name == "measured_light" and on:  # the light measured: (P_ref / (Z^2 P))^gamma where P is known
                light = given["pattern_dn"]
                known = np.isfinite(light) & (light > 0)
                ratio = p["measured_light.pattern_ref_dn_m2"] / (z**2 * np.where(known, light, 1.0))
                illum = illum * np.where(known, np.exp(p["measured_light.exponent"] * np.log(ratio)), 1.0)
        for t in terms:
            name = t["effect"]
            if name == "read_noise" and on:  # read noise against the pattern's light: r Z^2 (light loss)
                image = image + p["read_noise.ratio_at_1m"] * z**2 * illum
            elif name == "ambient":  # ambient / pattern brightness, measured
                a = given["ambient_ratio"]
                image = image + np.where(np.isfinite(a) & on, a, 0.0)
        var = shot * illum * (1.0 + image)
        for t in terms:
            name = t["effect"]
            if name == "noise_floor":  # (Z^2 / (f b))^2 sigma_px^2 (eq. error_prop_unassisted)
                var = var + (z**2 / fb) ** 2 * p["noise_floor.sigma_px"] ** 2
            elif name == "drift":
                var = var + given["drift_var_m2"]
        for t in terms:
            if t["effect"] == "empirical(position)":
                q = {n: p[f"empirical(position).{n}"] for n in ("a_x", "a_y", "a_xx", "a_xy", "a_yy")}
                var = var * np.exp(2.0 * (q["a_x"] * x + q["a_y"] * y + q["a_xx"] * x * x + q["a_xy"] * x * y
                                          + q["a_yy"] * y * y))
            elif t["effect"].startswith("empirical("):
                var = var * np.exp(2.0 * _shape(t, p, _covariate(t["covariate"], z, rho2, given)))
        for t in terms:
            if t["effect"] == "censoring":  # the disparity error truncated at +-T: var *= E[x^2 | |x| < c]
                c = p["censoring.threshold_px"] / (np.sqrt(var) * fb / z**2)
                kept = np.maximum(_erf(c / math.sqrt(2.0)), 1e-300)
                phi = np.exp(-0.5 * c * c) / math.sqrt(2 * math.pi)
                var = var * (1.0 - 2.0 * c * phi / kept)
        return var


def _covariate(name: str, z: np.ndarray, rho2: np.ndarray, given: dict[str, np.ndarray]) -> np.ndarray:
    """The covariate an empirical shape follows (docs/noise-model.md, "Empirical shapes")."""
    if name == "range":
        return z
    if name == "radius":
        return np.sqrt(rho2)
    if name == "slant":
        return z * np.sqrt(1.0 + rho2)
    if name == "brightness":
        return given["ir_dn"]
    return np.degrees(np.arccos(np.clip(given["cos_incidence"], -1.0, 1.0)))  # incidence, deg


def _shape(t: dict[str, Any], p: dict[str, float], c: np.ndarray) -> np.ndarray:
    """g(c): the cubic Hermite curve through (knots, values) with the file's slopes, flat beyond the end knots, over
    ln c for a log axis; 0 where c is not defined. The slopes move with the values by the file's Jacobian (exact at
    the fitted values, to first order beside them, which is all the standard error uses)."""
    knots = np.array(t["knots_axis"], dtype=float)
    names = t["knot_parameters"]
    g = np.array([0.0 if n is None else p[n] for n in names])
    g0 = np.array([0.0 if n is None else t["knot_values"][i] for i, n in enumerate(names)])
    slopes = np.array(t["slopes"], dtype=float) + np.array(t["slopes_jacobian"], dtype=float) @ (g - g0)
    with np.errstate(divide="ignore", invalid="ignore"):
        axis = np.where(c > 0, np.log(c), np.nan) if t["axis"] == "log" else np.asarray(c, dtype=float)
    ok = np.isfinite(axis)
    if len(knots) < 3:
        return np.where(ok, np.interp(np.clip(np.nan_to_num(axis), knots[0], knots[-1]), knots, g), 0.0)
    xa = np.clip(np.nan_to_num(axis), knots[0], knots[-1])
    i = np.clip(np.searchsorted(knots, xa, side="right") - 1, 0, len(knots) - 2)
    h = np.diff(knots)[i]
    s = (xa - knots[i]) / h
    s2, s3 = s * s, s * s * s
    out = ((2 * s3 - 3 * s2 + 1) * g[i] + (s3 - 2 * s2 + s) * h * slopes[i] + (3 * s2 - 2 * s3) * g[i + 1]
           + (s3 - s2) * h * slopes[i + 1])
    return np.where(ok, out, 0.0)
