"""Each stop's depth against the stage's ground truth: the figures the vendors' test methods define.

Intel's "Camera Depth Testing Methodology" and Orbbec's depth-quality metrics measure a flat target at known
distances: **depth accuracy**, the signed median of measured minus true depth as a % of the distance; **spatial
precision**, the RMS of the depth about a plane fitted to it; **fill rate**, the share of valid depth. Here each
pixel's depth is its mean over the stop's frames with the curvature of Z = f b / d taken out (the mean of f b / d
exceeds f b / mean d by sigma_Z^2 / Z: `curvature_free_m`), and the truth is the stop's distance as the stage
measured it, else as it was commanded, else the plan's (`stop_checks.stop_truth`; `truth_source` says which). A
perpendicular wall's depth (Z, not the range along the ray) is the distance at every pixel.

The stop's mean bias (the bias model's input) is the maximum-likelihood mean: each pixel weighted by its noise's
variance plus the wall's relief, estimated from the pixels' scatter (rig.accuracy.pixel_weights), with its
Cramer-Rao error. Each figure carries the error sampling noise gives it: the median's standard error is
sqrt(pi / 2) times the pixels' robust spread (1.4826 MAD) over sqrt(N); the spatial RMS is compared with what the
pixels' temporal noise adds to it, sqrt(mean(var_i / n_i)), var_i the noise model's variance where given, else the
stop's own power law of its pixels' variance in Z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..models import ModelData
from ..models.data.model_data import stops_of
from .pixel_weights import noise_of_mean, relief_weighted_fit
from .tilted_wall import WallPlane, fit_plane, plane_z_m, planned_z_m, wall_plane

#: sqrt(pi / 2): the standard error of a normal sample's median over that of its mean
MEDIAN_SE_FACTOR = math.sqrt(math.pi / 2)
#: the robust spread: 1.4826 x the median absolute deviation is a normal sample's standard deviation
MAD_TO_SD = 1.4826


@dataclass(frozen=True)
class StopAccuracy:
    """One stop's accuracy figures (see the module docstring)."""

    stop: str
    truth_m: float
    truth_source: str  # "stage measured", "stage commanded", "plan"
    pixels: int
    mean_bias_m: float  # mean of (Z - truth) over the pixels, m
    mean_bias_se_m: float  # its standard error: the pixels' standard deviation over sqrt(N), m
    depth_accuracy_pct: float  # signed median of (Z - truth) / truth, %
    depth_accuracy_se_pct: float
    spatial_rms_m: float  # RMS about the plane fitted to the pixels' depth, m
    spatial_rms_noise_m: float  # what the pixels' temporal noise alone adds to it, m
    fill_rate: float


def curvature_free_m(d: ModelData) -> np.ndarray:
    """Each pixel's mean depth less the curvature of Z = f b / d: E[Z] = Z0 (1 + v / Z0^2) to second order (eq.
    dist_to_disp), so Z0 = Z - v / Z with v the pixel's own sample variance (unbiased for it; m). One vectorised
    pass: `ModelData.z0_m`, which takes v from the neighbours for the noise models' sake, costs a pass over every
    pixel's neighbourhood (0.6 s of a full sweep's `rig fit`)."""
    return np.asarray(d.z_m, dtype=float) - np.asarray(d.s2_m2, dtype=float) / np.asarray(d.z_m, dtype=float)


def stop_accuracy(d: ModelData, var_m2: np.ndarray | None = None) -> list[StopAccuracy]:
    """The figures of every stop of `d` whose truth is known (`var_m2`: the noise model's variance of each row, for
    the pixels' weights and the spatial RMS's noise; the stop's own power law of its pixels' variance when None:
    rig.accuracy.pixel_weights)."""
    table = d.stops
    if table is None or table.truth_m is None:
        return []
    z_all = curvature_free_m(d)
    slices = d.stop_slices()  # rows come stop by stop: slices, not a mask over every row per stop
    by_stop = {int(d.stop[sl.start]): sl for sl in slices} if slices is not None else None
    out = []
    for s in stops_of(d).tolist():
        truth = float(table.truth_m[s])
        rows = np.arange(by_stop[s].start, by_stop[s].stop) if by_stop else np.flatnonzero(d.stop == s)
        z = z_all[rows]
        ok = np.isfinite(z) & (z > 0)
        if not math.isfinite(truth) or truth <= 0 or np.count_nonzero(ok) < 3:
            continue
        rows, z = rows[ok], z[ok]
        v = _noise_of_mean(d, rows, var_m2)
        dev = z - truth
        n = len(dev)
        mean = relief_weighted_fit(dev, v, np.ones((n, 1)))
        median = float(np.median(dev))
        spread = MAD_TO_SD * float(np.median(np.abs(dev - median)))
        plane = _plane_residuals(z, np.asarray(d.u_px[rows], float), np.asarray(d.v_px[rows], float))
        out.append(StopAccuracy(
            stop=table.label[s], truth_m=truth, truth_source=table.truth_source[s], pixels=n,
            mean_bias_m=float(mean.coef[0]), mean_bias_se_m=float(math.sqrt(mean.covariance[0, 0])),
            depth_accuracy_pct=100.0 * median / truth,
            depth_accuracy_se_pct=100.0 * MEDIAN_SE_FACTOR * spread / math.sqrt(n) / truth,
            spatial_rms_m=float(np.sqrt(np.mean(plane**2))), spatial_rms_noise_m=float(np.sqrt(np.mean(v))),
            fill_rate=float(np.mean(d.fill[rows])) if d.fill is not None else math.nan))
    return out


def _noise_of_mean(d: ModelData, rows: np.ndarray, var_m2: np.ndarray | None) -> np.ndarray:
    """The variance of each of the stop's pixels' mean depth (rig.accuracy.pixel_weights.noise_of_mean), m^2."""
    return noise_of_mean(np.asarray(d.z_m, float)[rows], np.asarray(d.s2_m2, float)[rows], np.asarray(d.n)[rows],
                         None if var_m2 is None else np.asarray(var_m2, float)[rows])


def _plane_residuals(z: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """z less the least-squares plane a + b u + c v through it (u, v centred, for a well-conditioned solve)."""
    a = np.column_stack([np.ones_like(z), u - u.mean(), v - v.mean()])
    coef, *_ = np.linalg.lstsq(a, z, rcond=None)
    return z - a @ coef


def tilted_stop_accuracy(d: ModelData, var_m2: np.ndarray | None, planned_tilt_deg: float
                         ) -> tuple[list[StopAccuracy], list[WallPlane]]:
    """The figures of every stop of `d` before a tilted wall (rig.accuracy.tilted_wall): the plane fitted to each
    stop's depth, the depth accuracy against the plan's plane (distance: the stop's truth; tilt: `planned_tilt_deg`,
    its sign from the fit) and the spatial RMS about the fitted plane. Returns the figures and each stop's WallPlane."""
    table = d.stops
    x_all, y_all = d.covariate("x_norm"), d.covariate("y_norm")
    if table is None or table.truth_m is None or x_all is None or y_all is None:
        return [], []
    z_all = curvature_free_m(d)
    figures, planes = [], []
    for s in stops_of(d).tolist():
        truth = float(table.truth_m[s])
        rows = np.flatnonzero(d.stop == s)
        var_mean = _noise_of_mean(d, rows, var_m2)
        z, x, y = z_all[rows], np.asarray(x_all, float)[rows], np.asarray(y_all, float)[rows]
        ok = np.isfinite(z) & (z > 0) & np.isfinite(var_mean) & (var_mean > 0) & np.isfinite(x) & np.isfinite(y)
        if not math.isfinite(truth) or truth <= 0 or np.count_nonzero(ok) < 4:
            continue
        rows, z, x, y, var_mean = rows[ok], z[ok], x[ok], y[ok], var_mean[ok]
        coef, cov, chi2, dof = fit_plane(z, var_mean, x, y)
        plane = wall_plane(coef, cov, chi2, dof, truth, planned_tilt_deg)
        planned = planned_z_m(plane, x)
        dev = z - planned
        n = len(dev)
        rel = dev / planned
        median = float(np.median(rel))
        spread = MAD_TO_SD * float(np.median(np.abs(rel - median)))
        about = z - plane_z_m(coef, x, y)
        figures.append(StopAccuracy(
            stop=table.label[s], truth_m=truth, truth_source=table.truth_source[s], pixels=n,
            mean_bias_m=float(np.mean(dev)), mean_bias_se_m=float(np.std(dev, ddof=1) / math.sqrt(n)),
            depth_accuracy_pct=100.0 * median, depth_accuracy_se_pct=100.0 * MEDIAN_SE_FACTOR * spread / math.sqrt(n),
            spatial_rms_m=float(np.sqrt(np.mean(about**2))), spatial_rms_noise_m=float(np.sqrt(np.mean(var_mean))),
            fill_rate=float(np.mean(d.fill[rows])) if d.fill is not None else math.nan))
        planes.append(plane)
    return figures, planes
