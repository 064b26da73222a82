"""Test vectors of an exported model (`rig export --test-vectors`): inputs, and the sigma and standard error that
`rig.noise_model` gives there, as CSV, for a port (C++, a ROS node) to check itself against (docs/noise-model.md).

The inputs are drawn with a fixed seed over, and a little beyond, where the model was fitted: ranges from 0.8 x the
nearest to 1.25 x the farthest on a log scale (past the end knots, where an empirical shape is flat), pixels over the
whole image at sub-pixel positions with its corners and centre exactly, and each input a term needs over its whole
domain: cos_incidence from 0.01 (the clip at 0.05) to 1, ambient_ratio 0 to 0.5 and NaN (not measured) in one row of
16, drift_var_m2 0 to 1e-8 m^2, ir_dn over the brightness shape's knots and beyond, pattern_dn within a factor 3 of the
typical pixel's light at that range (P_ref / Z^2) and NaN in one row of 16.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ..noise_model import NoiseModel
from .output_file import aside

#: rows in a vectors file: 1+2n evaluations of the model each (the differences of the standard error), well under a
#: second for every model rig fits
ROWS = 256


def vector_inputs(model: NoiseModel, rows: int = ROWS, seed: int = 0) -> dict[str, np.ndarray]:
    """z_m, u_px, v_px and the model's other inputs (`NoiseModel.inputs`), `rows` of each."""
    rng = np.random.default_rng(seed)
    lo, hi = model.doc["valid"]["z_m"]
    k = model.doc["camera"]["intrinsics"]
    w, h = k["width"], k["height"]
    u = rng.uniform(-0.5, w - 0.5, rows)
    v = rng.uniform(-0.5, h - 0.5, rows)
    corners = [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1), (k["cx"], k["cy"])]
    for i, (cu, cv) in enumerate(corners):
        u[i], v[i] = cu, cv
    out = {"z_m": np.exp(rng.uniform(np.log(0.8 * lo), np.log(1.25 * hi), rows)), "u_px": u, "v_px": v}
    knots = [t["knots"] for t in model.doc["sigma_terms"] if t.get("covariate") == "brightness"]
    dn = (0.5 * min(knots[0]), 2.0 * max(knots[0])) if knots else (5.0, 1000.0)
    ambient = rng.uniform(0.0, 0.5, rows)
    ambient[::16] = np.nan
    draws = {"cos_incidence": rng.uniform(0.01, 1.0, rows), "ir_dn": np.exp(rng.uniform(*np.log(dn), rows)),
             "ambient_ratio": ambient, "drift_var_m2": rng.uniform(0.0, 1e-8, rows)}
    if "pattern_dn" in model.inputs:  # about the light a typical pixel saw at that range, a factor 3 either way
        light = model.values["measured_light.pattern_ref_dn_m2"] / out["z_m"] ** 2 * np.exp(rng.uniform(-1.1, 1.1, rows))
        light[::16] = np.nan
        draws["pattern_dn"] = light
    out.update({n: draws[n] for n in model.inputs})
    return out


def write_vectors(model: NoiseModel, path: Path) -> Path:
    """Write `path`: a header row (z_m, u_px, v_px, the model's other inputs, sigma_m, sigma_se_m), then a row a
    sample, each number as Python's repr (the shortest decimal that reads back to the same double; nan for NaN)."""
    inputs = vector_inputs(model)
    sigma, se = model.sigma(inputs["z_m"], inputs["u_px"], inputs["v_px"], with_error=True,
                            **{n: inputs[n] for n in model.inputs})
    columns = {**inputs, "sigma_m": sigma, "sigma_se_m": se}
    with aside(path) as tmp, open(tmp, "w", newline="") as f:  # whole or not at all (rig.reports.output_file)
        out = csv.writer(f)
        out.writerow(columns)
        out.writerows(zip(*(map(repr, map(float, c)) for c in columns.values())))
    return path
