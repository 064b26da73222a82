"""Results a script can read: `rig fit`, `fit --model`, `compare` and `diagnose --json`, one schema for all.

The schema is docs/json-schema.json (explained in docs/json.md): a document with the command, the
file, the rig version, the recording's notes and a list of fits; each fit has the same fields
(model, values, errors, units, likelihood, headline error, whether lambda is determined). Numbers
that are not finite (an error that could not be computed) are written as null, so the output is
valid JSON for every parser.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from .. import package_version
from ..diagnosis import Diagnosis, Headline
from ..models import ModelFit
from ..models.data.determinacy import LambdaStatus, lambda_status

SCHEMA = "rig.result/1"


def finite(x: Any) -> Any:
    """`x` with every float that is not finite as None and numpy scalars and arrays as plain Python."""
    if isinstance(x, dict):
        return {str(k): finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [finite(v) for v in x]
    if isinstance(x, np.ndarray):
        return finite(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    return x


def dumps(doc: dict, *, line: bool = False) -> str:
    """The document as JSON text (with `line`, on one line: JSON Lines); never a bare NaN or Infinity."""
    return json.dumps(finite(doc), indent=None if line else 2, allow_nan=False)


def headline_json(h: Headline) -> dict:
    return {"error_pct": h.error_pct, "noise_pct": h.noise_pct, "excess_pct": h.excess_pct,
            "within_noise": h.within_noise if h.determined else None, "state": h.state, "verdict": h.verdict()}


def fit_json(fit: ModelFit, head: Headline | None = None, status: LambdaStatus | None = None,
             held_out_nll: float | None = None) -> dict:
    """One fit: the fields every command writes for every model (docs/json.md)."""
    params = fit.model.parameters()
    status = status or (head.lambda_status if head is not None else None)
    return {
        "model": fit.model.name,
        "values": {name: fit.values[name] for name, _ in params},
        "errors": {name: fit.errors.get(name) for name, p in params if p.vary},
        "units": {name: p.unit or "1" for name, p in params},
        "fixed": [name for name, p in params if not p.vary],
        "loglik": fit.loglik,
        "likelihood": fit.likelihood,
        "bic": fit.bic,
        "n_free": fit.n_free,
        "n_pixels": fit.n_obs,
        "n_samples": fit.n_samples,
        "dof": fit.dof,
        "z_min_m": fit.z_min_m,
        "z_max_m": fit.z_max_m,
        "corr_k_lambda": None if fit.lam_fixed else fit.corr,
        "converged": fit.converged,
        "headline": None if head is None else headline_json(head),
        "lambda_status": None if status is None else status.as_dict(),
        "held_out_nll": held_out_nll,
        "error_notes": dict(fit.error_notes),
    }


def document(command: str, file: str | Path, notes: list[str], fits: list[dict], *, best: str | None = None,
             window_m: tuple[float | None, float | None] = (None, None), diagnosis: dict | None = None,
             accuracy: dict | None = None) -> dict:
    """The whole output of one command (docs/json.md); `accuracy` (rig fit's: `rig.accuracy.accuracy_json`) only
    where given."""

    doc = {"schema": SCHEMA, "command": command, "rig_version": package_version(), "file": str(file),
           "notes": list(notes), "window_m": {"z_min": window_m[0], "z_max": window_m[1]}, "fits": fits,
           "best": best, "diagnosis": diagnosis}
    if accuracy is not None:
        doc["accuracy"] = accuracy
    return doc


def diagnosis_json(diag: Diagnosis, plots: list[Path], page: Path) -> tuple[list[dict], dict]:
    """(the fits of the diagnosis's path, start first; the diagnosis's own part of the document)."""
    fits = [fit_json(st.fit, st.headline) for st in diag.steps]
    if diag.unexplained is not None:
        fits += [fit_json(st.fit, st.headline) for st in diag.unexplained.steps]
    r = diag.residuals.consistency
    threshold = r.threshold_with(1)
    part = {
        "summary": diag.summary(),
        "start_model": diag.model_fit.model.name,
        "final_model": diag.final_fit.model.name,
        "added": diag.added,
        "empirical": [st.covariate for st in diag.unexplained.empirical_steps] if diag.unexplained is not None else [],
        "added_after_empirical": ([st.added for st in diag.unexplained.steps if not st.is_empirical]
                                  if diag.unexplained is not None else []),
        "stopped": diag.stopped,
        "power_law": fit_json(diag.power_law_fit, status=lambda_status(diag.data)),
        "candidates": [{"effect": c.effect.name, "dbic": c.dbic, "lrt": c.lrt, "df": c.df, "p_value": c.p_value,
                        "significant": c.significant} for c in diag.candidates],
        "checks": [{"name": c.name, "chi2": c.chi2, "dof": c.dof, "p_value": c.p_value,
                    "within_noise": c.p_value >= threshold} for c in r.checks],
        "report": {"html": str(page), "plots": [str(p) for p in plots]},
    }
    return fits, part
