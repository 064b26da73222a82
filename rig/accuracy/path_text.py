"""The bias loop in words and JSON (`rig accuracy`): each step's model, its RMS misfit and its evidence."""

from __future__ import annotations

from typing import Any

from .bias_effects import BIAS_EFFECTS
from .bias_loop import BiasDiagnosis, BiasModelFit

#: how each parameter is shown: its value in a unit a person reads
SHOWN = {"offset_m": (1e3, "mm"), "scale": (1e2, "%"), "disparity_offset_px": (1.0, "px"), "radial_px": (1.0, "px"),
         "warmup_px": (1.0, "px"), "warmup_time_s": (1.0, "s")}


def _value(name: str, fit: BiasModelFit) -> str:
    factor, unit = SHOWN.get(name, (1.0, ""))
    return f"{name} = {factor * fit.values[name]:+.4g} +/- {factor * fit.errors[name]:.2g} {unit}".rstrip()


def _checks(fit: BiasModelFit) -> str:
    return ", ".join(f"{k} chi2 {c:.1f} / {n}, p {p:.1e}" for k, (c, n, p) in fit.checks.items())


def bias_path_lines(dg: BiasDiagnosis) -> list[str]:
    """The path, one line a step, then the final model's parameters and checks."""
    lines = ["The bias path (each step adds the bias effect that lowers BIC most, while it lowers it by more than 10):"]
    for i, step in enumerate(dg.steps):
        how = "start" if i == 0 else f"+ {step.effects[-1].name} (dBIC {step.bic - dg.steps[i - 1].bic:+.1f})"
        # a step the path went on from is beyond noise by the evidence of the effect added next (its checks are
        # within-stop: a bias by range shows only in BIC, the stage's scatter taking the rest)
        state = "beyond noise" if i < len(dg.steps) - 1 or not step.within_noise else "within noise"
        lines.append(f"  {how:<36} {step.name:<40} RMS misfit {step.rms_mm:7.3f} mm  {state}")
    final = dg.final
    lines.append(f"  The path stopped: {dg.stopped}.")
    lines.append(f"Final: {final.name}: " + "; ".join(_value(n, final) for n in final.values))
    lines.append(f"  checks: {_checks(final)}; the stops scatter {1e3 * final.tau_m:.3g} mm (taken as the stage's "
                 f"repeatability), the regions {1e3 * final.kappa_m:.3g} mm (the wall's relief), beyond their pixels")
    if "by range" in final.checks and final.checks["by range"][2] < 1e-3:
        lines.append(f"  by range: the stops scatter {1e3 * final.tau_m:.3g} mm about the model, more than the stage's "
                     f"tolerance ({1e3 * groups_tolerance(dg):.3g} mm): a bias that changes with time (a warm-up"
                     f"{'' if dg.has_clock else '; this recording has no clock, so time cannot be told'}) or a stage "
                     "that is not where it says; record the stops in another order and compare")
    elif not dg.has_clock:
        lines.append("  time: this recording has no clock (a folder import): a bias that changes with time (a warm-up) "
                     "cannot be found")
    for e in final.effects:
        lines.append(f"  {e.name}: {e.physics} ({e.signature})")
    return lines


def groups_tolerance(dg: BiasDiagnosis) -> float:
    return dg.stage_tolerance_m if dg.stage_tolerance_m is not None else float("nan")


def bias_path_json(dg: BiasDiagnosis) -> dict[str, Any]:
    def fit_json(f: BiasModelFit) -> dict[str, Any]:
        return {"model": f.name, "values": f.values, "errors": f.errors, "rms_mm": f.rms_mm, "bic": f.bic,
                "tau_m": f.tau_m, "kappa_m": f.kappa_m, "within_noise": f.within_noise,
                "checks": {k: {"chi2": c, "dof": n, "p_value": p} for k, (c, n, p) in f.checks.items()}}

    return {"steps": [fit_json(s) for s in dg.steps], "added": dg.added, "stopped": dg.stopped,
            "stage_tolerance_m": dg.stage_tolerance_m, "has_clock": dg.has_clock,
            "candidates": [[{"effect": n, "dbic": b} for n, b in step] for step in dg.candidates],
            "effects": {n: {"physics": e.physics, "signature": e.signature,
                            "parameters": [{"name": q.name, "unit": q.unit, "meaning": q.meaning} for q in e.params]}
                        for n, e in BIAS_EFFECTS.items()}}
