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

from .samples import PixelSamples

LAMBDA_BOUNDS = (-2.0, 8.0)


@dataclass
class PowerLawFit:
    """Result of fitting sigma_Z = k * Z^lambda (Z in m, sigma_Z in m, k in m^(1 - lambda))."""

    k: float
    lam: float
    se_k: float
    se_lam: float
    corr: float  # correlation of the k and lambda estimates
    loglik: float
    n_pixels: int
    n_samples: int
    dof: float
    z_min_m: float
    z_max_m: float
    lam_fixed: bool = False

    def sigma_m(self, z_m: np.ndarray | float) -> np.ndarray:
        """Predicted sigma_Z in m at range z_m."""
        return self.k * np.asarray(z_m, dtype=float) ** self.lam

    def report(self, title: str = "power law sigma_Z = k * Z^lambda") -> str:
        lines = [
            f"[[Fit: {title}]]",
            f"    samples: {self.n_samples:,} in {self.n_pixels:,} pixel-stops ({self.dof:,.0f} degrees of freedom)",
            f"    range:   {self.z_min_m:.3f} - {self.z_max_m:.3f} m",
            f"    k      = {self.k:.6g} +/- {self.se_k:.2g} m^(1-lambda)",
            f"    lambda = {self.lam:.4f} +/- {self.se_lam:.4f}" + ("  (fixed)" if self.lam_fixed else ""),
            f"    corr(k, lambda) = {self.corr:+.3f};  log-likelihood = {self.loglik:.6g}",
        ]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, (np.floating, float)) else v) for k, v in vars(self).items()}


def _sums(z: np.ndarray, m2: np.ndarray, lam: float, z_ref: float) -> tuple[float, float, float]:
    """A, B, C of the module docstring, computed with z / z_ref for numerical range."""
    lz = np.log(z / z_ref)
    t = m2 * np.exp(-2.0 * lam * lz)
    return float(t.sum()), float((t * lz).sum()), float((t * lz * lz).sum())


def fit_power_law(samples: PixelSamples, *, lam: float | None = None) -> PowerLawFit:
    """Maximum-likelihood k and lambda (or k alone, with lambda fixed) from pixel samples."""
    w = samples.dof
    ok = w > 0
    z, m2, w = samples.z_m[ok], samples.m2_m2[ok], w[ok]
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
    se_k = float(np.sqrt(cov_k[0, 0]))
    se_lam = float(np.sqrt(cov_k[1, 1]))
    corr = float(cov_k[0, 1] / (se_k * se_lam)) if se_lam > 0 else 0.0
    return PowerLawFit(
        k=float(k), lam=float(lam), se_k=se_k, se_lam=se_lam, corr=corr, loglik=float(loglik),
        n_pixels=int(len(z)), n_samples=int(samples.n[ok].sum()), dof=W,
        z_min_m=float(z.min()), z_max_m=float(z.max()), lam_fixed=fixed,
    )


@dataclass
class BinnedSigma:
    """Measured sigma_Z per range bin (or per stop) with its standard error."""

    z_m: np.ndarray  # degrees-of-freedom-weighted mean range of the bin, m
    sigma_m: np.ndarray  # pooled sigma = sqrt(sum M / sum w), m
    se_sigma_m: np.ndarray  # sigma / sqrt(2 sum w): Cramer-Rao bound under normality
    dof: np.ndarray
    label: list[str]


def pooled_sigma(samples: PixelSamples, groups: np.ndarray, labels: list[str] | None = None) -> BinnedSigma:
    """Pool the variance within each group (e.g. stop index or range bin)."""
    keys = np.unique(groups)
    z, s, se, d, lab = [], [], [], [], []
    for g in keys:
        m = (groups == g) & (samples.dof > 0)
        w = samples.dof[m]
        W = w.sum()
        if W <= 0:
            continue
        sig = np.sqrt(samples.m2_m2[m].sum() / W)
        z.append(float(np.sum(w * samples.z_m[m]) / W))
        s.append(sig)
        se.append(sig / np.sqrt(2 * W))
        d.append(W)
        lab.append(labels[int(g)] if labels is not None else str(g))
    return BinnedSigma(np.array(z), np.array(s), np.array(se), np.array(d), lab)


def sigma_by_range(samples: PixelSamples, width_m: float = 0.25) -> BinnedSigma:
    """Pooled sigma in range windows of `width_m` (the paper's 0.25 m windows)."""
    idx = np.floor(samples.z_m / width_m).astype(np.int64)
    return pooled_sigma(samples, idx)
