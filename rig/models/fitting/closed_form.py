"""The paper's maximum-likelihood fit of sigma_Z = k * Z^lambda, on all pixels and frames.

Paper (Huber et al.), "Experimental parameter estimation": samples z_i ~ N(z_mean, (k z_mean^lambda)^2);
k follows analytically (eq. k_mle), lambda numerically (eq. lambda_mle), and the standard
errors are the Cramer-Rao bound from the inverse Hessian.

Here the samples enter through per-pixel sufficient statistics. A pixel p with n_p samples
and sum of squared deviations M_p contributes w_p = n_p - 1 degrees of freedom (its mean was
estimated from the same samples), so with A(lam) = sum_p M_p z_p^(-2 lam), W = sum_p w_p,
L = sum_p w_p ln z_p:
    l(k, lam) = -W/2 ln(2 pi) - W ln k - lam L - A(lam) / (2 k^2)
    k^2 = A(lam) / W                     (eq. k_mle with the degrees of freedom)
    dl/dlam = -L + B(lam) / k^2 = 0,     B = sum_p M_p z_p^(-2 lam) ln z_p   (eq. lambda_mle)
Hessian at the optimum: d2l/dk2 = -2W/k^2, d2l/dk dlam = -2B/k^3, d2l/dlam2 = -2C/k^2 with
C = sum_p M_p z_p^(-2 lam) (ln z_p)^2.

With k profiled out, -l is f(lam) = W/2 ln A(lam) + lam L + const, convex (f'' = 2 W (A C - B^2) / A^2 >= 0
by Cauchy-Schwarz), with f' = L - W B / A: lambda is found by Newton's method on f', each step one pass
over the pixels for A, B and C together (`_sums`, compiled), bisection keeping it inside LAMBDA_BOUNDS. On
many pixels Newton starts from the solution on every STRIDE-th pixel, so the passes over all are 3-4, not 7-8.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

LAMBDA_BOUNDS = (-2.0, 8.0)


@njit(cache=True, nogil=True)
def _sums(lz, m2, lam):  # pragma: no cover - compiled
    """A, B, C of the module docstring in one pass, with lz = ln(z / z_ref) for numerical range."""
    a = b = c = 0.0
    for i in range(lz.size):
        t = m2[i] * np.exp(-2.0 * lam * lz[i])
        tl = t * lz[i]
        a += t
        b += tl
        c += tl * lz[i]
    return a, b, c


@njit(cache=True, nogil=True)
def _degrees_of_freedom(z, n, ln_z):  # pragma: no cover - compiled
    """Over the pixels with two or more samples: W = sum (n - 1), sum (n - 1) ln z, pixels, samples, z range; and
    each such pixel's ln z into `ln_z` (0 for the others)."""
    W = s = 0.0
    pixels = samples = 0
    lo, hi = np.inf, -np.inf
    for i in range(z.size):
        if n[i] > 1:
            w = n[i] - 1.0
            ln_z[i] = np.log(z[i])
            W += w
            s += w * ln_z[i]
            pixels += 1
            samples += int(n[i])
            lo = min(lo, z[i])
            hi = max(hi, z[i])
        else:
            ln_z[i] = 0.0
    return W, s, pixels, samples, lo, hi


#: pixels above which lambda is first solved on every STRIDE-th of them, and Newton on all starts there
STRIDE = 64


def _solve_lambda(lz: np.ndarray, m2: np.ndarray, W: float, L: float, start: float = 2.5) -> float:
    """The lambda where f'(lam) = L - W B / A = 0 (module docstring): Newton from `start`, safeguarded by bisection."""
    lo, hi = LAMBDA_BOUNDS
    lam = start
    for _ in range(200):
        a, b, c = _sums(lz, m2, lam)
        g = L - W * b / a
        if g > 0:
            hi = lam
        else:
            lo = lam
        curvature = 2.0 * W * (a * c - b * b) / (a * a)
        step = g / curvature if curvature > 0 else np.inf
        new = lam - step
        if not lo < new < hi:
            new = 0.5 * (lo + hi)
        if abs(new - lam) < 1e-13 * max(1.0, abs(lam)) or hi - lo < 1e-13:
            return float(new)
        lam = new
    return float(lam)


@dataclass(frozen=True)
class PowerLawEstimate:
    """k (m^(1 - lambda)) and lambda with their covariance (order k, lambda), the log-likelihood,
    the degrees of freedom W and the pixels and samples they came from."""

    k: float
    lam: float
    covariance: np.ndarray
    loglik: float
    dof: float
    n_pixels: int
    n_samples: int
    z_range_m: tuple[float, float]
    lam_fixed: bool


def power_law_mle(z_m: np.ndarray, m2_m2: np.ndarray, n: np.ndarray, *, lam: float | None = None) -> PowerLawEstimate:
    """Maximum-likelihood k and lambda (or k alone, with lambda fixed) from per-pixel mean range z_m (m),
    sum of squared deviations m2_m2 (m^2) and sample count n (paper, eqs. k_mle and lambda_mle).

    Pixels whose samples were all equal (M = 0) count with their degrees of freedom, as the
    paper's Gaussian likelihood of the samples has them."""
    z_m = np.ascontiguousarray(z_m, dtype=np.float64)
    n = np.ascontiguousarray(n, dtype=np.float64)
    m2 = np.ascontiguousarray(m2_m2, dtype=np.float64)
    lz = np.empty(len(z_m))
    W, sum_wlz, pixels, samples, z_lo, z_hi = _degrees_of_freedom(z_m, n, lz)
    if pixels == 0:
        raise ValueError("no pixel has two or more samples; nothing to fit")
    # Work with z / z_ref (geometric mean) so exp(-2 lam ln z) stays in range; k is converted back.
    z_ref = float(np.exp(sum_wlz / W))
    # ln(z / z_ref); 0 weight (M = 0, lz = 0) for pixels with fewer than two samples
    np.subtract(lz, np.log(z_ref), out=lz, where=n > 1)
    m2 = np.where(n > 1, m2, 0.0) if pixels < len(n) else m2
    L = 0.0  # sum w ln(z / z_ref) is 0 by the choice of z_ref

    fixed = lam is not None
    if not fixed:
        if z_hi - z_lo < 1e-9 * z_hi:
            raise ValueError("all pixels are at the same range; lambda cannot be estimated (fit with lambda fixed)")
        start = 2.5
        if lz.size >= 4 * STRIDE * 1024:  # a pass over every pixel is an exp each: start close
            lz_s, m2_s = np.ascontiguousarray(lz[::STRIDE]), np.ascontiguousarray(m2[::STRIDE])
            w_s = np.maximum(n[::STRIDE] - 1.0, 0.0)
            if w_s.sum() > 0:
                start = _solve_lambda(lz_s, m2_s, float(w_s.sum()), float(np.dot(w_s, lz_s)))
        lam = _solve_lambda(lz, m2, W, L, start)
    a, b, c = _sums(lz, m2, float(lam))
    k2 = a / W
    k_ref = np.sqrt(k2)  # k for z measured in units of z_ref
    # k_ref (z/z_ref)^lam = k z^lam, so the log-likelihood is the same in either form
    loglik = -0.5 * W * np.log(2 * np.pi) - W * np.log(k_ref) - lam * L - 0.5 * W
    if fixed:
        var_kref = k2 / (2 * W)
        cov = np.array([[var_kref, 0.0], [0.0, 0.0]])
    else:
        info = np.array([[2 * W / k2, 2 * b / k_ref**3], [2 * b / k_ref**3, 2 * c / k2]])
        cov = np.linalg.inv(info)
    # sigma = k_ref (z / z_ref)^lam = k z^lam  =>  k = k_ref z_ref^(-lam)
    k = k_ref * z_ref ** (-lam)
    dk_dkref = z_ref ** (-lam)
    dk_dlam = -k * np.log(z_ref)
    jac = np.array([[dk_dkref, dk_dlam], [0.0, 1.0]])
    cov_k = jac @ cov @ jac.T
    return PowerLawEstimate(float(k), float(lam), cov_k, float(loglik), W, int(pixels), int(samples), (z_lo, z_hi), fixed)
