"""Which parameters the data determine at a fit: the observed information along them (issue 49).

A term whose coefficients the data do not determine describes nothing (its coefficients follow the noise), so the
diagnosis's path does not add it (`rig.diagnosis.unexplained`).
"""

from __future__ import annotations

import numpy as np

from ..data.model_data import ModelData
from .optimise import _hessian, fit_data
from ..parts.result import ModelFit

#: `undetermined`'s difference step, as a fraction of each parameter's value, or of 0.01 of its unit where the
#: parameter may cross 0 (a coefficient fitted near 0 would otherwise get steps below the likelihood's rounding)
DETERMINACY_STEP = 1e-4
#: a direction is flat when its curvature, with each parameter in units of its own held error (the information
#: matrix scaled to unit diagonal), is below this: the data then determine it 1e4 times worse than alone
FLAT_CURVATURE = 1e-8


def undetermined(fit: ModelFit, d: ModelData, names: list[str]) -> dict[str, str]:
    """The parameters among `names` that the data do not determine at `fit`, with the model's other parameters
    held, each with why: the log-likelihood's curvature (the observed information, by central differences) is not
    a maximum along it, or is flat along a direction it is most of (FLAT_CURVATURE). A parameter without a held
    error has no joint error either."""
    if not names:
        return {}
    params = dict(fit.model.parameters())
    nodes = fit_data(fit.model, d)
    x = np.array([fit.values[n] for n in names], dtype=float)
    # a parameter that may cross 0 (a coefficient in ln units) is stepped on a scale of at least 0.01 of its unit
    crosses = np.array([params[n].min < 0 < params[n].max for n in names])
    scale = np.where(crosses, np.maximum(np.abs(x), 1e-2), np.abs(x))
    steps = DETERMINACY_STEP * np.where(scale > 0, scale, 1e-2)
    lo = np.array([params[n].min for n in names]) + steps
    hi = np.array([params[n].max for n in names]) - steps
    x = np.clip(x, lo, hi)  # the differences inside the bounds

    def f(u: np.ndarray) -> float:
        v = dict(fit.values)
        v.update(zip(names, u))
        return fit.model.loglik(v, nodes)

    with np.errstate(all="ignore"):
        info = -_hessian(f, x, steps)
    diag = np.diag(info)
    out = {n: "the fit is not a maximum along it" for n, h in zip(names, diag) if not (np.isfinite(h) and h > 0)}
    if out or len(names) == 1:
        return out
    w, vecs = np.linalg.eigh(info / np.sqrt(np.outer(diag, diag)))
    for k in np.flatnonzero(w < FLAT_CURVATURE):
        i = int(np.argmax(np.abs(vecs[:, k])))  # the parameter that direction is most of
        out.setdefault(names[i], "the log-likelihood is flat along it" if w[k] > -FLAT_CURVATURE
                       else "the fit is not a maximum along it")
    return out
