"""The `--json` document of `rig compare a.h5 b.h5 ...` and `rig repeatability`: `rig.comparison/2`.

The schema is docs/comparison.schema.json (explained in docs/json.md). Version 2 because the shape changed from 1:
`differences` became one object per pair (its set-up differences first, then its parameters, each a named field),
and `rig_version`, each fit's `setup` and the document's `setup_differences` were added.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from .. import package_version
from ..recordings.camera_setup import SetupDifference, setup_differences
from ..recordings.comparison import Difference, Pair, Scatter, repeatability_verdict
from ..recordings.recording_fits import RecordingResult
from ..recordings.setup_effects import k_ratio, rounding

SCHEMA = "rig.comparison/2"
FIT_FIELDS = ("path", "model", "projector_on", "values", "errors", "free", "units", "n_obs", "headline_pct",
              "noise_pct", "verdict", "notes", "error", "setup")


def fit_json(r: RecordingResult) -> dict:
    return {k: getattr(r, k) for k in FIT_FIELDS}


def setup_json(d: SetupDifference, results: list[RecordingResult]) -> dict:
    """One set-up difference over `results` (the recordings it was found in, in order), with what physics expects of
    it where it says exactly (`rig.recordings.setup_effects`): rounding's variance for the depth unit, k's scale
    for the baseline and fx."""
    expected = None
    if d.item.key == "depth_unit_m":
        rs = [rounding(r) for r in results]
        expected = {"rounding_sigma_m": [x.sigma_q_m if x else None for x in rs],
                    "rounding_share": [x.share if x else None for x in rs],
                    "rounding_z_m": [x.z_m if x else None for x in rs],
                    "rounding_visible": [x.visible if x else None for x in rs]}
    elif d.item.key in ("baseline_m", "fx_px"):
        expected = {"k_relative": [k_ratio(r.setup, results[0].setup)[0] for r in results]}
    return {"item": d.item.key, "label": d.item.label, "values": list(d.values), "effect": d.item.effect,
            "expected": expected}


def difference_json(d: Difference) -> dict:
    return {"parameter": d.parameter, "value_a": d.value_a, "value_b": d.value_b, "z": d.z, "p": d.p,
            "significant": d.significant, "expected_ratio": d.ratio, "z_scaled": d.z_scaled,
            "differs": d.differs if d.significant is not None else None, "causes": d.causes, "sentence": d.sentence()}


def pair_json(p: Pair) -> dict:
    return {"a": p.a.path, "b": p.b.path, "setup_differences": [setup_json(d, [p.a, p.b]) for d in p.setup],
            "judged": p.judged, "not_judged": p.not_judged(), "parameters": [difference_json(d) for d in p.parameters],
            "verdict": p.verdict()}


def _document(command: str, results: list[RecordingResult], plots: list[Path], page: Path | None) -> dict:
    fitted = [r for r in results if not r.error]
    return {"schema": SCHEMA, "command": command, "rig_version": package_version(),
            "fits": [fit_json(r) for r in results],
            "setup_differences": [setup_json(d, fitted) for d in setup_differences([r.setup for r in fitted])],
            "plots": [str(p) for p in plots], "report": str(page) if page else None}


def compare_document(results: list[RecordingResult], pairs: list[Pair], plots: list[Path], page: Path | None) -> dict:
    """rig compare: every fit, the set-up differences over all of them, and each pair."""
    return _document("compare", results, plots, page) | {"differences": [pair_json(p) for p in pairs],
                                                         "verdicts": [p.verdict() for p in pairs]}


def repeatability_document(results: list[RecordingResult], scatters: list[Scatter], plots: list[Path],
                           page: Path | None) -> dict:
    """rig repeatability: every run's fit, the set-up differences over them, each parameter's scatter."""
    return _document("repeatability", results, plots, page) | {
        "scatter": [asdict(s) | {"honest": s.honest, "sentence": s.sentence()} for s in scatters],
        "verdicts": [repeatability_verdict(scatters, results)]}
