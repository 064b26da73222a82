"""The file `rig export` writes: a fitted model as `rig.noise-model/1` (docs/noise-model.md, the schema beside it),
which `rig.noise_model.NoiseModel` evaluates with numpy alone.

What goes in: the camera (identity, intrinsics, f b, depth unit) and its settings, every parameter with its unit and
error, the free parameters' covariance, the terms of sigma in the order they apply (an empirical shape with its knots,
values and slopes, so the evaluator draws the same curve), what changes the samples after sigma (rounding, outliers,
tails), and where the model is valid: the range and image region of the fitted pixels, with the headline error there.
"""

from __future__ import annotations

import json
import math
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from .. import package_version
from ..noise_model import SCHEMA, TERMS
from .data.model_data import ModelData
from .effects.pchip import pchip_slopes, slopes_jacobian
from .parts.prediction import EffectStage
from .parts.result import ModelFit

#: what each effect that acts after sigma does to the samples, in words (docs/noise-model.md, "After sigma")
AFTER_SIGMA = {
    "quantization": "depth is rounded to the depth unit (and disparity to step_px): q^2/12 more variance when sigma >> q",
    "outliers": "a fraction of samples are mismatches, uniform within +-width_px of the true disparity",
    "empirical(tails)": "the excess kurtosis follows a curve over ln Z: heavier or lighter tails, the same sigma",
    "empirical(time)": "noise shared by neighbouring pixels: the frame mean varies more than independent pixels give",
    "empirical(fill)": "the fill rate follows a curve over ln Z: samples lost for a reason the model does not name",
}


def _number(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(float(x)) else None


def _camera(recording: Any, d: ModelData) -> dict[str, Any]:
    cal = d.calibration
    try:
        described = json.loads(recording.attrs.get("camera", "{}"))
    except (TypeError, ValueError):
        described = {}
    described = described if isinstance(described, dict) else {}
    return {"model": described.get("model") or recording.attrs.get("camera_model"),
            "serial": described.get("serial") or recording.attrs.get("camera_serial"),
            "firmware": described.get("firmware"), "simulated": bool(described.get("simulated", False)),
            "intrinsics": {k: getattr(cal, k) for k in ("width", "height", "fx", "fy", "cx", "cy")},
            "baseline_m": cal.baseline_m, "fb_px_m": d.fb_px_m, "depth_unit_m": d.depth_unit_m}


def _settings(recording: Any, d: ModelData) -> dict[str, Any]:
    labels = recording.stop_labels()
    back = recording.stop(labels[0]).settings_read_back if labels else {}
    params = recording.protocol_params
    on = d.projector_on
    return {"projector_on": bool(np.asarray(on).any()) if on is not None else bool(params.get("projector_on", True)),
            "exposure_us": _number(back.get("exposure_us", params.get("exposure_us"))),
            "gain": _number(back.get("gain", params.get("gain"))),
            "auto_exposure": bool(back.get("auto_exposure", False))}


def _term(effect: Any, values: dict[str, float]) -> dict[str, Any]:
    """One term of sigma, as the evaluator reads it."""
    out: dict[str, Any] = {"effect": effect.name, "stage": int(effect.stage),
                           "kind": "empirical" if effect.name.startswith("empirical(") else "physical",
                           "parameters": [f"{effect.name}.{p.name}" for p in effect.params]}
    if effect.name not in TERMS:
        out["kind"] = "user"
        out["user_file"] = str(getattr(effect, "source", "") or "") or None
        return out
    covariate = getattr(effect, "covariate", None)
    if out["kind"] == "empirical" and covariate != "position":
        knots = np.asarray(effect.knots, dtype=float)
        axis = effect._axis(knots)
        g = np.array([0.0, *(values[n] for n in out["parameters"])])[: len(knots)]
        out.update(covariate=covariate, axis="log" if covariate in ("range", "slant", "brightness") else "linear",
                   knots=knots.tolist(), knots_axis=axis.tolist(),
                   knot_parameters=[None, *out["parameters"]][: len(knots)], knot_values=g.tolist(),
                   slopes=(pchip_slopes(axis, g) if len(knots) >= 3 else np.zeros(len(knots))).tolist(),
                   slopes_jacobian=(slopes_jacobian(axis, g) if len(knots) >= 3 else np.zeros((len(knots),) * 2)).tolist())
    return out


def _determined_covariance(fit: ModelFit, names: list[str]) -> np.ndarray:
    """The free parameters' covariance, with NaN (null in the file) in the row and column of each parameter the data
    do not determine: one without an error, or whose variance is not positive (the inverse of a Hessian that is not
    negative definite: along a flat or wrong-signed direction its entries are no covariance)."""
    if fit.covariance is None:
        return np.full((len(names), len(names)), np.nan)
    cov = np.array(fit.covariance, dtype=float)
    diag = np.diag(cov)
    errors = np.array([fit.errors.get(n, np.nan) for n in names], dtype=float)
    undetermined = ~(np.isfinite(diag) & (diag > 0) & np.isfinite(errors))
    cov[undetermined, :] = np.nan
    cov[:, undetermined] = np.nan
    return cov


def noise_model_document(fit: ModelFit, d: ModelData, recording: Any, recording_path: str | Path,
                         headline: Any = None, notes: list[str] | None = None,
                         bias: dict[str, Any] | None = None) -> dict[str, Any]:
    """The `rig.noise-model/1` document of `fit` (made on `d`, from the open `recording` at `recording_path`), with
    the depth correction `bias` where the accuracy against the stage gave one (`rig.accuracy.bias_export`)."""
    model = fit.model
    names = [n for n, _ in model.free()]
    cov = _determined_covariance(fit, names)
    determined = {n for i, n in enumerate(names) if np.isfinite(cov[i, i])}
    sigma_terms = [_term(e, fit.values) for e in model.effects if e.stage <= EffectStage.CENSOR]
    after = [{"effect": e.name, "stage": int(e.stage), "parameters": [f"{e.name}.{p.name}" for p in e.params],
              "meaning": AFTER_SIGMA.get(e.name, "a user's effect; see its file")} for e in model.effects if e.stage > EffectStage.CENSOR]
    words = [*(notes or [])]
    kinds = {t["kind"] for t in sigma_terms}
    if "empirical" in kinds:
        words.append("sigma includes an empirical shape: a fitted curve, not physics; do not extrapolate it past `valid`")
    if "user" in kinds:
        users = ", ".join(f"{t['effect']} ({t['user_file'] or 'file not known'})" for t in sigma_terms if t["kind"] == "user")
        words.append(f"sigma includes user effects this file cannot carry ({users}): rig.noise_model refuses it")
    if len(determined) < len(names):
        words.append(f"the data do not determine {', '.join(n for n in names if n not in determined)} (error null): "
                     "sigma's standard error is NaN wherever they enter sigma")
    u, v = d.u_px[np.isfinite(d.u_px)], d.v_px[np.isfinite(d.v_px)]
    doc = {
        "schema": SCHEMA, "rig_version": package_version(),
        "created_utc": datetime.now(timezone.utc).replace(microsecond=0).isoformat(),
        "recording": {"file": str(recording_path), "protocol": recording.protocol,
                      "started_utc": recording.attrs.get("started_utc")},
        "camera": _camera(recording, d), "settings": _settings(recording, d),
        "model": model.name, "likelihood": fit.likelihood,
        "parameters": [{"name": n, "value": float(fit.values[n]),
                        "error": (_number(fit.errors.get(n)) if n in determined else None) if p.vary else 0.0,
                        "unit": p.unit, "free": bool(p.vary), "meaning": p.doc} for n, p in model.parameters()],
        "covariance": {"parameters": names, "matrix": [[_number(x) for x in row] for row in np.asarray(cov)]},
        "sigma_terms": sigma_terms, "after_sigma": after,
        "valid": {"z_m": [float(np.min(d.z_m)), float(np.max(d.z_m))],
                  "u_px": [float(u.min()), float(u.max())] if u.size else [None, None],
                  "v_px": [float(v.min()), float(v.max())] if v.size else [None, None],
                  "headline_error_pct": _number(headline.error_pct) if headline is not None else None,
                  "noise_pct": _number(headline.noise_pct) if headline is not None else None,
                  "verdict": headline.verdict() if headline is not None else None,
                  "pixel_stops": int(len(d)), "samples": int(fit.n_samples)},
        "notes": words,
        "bias": bias,
    }
    return doc
