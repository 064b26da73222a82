"""The fake camera's per-frame arithmetic, compiled (numba): one pass per image, no temporaries.

Everything that does not change within a stop (the true disparity, its noise, which pixels
match, the IR light) is computed once per stop by `fakes.physics.build_field`; a frame is then
one draw of random numbers and one pass of these kernels.
"""

from __future__ import annotations

import numpy as np
from drivers.compiled import njit

#: the largest value a uint16 depth image holds; 0 means no data
MAX_DEPTH_UNITS = 65535


@njit(cache=True, nogil=True)
def depth_from_noise(noise, sigma_d_px, d_true_px, valid, units_per_px, out):  # pragma: no cover - compiled
    """Depth in units from a standard normal draw: d = d_true + sigma_d * noise (disparity, px), then
    Z = f b / d rounded to the depth unit (eq. dist_to_disp), 0 where the pixel does not match, d <= 0
    or Z falls outside 1..65534 units. All in float32, as the camera's own pipeline."""
    h, w = out.shape
    for r in range(h):
        for c in range(w):
            if not valid[r, c]:
                out[r, c] = 0
                continue
            d = d_true_px[r, c] + sigma_d_px[r, c] * noise[r, c]
            out[r, c] = _to_units(d, units_per_px)


@njit(cache=True, nogil=True)
def depth_from_disparity(d_px, valid, units_per_px, out):  # pragma: no cover - compiled
    """As `depth_from_noise`, from disparities already drawn (and changed by per-frame effects)."""
    h, w = out.shape
    for r in range(h):
        for c in range(w):
            out[r, c] = _to_units(d_px[r, c], units_per_px) if valid[r, c] else 0


@njit(cache=True, nogil=True, inline="always")
def _to_units(d, units_per_px):  # pragma: no cover - compiled
    if not d > 0:
        return 0
    z = np.rint(units_per_px / d)
    if z > 0 and z < MAX_DEPTH_UNITS:
        return np.uint16(z)
    return 0


@njit(cache=True, nogil=True)
def ir_from_uniform(uniform, light_e, noise_e, dn_per_e, max_dn, out):  # pragma: no cover - compiled
    """IR digital numbers: light_e photo-electrons plus shot noise of standard deviation noise_e (e), drawn
    uniform with that variance (u in [0, 1) -> (u - 1/2) sqrt(12)), times dn_per_e, rounded and clipped to
    0..max_dn. Only the stop's mean IR image and its scatter are used, not the noise's shape."""
    root12 = np.float32(np.sqrt(12.0))
    h, w = out.shape
    for r in range(h):
        for c in range(w):
            e = light_e[r, c] + noise_e[r, c] * (uniform[r, c] - np.float32(0.5)) * root12
            dn = np.rint(e * dn_per_e)
            out[r, c] = 0 if dn < 0 else (max_dn if dn > max_dn else np.uint16(dn))


@njit(cache=True, nogil=True)
def temporal_filter(depth, state, alpha):  # pragma: no cover - compiled
    """A temporal post-filter, as RealSense's and OAK-D's: out_t = alpha in_t + (1 - alpha) out_{t-1} on pixels valid in
    this frame and the last (exponential smoothing), in depth units; the filter's memory `state` (float32, 0 = none)
    is updated and `depth` rewritten in place, rounded. A pixel missing in this frame stays missing and is forgotten."""
    h, w = depth.shape
    for r in range(h):
        for c in range(w):
            d = depth[r, c]
            if d == 0:
                state[r, c] = 0
                continue
            s = state[r, c]
            v = np.float32(d) if s == 0 else np.float32(alpha) * np.float32(d) + np.float32(1 - alpha) * s
            state[r, c] = v
            depth[r, c] = np.uint16(np.rint(v))
