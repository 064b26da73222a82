"""Where a fitted model fails: measured against predicted sigma by range, radius, image position, IR
brightness and incidence, kurtosis by range, fill rate by stop and the frame mean over time; and the
verdict on all of them (`rig.diagnosis.consistency`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models import ModelData, ModelFit, Prediction
from .bins import BinComparison, compare_bins, range_bins
from .consistency import Check, Consistency, fill_check, frame_mean_check, kurtosis_check, sigma_check

#: image tiles for the position family (columns, rows)
POSITION_TILES = (8, 6)


@dataclass
class Residuals:
    """Measured against predicted statistics of one fitted model, and the verdict on them."""

    by_range: BinComparison
    by_radius: BinComparison
    by_position: BinComparison | None
    by_brightness: BinComparison | None
    by_incidence: BinComparison | None
    consistency: Consistency

    @property
    def image_map(self) -> np.ndarray:
        """ln(measured / predicted sigma) on the POSITION_TILES grid of the image (all stops pooled); NaN where empty."""
        nx, ny = POSITION_TILES
        out = np.full((ny, nx), np.nan)
        b = self.by_position
        if b is not None:
            for lab, lr in zip(b.labels, b.log_ratio):
                k = int(lab)
                out[k // nx, k % nx] = lr
        return out

    @property
    def fill_by_stop(self) -> list[tuple[str, float, float]]:
        """(stop, measured fill, predicted fill) per stop."""
        c = self.consistency.find("fill rate", "stop")
        return [] if c is None else [(lab, float(m), float(p)) for lab, m, p in zip(c.labels, c.measured, c.predicted)]


def radius_groups(d: ModelData) -> tuple[np.ndarray, dict[int, str]]:
    rho = np.sqrt(d.rho2)
    edges = np.linspace(0, rho.max() + 1e-9, 6)
    return np.digitize(rho, edges[1:-1]), {i: f"rho {edges[i]:.2f}-{edges[i + 1]:.2f}" for i in range(5)}


def position_groups(d: ModelData) -> tuple[np.ndarray, dict[int, str]]:
    """The image in POSITION_TILES tiles (all stops pooled); labels are the tile's index, row-major."""
    nx, ny = POSITION_TILES
    tx = np.clip((d.u_px / (np.nanmax(d.u_px) + 1) * nx).astype(int), 0, nx - 1)
    ty = np.clip((d.v_px / (np.nanmax(d.v_px) + 1) * ny).astype(int), 0, ny - 1)
    g = ty * nx + tx
    return g, {int(k): str(int(k)) for k in np.unique(g)}


def position_label(label: str) -> str:
    nx, _ = POSITION_TILES
    k = int(label)
    return f"image tile column {k % nx + 1} of {nx}, row {k // nx + 1}"


def brightness_groups(d: ModelData) -> tuple[np.ndarray, dict[int, str], np.ndarray] | None:
    """Six quantile bins of the IR brightness, and which pixels have one; None without IR images."""
    ok = np.isfinite(d.ir)
    if ok.sum() <= 100:
        return None
    q = np.nanquantile(d.ir, np.linspace(0, 1, 7))
    bq = np.where(ok, np.clip(np.digitize(np.nan_to_num(d.ir), q[1:-1]), 0, 5), -1)
    return bq, {i: f"IR {q[i]:.0f}-{q[i + 1]:.0f} DN" for i in range(6)}, bq >= 0


def incidence_groups(d: ModelData) -> tuple[np.ndarray, dict[int, str], np.ndarray] | None:
    """Five bins of the incidence angle (deg); None when all rays meet the wall at about one angle."""
    angle = np.degrees(np.arccos(np.clip(d.cos_inc, -1, 1)))
    if np.ptp(angle) <= 1:
        return None
    edges = np.linspace(angle.min(), angle.max() + 1e-9, 6)
    return np.digitize(angle, edges[1:-1]), {i: f"{edges[i]:.0f}-{edges[i + 1]:.0f} deg" for i in range(5)}, angle


def residuals(fit: ModelFit, d: ModelData, pred: Prediction | None = None) -> Residuals:
    """Every comparison of `fit` with the data, and the verdict on them."""
    pred = pred if pred is not None else fit.predict(d)
    r_bin, r_labels = range_bins(d.z_m)
    by_range = compare_bins(d, pred, r_bin, d.z_m, r_labels)
    g, labels = radius_groups(d)
    by_radius = compare_bins(d, pred, g, np.sqrt(d.rho2), labels)
    checks: list[Check] = [sigma_check(by_range, "range"), sigma_check(by_radius, "radius")]
    by_position = None
    if len(d) and np.isfinite(d.u_px).all() and np.isfinite(d.v_px).all():
        g, labels = position_groups(d)
        by_position = compare_bins(d, pred, g, g.astype(float), labels)
        check = sigma_check(by_position, "position")
        check.labels = [position_label(lab) for lab in check.labels]
        checks.append(check)
    by_brightness = None
    bright = brightness_groups(d)
    if bright is not None:
        g, labels, sel = bright
        by_brightness = compare_bins(d.select(sel), _subset(pred, sel), g[sel], d.ir[sel], labels)
        checks.append(sigma_check(by_brightness, "brightness"))
    by_incidence = None
    inc = incidence_groups(d)
    if inc is not None:
        g, labels, angle = inc
        by_incidence = compare_bins(d, pred, g, angle, labels)
        checks.append(sigma_check(by_incidence, "incidence"))
    kurt = kurtosis_check(by_range)
    if kurt is not None:
        checks.append(kurt)
    checks.append(fill_check(d, pred))
    frame_mean = frame_mean_check(d, pred)
    if frame_mean is not None:
        checks.append(frame_mean)
    return Residuals(by_range, by_radius, by_position, by_brightness, by_incidence, Consistency(checks))


def consistency(fit: ModelFit, d: ModelData) -> Consistency:
    """The verdict on every statistic `fit` predicts (see `rig.diagnosis.consistency`)."""
    return residuals(fit, d).consistency


def _subset(pred: Prediction, mask: np.ndarray) -> Prediction:
    def part(x):
        return x[mask] if isinstance(x, np.ndarray) else x

    return Prediction(pred.shot_m2[mask], pred.illum[mask], pred.image_terms[mask], pred.var_m2[mask],
                      part(pred.k4_m4), part(pred.fill), part(pred.common_inv2), part(pred.frame_mean_gain))
