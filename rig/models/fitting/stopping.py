"""When a maximum-likelihood fit has nothing left to gain: L-BFGS-B stopped by the Newton decrement, in nats.

L-BFGS-B's own tests are relative (the objective's reduction per step, the projected gradient's size). On a
log-likelihood of a million pixels neither says when the optimum is reached to the precision that matters: the
change a step makes reaches the arithmetic's rounding (~1e-7 nats of ~1e6) only after the fit is done, and
then the line search spends 10-60 evaluations probing that rounding before it gives up (on the benchmark's
demo recording, 264 of a diagnosis's 430 evaluations). The Newton decrement does: 0.5 g' H^-1 g is what a
Newton step would still gain, and one standard error away from the optimum costs 0.5 nats, so a fit whose
decrement is below STOP_NATS sits within sqrt(2 STOP_NATS / 0.5) ~ 0.002 standard error of it.

H^-1 is the BFGS estimate from the iterates' steps and gradient changes (what L-BFGS-B itself keeps, rebuilt
here because its callback is given only x and the objective); the fit must have made as many steps as it has parameters first.
"""

from __future__ import annotations

import numpy as np

#: the fit stops when a Newton step would gain less than this (log-likelihood units); 100x below the polish's
#: threshold (`optimise.NM_FATOL_NATS`), so a fit stopped here is never polished for want of it
STOP_NATS = 1e-6


class NewtonStop:
    """An L-BFGS-B `callback` (`minimize(..., callback=stop)`) that raises StopIteration when the Newton decrement,
    times `scale` (the objective is -log-likelihood / scale), falls below STOP_NATS.

    `seen(x, g)` must be called by the objective with each point and gradient it evaluates: the callback is given
    only the iterate, whose gradient is the last one seen there."""

    def __init__(self, scale: float, stop_nats: float = STOP_NATS, prior: np.ndarray | None = None):
        self.scale = scale
        self.prior = prior  # an inverse Hessian known before the first step (a warm refit's), trusted from it
        self.stop_nats = stop_nats
        self.start: tuple[np.ndarray, np.ndarray] | None = None
        self.last: tuple[np.ndarray, np.ndarray] | None = None
        self.iterates: list[tuple[np.ndarray, np.ndarray]] = []
        self.stopped = False
        self.gain_nats = np.inf

    def seen(self, x: np.ndarray, g: np.ndarray) -> None:
        self.last = (np.array(x, dtype=float), np.array(g, dtype=float))
        if self.start is None:
            self.start = self.last

    def __call__(self, intermediate_result) -> None:
        x = np.asarray(intermediate_result.x, dtype=float)
        if self.last is None or not np.array_equal(self.last[0], x):
            return  # the iterate's gradient was not seen (a wrapped objective): no estimate
        if not self.iterates and self.start is not None:
            self.iterates.append(self.start)
        self.iterates.append(self.last)
        if self.prior is None and len(self.iterates) <= x.size:  # one step per parameter before the estimate is trusted
            return
        h = inverse_hessian(self.iterates, self.prior)
        if h is None:
            return
        g = self.last[1]
        self.gain_nats = 0.5 * float(g @ h @ g) * self.scale
        if 0.0 <= self.gain_nats < self.stop_nats:
            self.stopped = True
            raise StopIteration


def inverse_hessian(iterates: list[tuple[np.ndarray, np.ndarray]], prior: np.ndarray | None = None) -> np.ndarray | None:
    """The BFGS inverse-Hessian estimate from successive (x, gradient) pairs, started from `prior` or else the last
    pair's scaled identity (s'y / y'y), as L-BFGS does; pairs without positive curvature (s'y <= 0) are skipped.
    None when no pair has it and there is no prior."""
    pairs = [(x1 - x0, g1 - g0) for (x0, g0), (x1, g1) in zip(iterates, iterates[1:])]
    pairs = [(s, y) for s, y in pairs if float(s @ y) > 1e-300 * max(float(y @ y), 1e-300)]
    if not pairs:
        return None if prior is None else np.array(prior, dtype=float)
    s, y = pairs[-1]
    n = s.size
    h = np.array(prior, dtype=float) if prior is not None else np.eye(n) * float(s @ y) / float(y @ y)
    for s, y in pairs:
        rho = 1.0 / float(s @ y)
        v = np.eye(n) - rho * np.outer(s, y)
        h = v @ h @ v.T + rho * np.outer(s, s)
    return h
