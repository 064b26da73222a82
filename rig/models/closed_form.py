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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

LAMBDA_BOUNDS = (-2.0, 8.0)


def _sums(z: np.ndarray, m2: np.ndarray, lam: float, z_ref: float) -> tuple[float, float, float]:
    """A, B, C of the module docstring, computed with z / z_ref for numerical range."""
    lz = np.log(z / z_ref)
    t = m2 * np.exp(-2.0 * lam * lz)
    return float(t.sum()), float((t * lz).sum()), float((t * lz * lz).sum())


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
    w = n - 1.0
    ok = w > 0
    z, m2, w = z_m[ok], m2_m2[ok], w[ok]
    if len(z) == 0:
        raise ValueError("no pixel has two or more samples; nothing to fit")
    W = float(w.sum())
    # Work with z / z_ref (geometric mean) so exp(-2 lam ln z) stays in range; k is converted back.
    z_ref = float(np.exp(np.sum(w * np.log(z)) / W))
    lz = np.log(z / z_ref)
    L = float(np.sum(w * lz))

    def neg_profile(lam_: float) -> float:
        a, _, _ = _sums(z, m2, lam_, z_ref)
        return 0.5 * W * np.log(a / W) + lam_ * L

    fixed = lam is not None
    if not fixed:
        if np.ptp(lz) < 1e-9:
            raise ValueError("all pixels are at the same range; lambda cannot be estimated (fit with lambda fixed)")
        res = minimize_scalar(neg_profile, bounds=LAMBDA_BOUNDS, method="bounded", options={"xatol": 1e-10})
        lam = float(res.x)
    a, b, c = _sums(z, m2, lam, z_ref)
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
    return PowerLawEstimate(float(k), float(lam), cov_k, float(loglik), W, int(len(z)), int(n[ok].sum()),
                            (float(z.min()), float(z.max())), fixed)
