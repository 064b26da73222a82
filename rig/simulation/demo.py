"""`rig demo`: the whole loop on the simulated rig, in about a minute.

Two perpendicular experiments (projector on, projector off) with the fake camera on the fake
stage, 0.5-3.0 m in 0.25 m steps, recorded, fitted with the paper's model and plotted.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from drivers.camera import CameraSettings
from protocols import Runner, perpendicular
from protocols.recording import utc_now

from .. import package_version
from ..accuracy import accuracy_of, accuracy_words

from ..analysis import fit_recording
from ..devices import open_devices
from ..diagnosis import diagnose
from ..models import ModelData
from ..reports.diagnosis_html import write_html
from ..reports.diagnosis_plots import write_plots
from ..reports.progress import TerminalProgress
from ..reports.run_info import run_info
from ..reports.sigma_plot import SigmaSeries, plot_sigma_vs_range
from ..reports.tables import fit_table
from ..reports.work_progress import WorkProgressLine

MODES = (("active", True, "tab:red"), ("passive", False, "tab:blue"))


def run_demo(out_dir: Path, *, frames: int = 300, width: int = 424, seed: int = 1, depth_unit_mm: float = 0.1,
             verbosity: int = 0) -> int:
    """`verbosity`: of the diagnosis's progress line on stderr (rig.reports.work_progress; -1 silences it)."""
    t0 = time.monotonic()
    out_dir.mkdir(parents=True, exist_ok=True)
    height = round(width * 480 / 848)
    print("rig demo: a simulated RealSense-D435-like camera on a simulated linear stage, facing a wall.")
    print(f"  11 stops from 0.5 to 3.0 m, {frames} frames each, projector on (active) and off (passive).")
    if width < 848:
        print(f"  Image {width}x{height} px (binned from 848x480 to keep the demo short; same noise per sample,"
              " fewer samples). Use --full-resolution for 848x480.")
    print(f"  Depth unit {depth_unit_mm:g} mm (RealSense allows setting it; at 1 mm rounding would dominate "
          "the noise at 0.5 m).\n")
    rows, series, truths, accuracies = [], [], [], []
    for i, (mode, projector_on, color) in enumerate(MODES):
        path = out_dir / f"perpendicular-{mode}.h5"
        if path.exists():
            path.unlink()  # the demo's own output from an earlier run
        devices = open_devices(f"fake:width={width},height={height},depth_unit_mm={depth_unit_mm},seed={seed + i}", "fake:")
        plan = perpendicular(frames_per_stop=frames, projector_on=projector_on)
        print(f"Recording the {mode} experiment (projector {'on' if projector_on else 'off'}) -> {path}")
        Runner(devices.camera, devices.stage, progress=TerminalProgress(sys.stdout, "  "), sleep=devices.sleep).run(plan, path)
        settings = CameraSettings(projector_on=projector_on, exposure_us=plan.params["exposure_us"], gain=plan.params["gain"])
        truths.append((mode, *devices.camera.base_truth(settings)))
        r = fit_recording(path)
        accuracies.append(accuracy_of(r.samples))
        rows.append((f"perpendicular {mode}", r.fit))
        series.append(SigmaSeries(f"{mode} (projector {'on' if projector_on else 'off'})", r.measured, r.fit, color))
        print()
    print("Maximum-likelihood fit of sigma_Z = k * Z^lambda on every valid pixel of every frame:\n")
    print(fit_table(rows))
    print()
    q_m = depth_unit_mm / 1000.0
    for (mode, k, lam), (_, f), s, a in zip(truths, rows, series, accuracies):
        z = (f.lam - lam) / f.se_lam
        print(f"  {mode}: the simulation's shot-noise physics has lambda = {lam:g}, k = {k:.5g}; "
              f"fitted lambda = {f.lam:.4f} ({z:+.1f} standard errors from it)")
        if abs(z) > 3:
            share = q_m**2 / 12 / s.measured.sigma_m[0] ** 2
            print(f"    With {f.n_samples / 1e6:.0f} M samples the fit resolves what the paper's model leaves out: depth is"
                  f" rounded to the {depth_unit_mm:g} mm unit, adding q^2/12 = {100 * share:.1f} % to the variance at"
                  f" {s.measured.z_m[0]:.2f} m, which flattens the curve.")
        print(f"    {accuracy_words(a)}")
    plot = plot_sigma_vs_range(series, out_dir / "sigma-vs-range.png",
                               title="Simulated D435: range error, projector on and off")
    loop_files = _diagnosis_loop(out_dir, seed=seed, verbosity=verbosity)
    print(f"\nFiles (in {out_dir.resolve()}):")
    for mode, _, _ in MODES:
        print(f"  recording: {out_dir / f'perpendicular-{mode}.h5'}")
    print(f"  plot:      {plot}")
    for label, path in loop_files:
        print(f"  {label:<10} {path}")
    print(f"\nDone in {time.monotonic() - t0:.0f} s. Open {out_dir / 'diagnosis' / 'diagnosis.html'} in a browser.")
    print(f"Next (after `source .venv/bin/activate`): rig diagnose {out_dir / 'perpendicular-active-unknown.h5'}, "
          "rig simulate --seed 7 mystery.h5, rig tui")
    return 0


#: the demo's "real" camera: shot noise plus a disparity noise floor at the level that gives the
#: paper's active lambda of about 2.5 (see docs/paper-windows.md), in native px
DEMO_NOISE_FLOOR_PX = 0.06


def record_unknown(path: Path, *, seed: int, progress=None) -> Path:
    """The loop's recording: 106x60 px, 11 stops of 100 frames, projector on, a 0.05 mm depth unit, and the
    camera's noise floor (`DEMO_NOISE_FLOOR_PX`) that the paper's model lacks; the fake camera's seed is seed + 7."""
    devices = open_devices(f"fake:width=106,height=60,depth_unit_mm=0.05,seed={seed + 7},"
                           f"effects=noise_floor(sigma_px={DEMO_NOISE_FLOOR_PX})", "fake:")
    Runner(devices.camera, devices.stage, progress=progress, sleep=devices.sleep).run(
        perpendicular(frames_per_stop=100, projector_on=True, ambient_frames=3), path)
    return path


def _diagnosis_loop(out_dir: Path, *, seed: int, verbosity: int = 0) -> list[tuple[str, Path]]:
    """Record a camera with a noise floor, diagnose it blind, add the effect it names, show the error fall."""
    print("\nThe loop: a camera whose noise has something the paper's model leaves out.")
    print("  Simulated like the paper's R200 runs (106x60 px, 100 frames a stop, projector on); rig is not told what.")
    path = out_dir / "perpendicular-active-unknown.h5"
    if path.exists():
        path.unlink()
    record_unknown(path, seed=seed, progress=TerminalProgress(sys.stdout, "  "))
    with WorkProgressLine("rig demo: diagnosing", verbosity) as progress:
        diag = diagnose(ModelData.from_recording(path), source=str(path), second_round=False, progress=progress)
    pl = diag.power_law_fit
    print(f"  The paper's power law fits lambda = {pl.values['lambda']:.3f} +/- {pl.errors['lambda']:.1g} "
          "(the paper measured 2.4-2.6 and blamed the noise floor).")
    print(f"  Model {diag.model_fit.model.name}: headline error {diag.model_headline}")
    print(f"  Diagnosis: {diag.summary()}")
    if diag.best is not None:
        print(f"  Refit with {diag.best.fit.model.name}: headline error {diag.refit_headline}")
        for name, p in diag.best.fit.model.free():
            if name not in ("k", "lambda"):
                print(f"    {name} = {diag.best.fit.values[name]:.4g} +/- {diag.best.fit.errors[name]:.2g} {p.unit} "
                      f"(simulated: {DEMO_NOISE_FLOOR_PX * 106 / 848:.4g} px at this image width)")
    report_dir = out_dir / "diagnosis"
    plots = write_plots(diag, report_dir)
    page = write_html(diag, plots, report_dir, run_info(path, utc_now(), package_version()))
    return [("recording:", path), ("report:", page)] + [("plot:", p) for p in plots]
