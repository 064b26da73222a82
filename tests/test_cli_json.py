"""`--json` of rig fit, fit --model, compare and diagnose: one schema (docs/json-schema.json, checked here with
tests/json_schema.py), always valid JSON (no bare NaN), the same numbers as the text and the Python API."""

import json
from pathlib import Path

import pytest

from json_schema import validate
from rig.analysis import fit_recording
from rig.cli import main
from rig.reports.result_json import dumps
from simrig import record_perpendicular

SCHEMA = json.loads((Path(__file__).resolve().parents[1] / "docs" / "json-schema.json").read_text())


@pytest.fixture(scope="module")
def recordings(tmp_path_factory, small_recording) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("json")
    return {"four": small_recording,
            "one": record_perpendicular(folder / "one.h5", width=32, frames=8, stops_m=[1.0])[0]}


def strict(text: str) -> dict:
    def refuse(name: str):
        raise ValueError(f"bare {name} in the JSON output")

    return json.loads(text, parse_constant=refuse)


def run_json(capsys, *args, status: int = 0) -> dict:
    code = main([*map(str, args), "--json"])
    out = capsys.readouterr().out
    assert code == status, out
    doc = strict(out)
    assert validate(doc, SCHEMA) == [], validate(doc, SCHEMA)
    return doc


def keys(x) -> set[str]:
    if isinstance(x, dict):
        return set(x) | {k for v in x.values() for k in keys(v)}
    return {k for v in x for k in keys(v)} if isinstance(x, list) else set()


def test_fit(recordings, capsys):
    doc = run_json(capsys, "fit", recordings["four"])
    assert doc["command"] == "fit" and doc["file"] == str(recordings["four"]) and doc["diagnosis"] is None
    (fit,) = doc["fits"]
    paper = fit_recording(recordings["four"]).fit
    assert fit["model"] == "power_law" == doc["best"]
    assert fit["values"] == {"k": paper.k, "lambda": paper.lam}
    assert fit["errors"] == {"k": paper.se_k, "lambda": paper.se_lam}
    assert fit["units"] == {"k": "m^(1-lambda)", "lambda": "1"} and fit["n_samples"] == paper.n_samples
    assert fit["lambda_status"]["determined"] and fit["lambda_status"]["n_ranges"] == 4
    assert "lam" not in keys(doc) and "se_lam" not in keys(doc)  # lambda is spelled lambda everywhere
    main(["fit", str(recordings["four"])])
    text = capsys.readouterr().out
    assert f"headline error: {fit['headline']['error_pct']:.2f} % (noise alone: {fit['headline']['noise_pct']:.2f} %; " \
           f"{fit['headline']['verdict']})" in text


@pytest.mark.slow
def test_fit_model_and_compare_share_the_fit_fields(recordings, capsys):
    doc = run_json(capsys, "fit", recordings["four"], "--model", "active")
    (fit,) = doc["fits"]
    assert fit["values"]["lambda"] == 3.0 and fit["fixed"] == ["lambda"] and set(fit["errors"]) == {"k"}
    assert fit["corr_k_lambda"] is None and fit["held_out_nll"] < 0 and fit["likelihood"].startswith("Gamma")
    cmp = run_json(capsys, "compare", recordings["four"], "--models", "active,power_law,active+noise_floor", "--no-held-out")
    assert [f["model"] for f in cmp["fits"]] == ["active", "power_law", "active+noise_floor"]
    assert cmp["best"] == min(cmp["fits"], key=lambda f: f["bic"])["model"]
    # compare fits active as fit --model does, the same code on the same data: the same numbers, not approximately
    assert cmp["fits"][0]["values"] == fit["values"] and cmp["fits"][0]["held_out_nll"] is None
    floor = cmp["fits"][2]
    assert set(floor["values"]) == {"k", "lambda", "noise_floor.sigma_px"} and floor["units"]["noise_floor.sigma_px"] == "px"


@pytest.mark.slow
def test_diagnose(recordings, capsys, tmp_path):
    doc = run_json(capsys, "diagnose", recordings["four"], "--out", tmp_path / "d")
    d = doc["diagnosis"]
    assert doc["fits"][0]["model"] == d["start_model"] == "active" and doc["best"] == d["final_model"]
    assert [f["model"] for f in doc["fits"]][-1] == d["final_model"]
    assert d["power_law"]["model"] == "power_law" and d["power_law"]["lambda_status"]["determined"]
    assert Path(d["report"]["html"]).exists() and all(Path(p).exists() for p in d["report"]["plots"])
    assert {c["name"] for c in d["checks"]} >= {"sigma by range", "fill rate by stop"}


def test_not_determined_is_a_field_with_the_reason(recordings, capsys):
    doc = run_json(capsys, "fit", recordings["one"], status=3)
    fit = doc["fits"][0]
    status, head = fit["lambda_status"], fit["headline"]
    assert status["free"] and not status["determined"] and status["n_ranges"] == 1
    assert "one range" in status["reason"] and "--model active" in status["fix"]
    assert head["within_noise"] is None and head["state"] == "not determined"
    assert "NOT DETERMINED" in head["verdict"] and "within noise" not in head["verdict"]
    window = run_json(capsys, "fit", recordings["four"], "--z-min", "0.9", "--z-max", "1.1", status=3)
    assert window["window_m"] == {"z_min": 0.9, "z_max": 1.1} and not window["fits"][0]["lambda_status"]["determined"]
    fixed = run_json(capsys, "fit", recordings["one"], "--model", "active", "--no-held-out")
    assert fixed["fits"][0]["lambda_status"] == {**fixed["fits"][0]["lambda_status"], "free": False, "determined": True}


def test_numbers_that_are_not_finite_are_null_and_the_checker_can_fail():
    text = dumps({"a": float("nan"), "b": [float("inf"), 1.5], "c": {"d": -float("inf")}})
    assert strict(text) == {"a": None, "b": [None, 1.5], "c": {"d": None}}
    with pytest.raises(ValueError, match="bare NaN"):
        strict('{"a": NaN}')
    bad = {"schema": "rig.result/1", "command": "fit", "rig_version": "x", "file": "f", "notes": [],
           "window_m": {"z_min": None, "z_max": None}, "fits": [{"model": "m"}], "best": None, "diagnosis": None}
    problems = validate(bad, SCHEMA)
    assert "$.fits[0]: lacks 'headline'" in problems and "$.fits[0]: lacks 'values'" in problems
