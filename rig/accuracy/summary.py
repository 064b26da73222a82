"""A recording's accuracy in words and in JSON: the stops' figures and the bias model, for `rig fit`."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ..models import ModelData
from .bias import MEANING, UNITS, BiasFit, fit_bias
from .stop_figures import StopAccuracy, stop_accuracy, tilted_stop_accuracy
from .tilted_wall import WallPlane


@dataclass(frozen=True)
class Accuracy:
    """Every stop's figures and the bias fitted to them (None with fewer than two stops of known truth)."""

    stops: tuple[StopAccuracy, ...]
    bias: BiasFit | None
    why_not: str = ""  # why nothing was measured, in words ("" when it was, or when no stop's truth is known)
    walls: tuple[WallPlane, ...] = ()  # the tilted protocol's fitted wall, one per stop (rig.accuracy.tilted_wall)

    @property
    def truth_source(self) -> str:
        """Where the truth came from, in words: one source, or each with its stops' count."""
        sources = [s.truth_source for s in self.stops]
        kinds = sorted(set(sources), key=sources.index)
        return kinds[0] if len(kinds) == 1 else ", ".join(f"{k} ({sources.count(k)} stops)" for k in kinds)


#: the protocols whose wall is perpendicular to the optical axis: Z is the stop's distance at every pixel
FLAT_ON = ("perpendicular", "import")
#: why a tilted stop has no bias model, in words (rig.accuracy.tilted_wall)
TILTED_NO_BIAS = ("not fitted on a tilted wall: a plane of unknown distance and angle absorbs a depth scale and a "
                  "disparity offset (1/Z stays linear in x); measure them on a perpendicular sweep")


def accuracy_of(d: ModelData, var_m2: np.ndarray | None = None, protocol: str = "perpendicular",
                protocol_params: dict[str, Any] | None = None) -> Accuracy:
    """The accuracy of the recording `d` holds (`var_m2`: the noise model's variance of each row, see
    `stop_accuracy`). The tilted protocol's stops are measured against their fitted plane and the plan's
    (`protocol_params`' `tilt_deg`; rig.accuracy.tilted_wall), with no bias model; a protocol whose wall is not known
    is not measured (`why_not` says so)."""
    if protocol == "tilted":
        tilt = (protocol_params or {}).get("tilt_deg")
        tilt = float(tilt) if isinstance(tilt, (int, float)) and not isinstance(tilt, bool) else math.nan
        stops, walls = tilted_stop_accuracy(d, var_m2, tilt)
        return Accuracy(tuple(stops), None, walls=tuple(walls))
    if protocol not in FLAT_ON:
        return Accuracy((), None, f"the {protocol} protocol's wall is not known to face the camera: accuracy is not "
                                  "measured")
    stops = stop_accuracy(d, var_m2)
    return Accuracy(tuple(stops), fit_bias(stops, d.fb_px_m))


def accuracy_lines(a: Accuracy) -> list[str]:
    """The text report's lines (none when no stop's truth is known)."""
    if a.why_not:
        return [f"    accuracy: not measured; {a.why_not}"]
    if not a.stops:
        return []
    worst = max(a.stops, key=lambda s: abs(s.depth_accuracy_pct))
    lines = [f"    accuracy against the {a.truth_source} distance: depth accuracy {worst.depth_accuracy_pct:+.3f} % "
             f"(+/- {worst.depth_accuracy_se_pct:.3f}) at {worst.stop}, the worst of {len(a.stops)} stops; spatial RMS "
             f"{1e3 * worst.spatial_rms_m:.3g} mm there (noise alone {1e3 * worst.spatial_rms_noise_m:.3g} mm)"]
    if a.walls:
        return lines + [wall_line(w) for w in a.walls] + [f"    bias model: {TILTED_NO_BIAS}"]
    b = a.bias
    if b is None:
        return lines + ["    bias model: not fitted (it needs two stops or more whose distance is known)"]
    shown = {"offset_m": lambda v: f"{1e3 * v:+.3f} mm", "scale": lambda v: f"{100 * v:+.4f} %",
             "disparity_offset_px": lambda v: f"{v:+.5f} px"}
    parts = [f"{n} {shown[n](b.values[n])} +/- {shown[n](b.errors[n]).lstrip('+')}" for n in b.names]
    fit = (f"chi2 {b.chi2:.1f} / {b.dof}, p {b.p_value:.1e}" if b.dof > 0 else "no degree of freedom left")
    scatter = (f"; the stops scatter {1e3 * b.tau_m:.3g} mm beyond their pixels' noise (stage repeatability, the "
               "wall), taken into the errors" if not b.within_noise else
               (": within the pixels' noise" if b.dof > 0 else ""))
    return lines + [f"    bias model: {', '.join(parts)} ({fit}{scatter})"]


def wall_line(w: WallPlane) -> str:
    """The fitted wall against the plan's, in one line."""
    planned = (f"plan {w.planned_distance_m:.4f} m, {w.planned_tilt_deg:+.2f} deg" if math.isfinite(w.planned_tilt_deg)
               else f"plan {w.planned_distance_m:.4f} m, tilt not given")
    relief = (f"; the pixels scatter {w.relief_ratio:.2g} times their noise about it (the wall's relief), taken into "
              "the errors" if w.relief_ratio > 1 else "")
    return (f"    wall fitted: {w.distance_m:.5f} m +/- {1e3 * w.distance_se_m:.2g} mm on the optical axis, tilted "
            f"{w.tilt_deg:+.3f} +/- {w.tilt_se_deg:.3f} deg about the vertical and {w.tilt_x_deg:+.3f} +/- "
            f"{w.tilt_x_se_deg:.3f} deg about the horizontal ({planned}){relief}")


def accuracy_words(a: Accuracy) -> str:
    """The accuracy in one line, beside the precision (the demo's)."""
    if a.why_not or not a.stops:
        return f"accuracy: not measured; {a.why_not or 'no stop says where the wall was'}"
    worst = max(a.stops, key=lambda s: abs(s.depth_accuracy_pct))
    line = (f"accuracy against the {a.truth_source} distance: within {abs(worst.depth_accuracy_pct):.3f} % at every "
            f"stop (the worst, {worst.stop})")
    b = a.bias
    if b is None:
        return line
    found = [n for n in ("scale", "disparity_offset_px") if n in b.names and abs(b.values[n]) > 3 * b.errors[n]]
    words = {"scale": lambda: f"scale {100 * b.values['scale']:+.3f} +/- {100 * b.errors['scale']:.3f} %",
             "disparity_offset_px": lambda: (f"disparity offset {b.values['disparity_offset_px']:+.5f} +/- "
                                             f"{b.errors['disparity_offset_px']:.5f} px")}
    if not found:
        return line + "; no calibration bias beyond noise (" + ", ".join(words[n]() for n in words if n in b.names) + ")"
    return line + "; calibration bias: " + ", ".join(words[n]() for n in found) + " (rig export writes the correction)"


def accuracy_json(a: Accuracy) -> dict[str, Any]:
    """The `accuracy` part of rig.result/1 (docs/json.md)."""

    def number(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    b = a.bias
    return {
        "truth_source": a.truth_source if a.stops else None, "why_not": a.why_not or None,
        "stops": [{k: (number(v) if isinstance(v, float) else v) for k, v in asdict(s).items()} for s in a.stops],
        "walls": [{k: (number(v) if isinstance(v, float) else v) for k, v in asdict(w).items()} for w in a.walls],
        "bias": None if b is None else {
            "parameters": [{"name": n, "value": b.values[n], "error": b.errors[n], "unit": UNITS[n],
                            "meaning": MEANING[n]} for n in b.names],
            "covariance": {"parameters": list(b.names), "matrix": np.asarray(b.covariance).tolist()},
            "chi2": b.chi2, "dof": b.dof, "p_value": number(b.p_value), "within_noise": b.within_noise,
            "tau_m": b.tau_m, "fb_px_m": b.fb_px_m},
    }


def bias_export(a: Accuracy) -> dict[str, Any] | None:
    """The `bias` of an exported noise model (docs/noise-model.md, "The depth correction"): the camera's own part of
    the bias model (scale and disparity offset, with their covariance); the wall's offset belongs to the rig and is
    given apart. None where no bias was fitted or it has no disparity offset (fewer than four stops)."""
    b = a.bias
    if b is None or "disparity_offset_px" not in b.names:
        return None
    own = ["scale", "disparity_offset_px"]
    idx = [b.names.index(n) for n in own]
    cov = np.asarray(b.covariance)[np.ix_(idx, idx)]
    truths = [s.truth_m for s in b.stops]
    return {
        "formula": "Z_true = 1 / ((1 + scale) / Z - disparity_offset_px / fb_px_m)",
        "parameters": [{"name": n, "value": b.values[n], "error": b.errors[n], "unit": UNITS[n], "meaning": MEANING[n]}
                       for n in own],
        "covariance": {"parameters": own, "matrix": cov.tolist()},
        "fb_px_m": b.fb_px_m,
        "offset_m": {"value": b.values["offset_m"], "error": b.errors["offset_m"], "meaning": MEANING["offset_m"]},
        "truth_source": a.truth_source, "tau_m": b.tau_m, "within_noise": b.within_noise,
        "valid_z_m": [min(truths), max(truths)],
    }

