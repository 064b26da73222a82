"""Why a fitted parameter has no standard error, in words (`ModelFit.error_notes`).

A Cramer-Rao error is the curvature of the log-likelihood at its maximum. There is none when

- the parameter sits at a bound: the maximum is on the edge of what it may take, where the
  likelihood still rises towards the edge and its curvature is not an error (at a lower bound of
  0: the data show none of the effect);
- the data cannot tell two or more parameters apart (an effect degenerate with k): the
  likelihood is flat along a combination of them, so the information matrix is singular;
- another parameter is in one of those cases: the errors are joint, so the others' go with it.
"""

from __future__ import annotations

import numpy as np

from .parameters import Param

#: a parameter takes part in a flat combination when its share of the flattest direction is at least this
PART_OF_FLAT = 0.3


def error_notes(names: list[str], values: dict[str, float], params: dict[str, Param], hessian: np.ndarray | None,
                se: np.ndarray) -> dict[str, str]:
    """For each parameter of `names` whose error `se` is not finite, why (one sentence); `hessian` is the log-likelihood's
    (in the parameters as the errors were taken), None if it could not be made."""
    missing = [i for i, s in enumerate(se) if not np.isfinite(s)]
    if not missing:
        return {}
    notes: dict[str, str] = {}
    edge = {n: params[n].at_bound(values[n]) for n in names}
    at = [n for n in names if edge[n]]
    for n in at:
        p = params[n]
        bound = p.min if edge[n] == "lower" else p.max
        if edge[n] == "lower" and bound == 0 and "." in n:
            notes[n] = (f"at its lower bound, 0: the data show none of {_effect(n)} (drop it); a fit on a bound has no "
                        "Cramer-Rao error")
        else:
            notes[n] = (f"at its {edge[n]} bound, {bound:g}: the best value is on the edge of what it may take, where the "
                        f"likelihood's curvature is no error; widen the bound or drop {_effect(n)}")
    flat = _flattest(names, hessian)
    for i in missing:
        n = names[i]
        if n in notes:
            continue
        if at:
            notes[n] = (f"its error is joint with that of {_and(at)}, on {'a bound' if len(at) == 1 else 'bounds'}: "
                        f"refit without {_and(sorted({_effect(a) for a in at}))} for it")
        elif len(flat) > 1 and n in flat:
            effects = sorted({_effect(m) for m in flat if "." in m})
            notes[n] = (f"{_and(flat)} trade off against each other (the likelihood is flat along a combination of "
                        "them), so the data cannot tell them apart; "
                        + (f"drop {_and(effects)} or hold one of them fixed" if effects else "hold one of them fixed"))
        else:
            notes[n] = (f"the likelihood does not curve along {n} at the fit (flat, or a saddle), so the data do not "
                        "determine it here")
    return notes


def _flattest(names: list[str], hessian: np.ndarray | None) -> list[str]:
    """The parameters that make up the direction along which the log-likelihood curves least (scaled by each one's
    own curvature), largest share first."""
    if hessian is None or not np.all(np.isfinite(hessian)) or len(names) < 2:
        return []
    info = -np.asarray(hessian, dtype=float)
    scale = np.sqrt(np.abs(np.diag(info)))
    scale = np.where(scale > 0, scale, 1.0)
    _, vectors = np.linalg.eigh(info / np.outer(scale, scale))
    share = np.abs(vectors[:, 0])
    order = np.argsort(-share)
    return [names[i] for i in order if share[i] >= PART_OF_FLAT]


def _effect(qualified: str) -> str:
    return qualified.split(".", 1)[0] if "." in qualified else qualified


def _and(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]
