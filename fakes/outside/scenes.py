"""The seven scenes: the base physics (`baseline`) and the base physics plus one physical effect each (`miscalibrated`:
two calibration errors and, optionally, the stage's zero).

Every scene is a function (seed, out_dir, **options) -> Path that writes `out_dir/<scene>-seed<seed>/` (a folder
`rig import` reads) and `out_dir/<scene>-seed<seed>.answer.json` (the physics, its parameters and what it predicts).
Options: frames_per_stop (100), width_px (64), height_px (36), stops_m (0.5..3.0 by 0.25), depth_unit_m (1e-4), and
the scene's own parameter(s), named in its docstring.
"""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable

import numpy as np

from .calibration import Miscalibration
from .dots import DotPattern
from .expectation import population_fit, stop_moments
from .folder import stop_label, write_answer, write_manifest, write_stop
from .sweep import Streams, Sweep, StopMaps, render_stop, stop_maps
from .thermal import ThermalDrift
from .wall import PrintedWall

COMMON_OPTIONS = ("frames_per_stop", "width_px", "height_px", "stops_m", "depth_unit_m")

BASE_PHYSICS = [
    "Projector: a point source at the left imager (the depth origin) of radiant intensity J(theta), 0.36 W over "
    "its 86 x 57 deg field; irradiance on the wall E = J(theta) cos(theta_i) / R^2 = J(theta) Z / R^3.",
    "Wall: Lambertian, radiance L = rho E / pi, rho = 0.8 (white matte).",
    "Imager: camera equation E_img = pi L T RI(phi) / (4 N^2), N = 2, T = 0.8, RI = 1; electrons "
    "S = E_img A_pix t_exp QE lambda / (h c) (3 um pixels, 8.5 ms, QE 0.3 at 850 nm): about 1070 e- on axis at 1 m, "
    "falling as Z^-2.",
    "IR image (Y8): DN = clip(round(255/8000 * (Poisson(S * dot) + N(0, 5^2))), 0, 255); dot = the projected "
    "pattern the pixel sees (log-normal, 25 % spread, fixed to the projector's rays).",
    "Disparity noise (Matthies 1989 as in Huber et al. eq. 7, the gradient made by the dots I' = c S): "
    "sigma_d^2 = 2 (S + r^2) / (n_W c^2 S^2), n_W = 49, c = 0.15, r = 5 e-, S the window's mean electrons of the "
    "two imagers; pure shot noise gives sigma_d ~ Z and sigma_Z ~ Z^3.",
    "Depth: d = f b / Z + delta_d(t) + sigma_d N(0,1) (native px, f = 424 px, b = 50 mm), Z = f b / d, rounded to "
    "0.1 mm counts; 0 where the right imager does not see the wall point (the left invalid band).",
    "Not modelled: ambient light, a disparity noise floor independent of the signal, confidence-based invalidation, "
    "saturated dots degrading the match, temporal filtering.",
]


def _base_sweep(options: dict) -> Sweep:
    sweep = Sweep()
    camera = sweep.camera
    if "width_px" in options or "height_px" in options:
        camera = replace(camera, width_px=int(options.get("width_px", camera.width_px)),
                         height_px=int(options.get("height_px", camera.height_px)))
    sweep = replace(sweep, camera=camera)
    if "frames_per_stop" in options:
        sweep = replace(sweep, frames_per_stop=int(options["frames_per_stop"]))
    if "stops_m" in options:
        sweep = replace(sweep, stops_m=tuple(float(z) for z in options["stops_m"]))
    if "depth_unit_m" in options:
        sweep = replace(sweep, depth_unit_m=float(options["depth_unit_m"]))
    return sweep


def _check_options(scene: str, options: dict, own: tuple[str, ...]) -> None:
    unknown = sorted(set(options) - set(COMMON_OPTIONS) - set(own))
    if unknown:
        raise ValueError(f"scene {scene!r} takes no option {', '.join(unknown)}; it takes "
                         f"{', '.join(COMMON_OPTIONS + own)}")


def _render(name: str, seed: int, out_dir: Path, sweep: Sweep, effect: dict | None, bias: bool = False) -> Path:
    """Writes the scene; with bias, the effect also states the expected bias of each stop's mean depth."""
    out_dir = Path(out_dir)
    folder = out_dir / f"{name}-seed{seed}"
    if folder.exists() and any(folder.iterdir()):
        raise FileExistsError(f"{folder} exists and is not empty; remove it or write to another out_dir")
    folder.mkdir(parents=True, exist_ok=True)
    streams = Streams.from_seed(seed)
    dots = DotPattern(streams.dots, (sweep.camera.height_px, sweep.camera.width_px))
    stops, moments = [], []
    for index, z_m in enumerate(sweep.stops_m):
        maps = stop_maps(sweep, z_m, dots)
        depth, ir = render_stop(sweep, index, maps, streams)
        write_stop(folder, z_m, depth, ir)
        moments.append(stop_moments(_expectation_sweep(sweep), index, maps))
        stops.append(_stop_summary(sweep, maps, depth, ir, moments[-1]))
    if bias:
        effect = {**effect, **_expected_bias(sweep, moments)}
    write_manifest(folder, sweep.camera.intrinsics(),
                   sweep.miscalibration.reported_baseline_m(sweep.camera.baseline_m), sweep.depth_unit_m,
                   sweep.imager.exposure_us, gain=16.0, camera_model=f"fakes.outside {name} (D435-like, simulated)")
    k, lam = population_fit(moments, sweep.frames_per_stop - 1)
    answer = {
        "scene": name,
        "seed": seed,
        "written_without_reading": "rig's effects, fakes, models, simulation or diagnosis",
        "base_physics": BASE_PHYSICS,
        "effect": effect,
        "parameters": _parameters(sweep),
        "stops": stops,
        "expected_fit": {
            "model": "sigma_Z = k Z^lambda, maximum likelihood on every valid pixel's variance (n - 1 dof)",
            "k": k, "lambda": lam,
            "how": "the fit's limit on this scene's exact moments (fakes/outside/expectation.py), no noise drawn",
            "quadrature_reliable": max(m.max_relative_sigma_d for m in moments) < 0.15,
            "max_sigma_d_over_d": max(m.max_relative_sigma_d for m in moments),
        },
        "folder": str(folder),
    }
    write_answer(out_dir / f"{name}-seed{seed}.answer.json", answer)
    return folder


def _expected_bias(sweep: Sweep, moments: list) -> dict:
    """Per stop (mm): the mean over the valid pixels of each pixel's expected depth (its quadrature mean) less the
    stage's reading; the noise-free bias and its first order (calibration.py) beside it."""
    fb, cal = sweep.fb_px_m, sweep.miscalibration
    return {
        "stops_m": list(sweep.stops_m),
        "expected_mean_bias_mm": [1e3 * (float(np.nanmean(m.mean_m)) - z) for m, z in zip(moments, sweep.stops_m)],
        "noise_free_bias_mm": [1e3 * cal.noise_free_bias_m(fb, z) for z in sweep.stops_m],
        "first_order_bias_mm": [1e3 * cal.first_order_bias_m(fb, z) for z in sweep.stops_m],
        "expected_mean_bias_how": "mean over the valid pixels of each pixel's expected reported depth (Gauss-Hermite "
                                  "quadrature of (1 + e) f b / (f b / (Z + w) + delta + sigma_d N(0, 1)), "
                                  "fakes/outside/expectation.py) less the stage's Z; the mean of every valid frame's "
                                  "depth converges to it (rounding to the depth unit adds no bias while sigma_Z > u)",
    }


def _expectation_sweep(sweep: Sweep) -> Sweep:
    """Without drift every frame of a stop has the same distribution: one frame suffices for the moments."""
    return sweep if sweep.drift.amplitude_px else replace(sweep, frames_per_stop=1)


def _stop_summary(sweep: Sweep, maps: StopMaps, depth: np.ndarray, ir: np.ndarray, moments) -> dict:
    valid = maps.valid
    sigma_z_delta = maps.wall_z_m**2 * maps.sigma_d_px / sweep.fb_px_m   # delta method, Huber et al. eq. 9
    return {
        "z_m": maps.z_m, "label": stop_label(maps.z_m),
        "disparity_native_px": maps.disparity_px,
        "signal_e_median": float(np.median(maps.signal_e)), "signal_e_min": float(maps.signal_e.min()),
        "sigma_d_px_median": float(np.median(maps.sigma_d_px)),
        "sigma_z_m_median_delta_method": float(np.median(sigma_z_delta[valid])),
        "sigma_z_m_median_expected": float(np.sqrt(np.nanmedian(moments.var_m2))),
        "valid_fraction": float(valid.mean()),
        "ir_dn_mean": float(ir.mean()), "ir_saturated_fraction": float((ir == sweep.imager.full_scale_dn).mean()),
        "depth_zero_fraction": float((depth == 0).mean()),
    }


def _parameters(sweep: Sweep) -> dict:
    params = {name: asdict(getattr(sweep, name)) for name in ("camera", "projector", "imager", "matcher", "drift",
                                                               "clock")}
    params["wall"] = sweep.wall.describe()
    params["camera"]["native_f_px"] = sweep.camera.native_f_px
    params["camera"]["delivered_intrinsics"] = sweep.camera.intrinsics()
    params["stops_m"] = list(sweep.stops_m)
    params["frames_per_stop"] = sweep.frames_per_stop
    params["depth_unit_m"] = sweep.depth_unit_m
    params["projector"]["peak_intensity_w_sr"] = sweep.projector.peak_intensity_w_sr()
    return params


def baseline(seed: int, out_dir: Path, **options) -> Path:
    """The base physics alone: the control."""
    _check_options("baseline", options, ())
    return _render("baseline", seed, out_dir, _base_sweep(options), None)


def gaussian_spot(seed: int, out_dir: Path, **options) -> Path:
    """The projector's beam is a Gaussian spot, J(theta) = J_peak exp(-theta^2 / 2 w^2), w = beam_width_deg (25),
    the same 0.36 W in total."""
    _check_options("gaussian_spot", options, ("beam_width_deg",))
    w = float(options.pop("beam_width_deg", 25.0))
    sweep = _base_sweep(options)
    sweep = replace(sweep, projector=replace(sweep.projector, beam_width_deg=w))
    return _render("gaussian_spot", seed, out_dir, sweep, {
        "name": "gaussian_spot",
        "physics": "the projector's radiant intensity is a Gaussian in the off-axis angle, not uniform: the wall's "
                   "irradiance, the signal and so sigma_d ~ S^-1/2 vary across the image by the beam, at every range "
                   "alike (the angle of a pixel's wall point from the projector does not depend on Z)",
        "formulas": ["J(theta) = J_peak exp(-theta^2 / (2 w^2))",
                     "J_peak = P / (2 pi int_0^{pi/2} exp(-theta^2/2w^2) sin theta dtheta)",
                     "sigma_d^2 ~ 1/S ~ exp(theta^2 / (2 w^2)) where shot noise dominates"],
        "beam_width_deg": w})


def offcentre_projector(seed: int, out_dir: Path, **options) -> Path:
    """The projector sits projector_offset_m (0.030) beside the left imager, towards the right imager."""
    _check_options("offcentre_projector", options, ("projector_offset_m",))
    x_p = float(options.pop("projector_offset_m", 0.030))
    sweep = _base_sweep(options)
    sweep = replace(sweep, projector=replace(sweep.projector, x_m=x_p))
    return _render("offcentre_projector", seed, out_dir, sweep, {
        "name": "offcentre_projector",
        "physics": "the projector is beside the imager: its axis meets the wall at X = x_p, which the camera sees at "
                   "x_n = x_p / Z, so the illumination's centre and falloff move across the image with range (most "
                   "at the near stops), and the dots slide by f x_p / Z native px",
        "formulas": ["E = J Z / R_p^3, R_p^2 = (x_n Z - x_p)^2 + (y_n Z)^2 + Z^2",
                     "brightest column: x_n = x_p / Z", "dot shift: f x_p / Z native px"],
        "projector_offset_m": x_p})


def ir_vignetting(seed: int, out_dir: Path, **options) -> Path:
    """The IR lens's relative illumination falls as cos^4 of the field angle (natural vignetting)."""
    _check_options("ir_vignetting", options, ())
    sweep = _base_sweep(options)
    sweep = replace(sweep, imager=replace(sweep.imager, cos4_vignetting=True))
    return _render("ir_vignetting", seed, out_dir, sweep, {
        "name": "ir_vignetting",
        "physics": "natural vignetting: the image irradiance falls as cos^4 of the field angle (the cosine-fourth "
                   "law), in both imagers (the right one at its own field angle), so the electrons, the IR image "
                   "and 1/sigma_d^2 fall towards the corners, the same at every range",
        "formulas": ["E_img = pi L T cos^4(phi) / (4 N^2)", "cos(phi) = 1 / sqrt(1 + x_n^2 + y_n^2)",
                     "right imager: x_n - b / Z"]})


def printed_albedo(seed: int, out_dir: Path, **options) -> Path:
    """The wall is printed with blotches of albedo between albedo_low (0.3) and albedo_high (0.9); their layout
    comes from the seed."""
    _check_options("printed_albedo", options, ("albedo_low", "albedo_high"))
    low = float(options.pop("albedo_low", 0.3))
    high = float(options.pop("albedo_high", 0.9))
    sweep = replace(_base_sweep(options), wall=PrintedWall(Streams.from_seed(seed).wall, low=low, high=high))
    return _render("printed_albedo", seed, out_dir, sweep, {
        "name": "printed_albedo",
        "physics": "the wall's reflectance is printed: blotches fixed on the wall (in metres) between dark and light "
                   "ink, so the signal (and sigma_d ~ S^-1/2) varies across the image independently of geometry, "
                   "and the pattern shrinks in the image as 1/Z; the window averages the albedo over its patch of "
                   "wall (7 native px wide)",
        "formulas": ["L = rho(X, Y) E / pi", "rho = mid + half clip(gain g(X, Y), -1, 1)"],
        "albedo_low": low, "albedo_high": high})


def thermal_drift(seed: int, out_dir: Path, **options) -> Path:
    """The disparity drifts as the camera warms: delta_d(t) = A (1 - exp(-t / tau)), A = drift_amplitude_px (0.25
    native px), tau = drift_tau_s (240 s); frames at 30 fps, 5 s between stops, the camera cold at the first frame."""
    _check_options("thermal_drift", options, ("drift_amplitude_px", "drift_tau_s"))
    amplitude = float(options.pop("drift_amplitude_px", 0.25))
    tau = float(options.pop("drift_tau_s", 240.0))
    sweep = replace(_base_sweep(options), drift=ThermalDrift(amplitude_px=amplitude, tau_s=tau))
    return _render("thermal_drift", seed, out_dir, sweep, {
        "name": "thermal_drift",
        "physics": "the camera warms from cold over the run; the imagers' relative yaw follows the temperature and "
                   "shifts every disparity by the same delta_d(t): depths read short by Z^2 delta_d / (f b), more at "
                   "each later stop and drifting within each stop (a slope over the frames, largest at the first)",
        "formulas": ["delta_d(t) = A (1 - exp(-t / tau))",
                     "t = stop_index (n / fps + move_s) + frame / fps",
                     "Z = f b / (f b / Z_true + delta_d(t) + noise)"],
        "drift_amplitude_px": amplitude, "drift_tau_s": tau, "fps": sweep.clock.fps, "move_s": sweep.clock.move_s})


def miscalibrated(seed: int, out_dir: Path, **options) -> Path:
    """The camera is miscalibrated: every disparity is off by disparity_offset_native_px (0.05 native px), its f b is
    (1 + baseline_scale_error) (1.003) times the true one, and the wall sits wall_offset_m (0.0) beyond the stage's
    reading. The manifest carries the camera's own baseline, b (1 + e)."""
    own = ("disparity_offset_native_px", "baseline_scale_error", "wall_offset_m")
    _check_options("miscalibrated", options, own)
    cal = Miscalibration(disparity_offset_px=float(options.pop("disparity_offset_native_px", 0.05)),
                         fb_scale_error=float(options.pop("baseline_scale_error", 0.003)),
                         wall_offset_m=float(options.pop("wall_offset_m", 0.0)))
    sweep = replace(_base_sweep(options), miscalibration=cal)
    if min(sweep.stops_m) + cal.wall_offset_m <= 0:
        raise ValueError(f"wall_offset_m = {cal.wall_offset_m:g} puts the wall behind the camera at the "
                         f"{min(sweep.stops_m):g} m stop; give an offset above {-min(sweep.stops_m):g} m")
    b = sweep.camera.baseline_m
    return _render("miscalibrated", seed, out_dir, sweep, {
        "name": "miscalibrated",
        "physics": "the matcher's disparity is off by a constant delta (a right principal point off by delta px: the "
                   "absolute error Intel's tare calibration adjusts against a flat target at a known distance), and "
                   "the camera divides by an f b (1 + e) times the true one (a baseline off by e; the manifest "
                   "states the camera's baseline b (1 + e)); the wall is w farther "
                   "than the stage's reading says. The mean depth reads w + e Z - Z^2 delta / (f b) off the stage's "
                   "Z to first order, plus the baseline's small curvature of 1/d, + Var(Z) / Z",
        "formulas": ["d = f b / (Z + w) + delta + sigma_d N(0, 1)", "Z_reported = (1 + e) f b / d",
                     "noise-free bias = (1 + e) f b / (f b / (Z + w) + delta) - Z ~ w + e Z - Z^2 delta / (f b)",
                     "1 / Z_reported = (1 / Z_calibrated + delta / (f b)) / (1 + e) frame by frame (w = 0)"],
        "disparity_offset_native_px": cal.disparity_offset_px, "baseline_scale_error": cal.fb_scale_error,
        "wall_offset_m": cal.wall_offset_m, "true_baseline_m": b, "reported_baseline_m": cal.reported_baseline_m(b),
        "native_f_px": sweep.camera.native_f_px}, bias=True)


SCENES: dict[str, Callable[..., Path]] = {
    "baseline": baseline,
    "gaussian_spot": gaussian_spot,
    "offcentre_projector": offcentre_projector,
    "ir_vignetting": ir_vignetting,
    "printed_albedo": printed_albedo,
    "thermal_drift": thermal_drift,
    "miscalibrated": miscalibrated,
}
