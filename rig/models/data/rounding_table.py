"""The sample variance of a pixel's rounded samples given their measured mean, exactly, as a table.

In units of the depth unit q: a pixel's n samples are R_i = round(X_i), X_i ~ N(mu, s^2), and
the recording keeps the pixel only if its samples are not all equal (s2 > 0; `ModelData`
drops the others). Relative to the level L nearest the measured mean, the counts' sum
T = sum(R_i - L) = K is what the mean tells (f = K / n), and the sample variance is
s2 = (Q - K^2 / n) / (n - 1) with Q = sum((R_i - L)^2). So what the model must predict is

  E[s2 | T = K, kept] = (E[Q 1{T=K}] - K^2 / n P(T=K)) / ((n - 1) (P(T=K) - P(all equal, T=K)))

averaged over where the true mean mu = L + phi sits, phi uniform (a wall's pixels sit
anywhere between levels). For one phi, with p_k = P(R - L = k) and the generating function
P(z) = sum_k p_k z^k, P(T = K) is the z^K coefficient of P(z)^n and E[Q 1{T=K}] that of
n P2(z) P(z)^(n-1), P2(z) = sum_k k^2 p_k z^k (Q is a sum of n identically distributed terms);
both come from one FFT of the coefficients. P(all equal, T=K) is p_0^n for K = 0, else 0.

`build(s, n)` computes this for K = 0 .. n // 2 (by symmetry that is every f in [-1/2, 1/2]);
`TABLE_FILE` holds it on S_GRID x N_GRID, as what a third level adds to two-level data, by K near a
level and by f beyond (`resample`),
written by `python -m rig.models.data.rounding_table` (about two minutes) and checked against a
fresh computation by tests/test_rounding.py.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.special import ndtr

TABLE_FILE = Path(__file__).with_name("rounding_table.npz")
#: spreads (units of q) the table covers; above S_GRID[-1] the conditioning is below 1e-3 of the variance
S_GRID = np.exp(np.linspace(np.log(0.02), np.log(0.7), 48))
#: sample counts the table holds; other counts are interpolated in 1 / n, counts above the last use its column
N_GRID = np.array([*range(2, 17), 20, 24, 28, 32, 40, 48, 56, 64, 80, 96, 100, 112, 128, 160, 192, 224, 256, 300,
                   320, 384, 448, 512])
#: measured mean offsets |f| (units of q), for K above K_EXACT
F_GRID = np.linspace(0.0, 0.5, 101)
#: counts K = n |f| held exactly (where a third level changes s2 most and fastest, near a level)
K_EXACT = 32
#: resolution of the average over where the true mean sits (units of q)
PHI_STEP = 0.002
#: the most K = 0's subtraction (P(T = 0) less P(all equal)) may amplify the FFT's rounding; beyond it the kept
#: pixels at K = 0 are, but for a fraction under 1 / MAX_CANCELLATION, those with one sample a level up and one a
#: level down, whose s2 is 2 / (n - 1) exactly
MAX_CANCELLATION = 1e6


def build(s: float, n: int) -> np.ndarray:
    """E[s2 | K, kept] (units of q^2) for K = 0 .. n // 2: n rounded samples of N(phi, s^2), phi uniform."""
    spread_of_mean = np.sqrt(s * s + 0.25) / np.sqrt(n)  # at most, of the rounded samples' mean
    half = 0.5 + 6.0 * spread_of_mean  # true means that can give a measured mean within 1/2 of level 0
    g = int(np.ceil(2 * half / PHI_STEP))
    phi = -half + (np.arange(g) + 0.5) * (2 * half / g)
    top = int(np.ceil(half + 6.0 * s)) + 1
    k = np.arange(-top, top + 1)[:, None]
    p = ndtr((k + 0.5 - phi) / s) - ndtr((k - 0.5 - phi) / s)
    p /= p.sum(axis=0)
    size = 1 << int(np.ceil(np.log2(2 * top * n + 1)))
    gen = np.fft.rfft(p, size, axis=0)
    gen_n1 = gen ** (n - 1)
    K = np.arange(0, n // 2 + 1)
    at = K + n * top  # coefficient index of z^K (the polynomial starts at z^(-top n))
    prob = np.fft.irfft(gen_n1 * gen, size, axis=0)[at].sum(axis=1)
    q_sum = n * np.fft.irfft(gen_n1 * np.fft.rfft(p * k**2, size, axis=0), size, axis=0)[at].sum(axis=1)
    with_all_equal = prob[0]
    prob[0] -= float(np.sum(p[top] ** n))  # all samples on level 0: s2 = 0, not kept
    with np.errstate(divide="ignore", invalid="ignore"):
        out = (q_sum / prob - K**2 / n) / (n - 1)
    if not (prob[0] * MAX_CANCELLATION > with_all_equal and np.isfinite(out[0])):
        # K = 0 kept needs one sample each side; when that is rarer than the subtraction's rounding allows, it is
        # one sample a level up and one a level down (s2 = 2 / (n - 1), the least there can be) but for a
        # fraction of about n^2 p(+1) p(-1) / 4 < 1 / MAX_CANCELLATION
        out[0] = 2.0 / (n - 1)
    return out


def two_level(f: np.ndarray) -> np.ndarray:
    """E[s2] (n - 1) / n of two-level data (units of q^2): f (1 - f), exactly, at offset f."""
    return f * (1.0 - f)


def resample(values: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """`build`'s output for n as D = E (n - 1) / n - f (1 - f): (at K = 0 .. K_EXACT, on F_GRID).

    Two-level data have E (n - 1) / n = f (1 - f) exactly, so D is what a third level adds. Near a level
    it falls off with K (roughly as 1 / K), not with f, so the first K_EXACT + 1 counts are kept as they
    are (K = 0 is also special: a pixel on a level is kept only if samples fell on both sides); beyond,
    D is small and smooth in f. Unreachable K (above n / 2) hold NaN."""
    K = np.arange(len(values))
    f = K / n
    d = values * (n - 1) / n - two_level(f)
    small = np.full(K_EXACT + 1, np.nan)
    small[: min(len(d), K_EXACT + 1)] = d[: K_EXACT + 1]
    return small, np.interp(F_GRID, f[1:], d[1:])


def compute_table() -> tuple[np.ndarray, np.ndarray]:
    """D (see `resample`) on S_GRID x N_GRID x (K = 0 .. K_EXACT) and on S_GRID x N_GRID x F_GRID."""
    on_k = np.empty((len(S_GRID), len(N_GRID), K_EXACT + 1))
    on_f = np.empty((len(S_GRID), len(N_GRID), len(F_GRID)))
    for i, s in enumerate(S_GRID):
        for j, n in enumerate(N_GRID):
            on_k[i, j], on_f[i, j] = resample(build(float(s), int(n)), int(n))
    return on_k, on_f


@lru_cache(maxsize=1)
def table() -> tuple[np.ndarray, np.ndarray]:
    """The shipped table (or, if it is missing or was made on other grids, a fresh one: about two minutes)."""
    if TABLE_FILE.exists():
        with np.load(TABLE_FILE) as z:
            if ("on_k" in z and z["on_k"].shape[-1] == K_EXACT + 1 and z["s_grid"].shape == S_GRID.shape
                    and np.allclose(z["s_grid"], S_GRID)
                    and np.array_equal(z["n_grid"], N_GRID) and np.allclose(z["f_grid"], F_GRID)):
                return z["on_k"].astype(float), z["on_f"].astype(float)
    return compute_table()


def write_table(path: Path = TABLE_FILE) -> None:
    on_k, on_f = compute_table()
    np.savez_compressed(path, s_grid=S_GRID, n_grid=N_GRID, f_grid=F_GRID, on_k=on_k, on_f=on_f)


def conditional_variance(s: np.ndarray, f: np.ndarray, n: np.ndarray) -> np.ndarray:
    """E[s2 | measured offset f, kept] in units of q^2, for spread s (units of q, within the table) and n samples.

    D (see `resample`) linear in ln s; at K = n |f| up to K_EXACT (and half the smaller count), taken at that
    K in both neighbouring tabulated counts, beyond it linear in f between F_GRID points; between the two counts linear in 1 / n."""
    on_k, on_f = table()
    s = np.asarray(s, dtype=float)
    n = np.maximum(np.asarray(n, dtype=float), 2.0)
    f = np.clip(np.abs(np.asarray(f, dtype=float)), 0.0, 0.5)
    ls = np.log(np.clip(s, S_GRID[0], S_GRID[-1]))
    x = (ls - np.log(S_GRID[0])) / (np.log(S_GRID[1]) - np.log(S_GRID[0]))
    i = np.clip(x.astype(int), 0, len(S_GRID) - 2)
    wi = x - i
    j = np.clip(np.searchsorted(N_GRID, n, side="right") - 1, 0, len(N_GRID) - 2)
    n_lo, n_hi = N_GRID[j], N_GRID[j + 1]
    wj = np.clip((1.0 / n_lo - 1.0 / np.minimum(n, n_hi)) / (1.0 / n_lo - 1.0 / n_hi), 0.0, 1.0)
    count = np.rint(f * n).astype(int)
    small = count <= np.minimum(K_EXACT, n_lo // 2)  # a K both neighbouring counts can hold
    kk = np.minimum(count, K_EXACT)
    y = f / (F_GRID[1] - F_GRID[0])
    k = np.clip(y.astype(int), 0, len(F_GRID) - 2)
    wk = y - k

    def at(ii: np.ndarray, jj: np.ndarray) -> np.ndarray:
        by_k = np.nan_to_num(on_k[ii, jj, kk])  # NaN (K above n / 2) only where `small` is False
        return np.where(small, by_k, (1 - wk) * on_f[ii, jj, k] + wk * on_f[ii, jj, k + 1])

    d = ((1 - wi) * ((1 - wj) * at(i, j) + wj * at(i, j + 1))
         + wi * ((1 - wj) * at(i + 1, j) + wj * at(i + 1, j + 1)))
    return (d + two_level(f)) * n / (n - 1)


if __name__ == "__main__":
    write_table()
    print(f"wrote {TABLE_FILE}")
