"""Where a fitted model fails: measured against predicted sigma by range, radius, brightness and
incidence, an image map, kurtosis by range and fill rate by stop."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models import ModelData, ModelFit, Prediction
from .bins import BinComparison, compare_bins, range_bins


@dataclass
class Residuals:
    """Measured against predicted sigma by range, radius, brightness, incidence, and kurtosis by range."""

    by_range: BinComparison
    by_radius: BinComparison
    by_brightness: BinComparison | None
    by_incidence: BinComparison | None
    image_map: np.ndarray  # ln(measured / predicted sigma) on a coarse grid over the image
    fill_by_stop: list[tuple[str, float, float]]  # (stop, measured fill, predicted fill)


def residuals(fit: ModelFit, d: ModelData) -> Residuals:
    pred = fit.predict(d)
    r_bin, r_labels = range_bins(d.z_m)
    by_range = compare_bins(d, pred, r_bin, d.z_m, r_labels)
    rho = np.sqrt(d.rho2)
    edges = np.linspace(0, rho.max() + 1e-9, 6)
    rq = np.digitize(rho, edges[1:-1])
    by_radius = compare_bins(d, pred, rq, rho, {i: f"rho {edges[i]:.2f}-{edges[i + 1]:.2f}" for i in range(5)})
    by_brightness = None
    if np.isfinite(d.ir).sum() > 100:
        ok = np.isfinite(d.ir)
        q = np.nanquantile(d.ir, np.linspace(0, 1, 7))
        bq = np.where(ok, np.clip(np.digitize(np.nan_to_num(d.ir), q[1:-1]), 0, 5), -1)
        labels = {i: f"IR {q[i]:.0f}-{q[i + 1]:.0f} DN" for i in range(6)}
        sel = bq >= 0
        by_brightness = compare_bins(d.select(sel), _subset(pred, sel), bq[sel], d.ir[sel], labels)
    angle = np.degrees(np.arccos(np.clip(d.cos_inc, -1, 1)))
    by_incidence = None
    if np.ptp(angle) > 1:
        edges = np.linspace(angle.min(), angle.max() + 1e-9, 6)
        ab = np.digitize(angle, edges[1:-1])
        by_incidence = compare_bins(d, pred, ab, angle, {i: f"{edges[i]:.0f}-{edges[i + 1]:.0f} deg" for i in range(5)})
    # image map: ln(measured/predicted) in an 8 x 6 grid of image tiles, all stops pooled
    nx, ny = 8, 6
    tx = np.clip((d.u_px / (d.u_px.max() + 1) * nx).astype(int), 0, nx - 1)
    ty = np.clip((d.v_px / (d.v_px.max() + 1) * ny).astype(int), 0, ny - 1)
    image_map = np.full((ny, nx), np.nan)
    nu = d.nu
    for j in range(ny):
        for i in range(nx):
            m = (tx == i) & (ty == j)
            if m.sum() >= 5:
                image_map[j, i] = 0.5 * np.log((d.s2_m2[m] * nu[m]).sum() / (pred.var_m2[m] * nu[m]).sum())
    fill = []
    for s in np.unique(d.stop):
        m = d.stop == s
        pf = float(np.mean(pred.fill[m])) if pred.fill is not None else 1.0
        fill.append((f"{np.median(d.z_m[m]):.2f} m", float(np.mean(d.fill[m])), pf))
    return Residuals(by_range, by_radius, by_brightness, by_incidence, image_map, fill)


def _subset(pred: Prediction, mask: np.ndarray) -> Prediction:
    return Prediction(pred.shot_m2[mask], pred.illum[mask], pred.image_terms[mask], pred.var_m2[mask],
                      None if pred.k4_m4 is None else pred.k4_m4[mask], None if pred.fill is None else pred.fill[mask])
