"""What a difference in the set-up does to the range noise, where physics says it exactly: the geometry scales k,
and rounding to the depth unit adds variance.

Geometry: sigma_Z = Z^2 sigma_d / (f b) (the paper's eq. error_prop; sigma_d the disparity noise in px), so with the
same sensor and resolution (the same sigma_d) k_a / k_b = (f_b b_b) / (f_a b_a).

Rounding: a range stored in whole depth units q has q^2/12 more variance than the range where the noise is well above
q (Sheppard's correction; up to q^2/4 and down to 0 below it, `rig.models.data.rounding`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .recording_fits import RecordingResult


def k_ratio(a: dict[str, Any], b: dict[str, Any]) -> tuple[float, list[str]]:
    """(k_a / k_b as the geometry predicts it, the items that make it differ from 1: "baseline_m", "fx_px"), or
    (nan, []) where it predicts nothing: another resolution (sigma_d in px changes too), or f or b not recorded."""
    keys = ("baseline_m", "fx_px", "width_px", "height_px")
    if any(not isinstance(s.get(k), (int, float)) for s in (a, b) for k in keys):
        return math.nan, []
    if (a["width_px"], a["height_px"]) != (b["width_px"], b["height_px"]):
        return math.nan, []
    moved = [k for k in ("baseline_m", "fx_px") if not math.isclose(a[k], b[k], rel_tol=1e-9)]
    return (b["fx_px"] * b["baseline_m"]) / (a["fx_px"] * a["baseline_m"]), moved


@dataclass(frozen=True)
class Rounding:
    """What rounding to the depth unit q adds to one recording's measured variance."""

    q_m: float
    z_m: float  # the stop where q^2/12 is the largest share of the measured variance (the nearest, sigma growing)
    share: float  # (q^2/12) / sigma^2 there
    visible: bool  # q^2/12 above twice the standard error of the measured variance at some stop

    @property
    def sigma_q_m(self) -> float:
        """q / sqrt(12): the standard deviation of a rounding error uniform over one depth unit."""
        return self.q_m / math.sqrt(12.0)


def rounding(result: RecordingResult) -> Rounding | None:
    """Rounding's share of the recording's measured variance per stop (`result.sigma_m`, its errors `se_sigma_m`); None
    without a depth unit or a measured sigma."""
    q = result.setup.get("depth_unit_m")
    sigma = np.asarray(result.sigma_m, dtype=float)
    if not isinstance(q, (int, float)) or not sigma.size:
        return None
    added = q * q / 12.0
    share = added / sigma**2
    se_var = 2.0 * sigma * np.asarray(result.se_sigma_m, dtype=float)  # delta method: d(sigma^2) = 2 sigma d(sigma)
    i = int(np.nanargmax(share))
    return Rounding(float(q), float(result.z_m[i]), float(share[i]), bool(np.any(added > 2.0 * se_var)))


def models_rounding(model: str) -> bool:
    """The model has the quantization effect (rounding to the recording's own depth unit)."""
    return any(part.split("(")[0].strip() == "quantization" for part in model.split("+"))
