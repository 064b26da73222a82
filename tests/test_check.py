"""`rig check REC --spec spec.toml` (issue 51, item 3): a spec's lines passed, failed or not decided with the
measurement's own error, for one recording or a fleet, with CI's exit status and rig.check/1 JSON.

The verdicts are checked against figures this file computes from the recordings' raw per-stop statistics with h5py
(each stop's `count`, `m2_m2` and `n_frames`, docs/data-format.md), not with rig's functions; the fill also against
the frames' own `valid_fraction` series, which the recorder writes frame by frame on another path; the sigma's
error propagation against draws from the fit's covariance; the JSON against docs/check.schema.json with jsonschema,
the reference validator.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import h5py
import jsonschema
import numpy as np
import pytest

from cli_in_process import rig_in_process
from rig.check import RecordingFigures, read_spec
from rig.check.figures import StopFigures, sigma_at
from rig.check.verdicts import evaluate

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = json.loads((ROOT / "docs" / "check.schema.json").read_text())
CAMERA = "fake:width=16,height=12,depth_unit_mm=0.1"
#: the fake's matcher drops samples whose disparity error passes 0.12 px: the fill falls with range
HOLES = "censoring(threshold_px=0.12)"
U = np.finfo(np.float64).eps / 2


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    folder = tmp_path_factory.mktemp("check")
    out = {}
    for name, seed, effects in (("clean", 1, ""), ("holes", 2, f",effects={HOLES}")):
        out[name] = folder / f"{name}.h5"
        r = rig_in_process("run", "--protocol", "perpendicular", "--stops", "0.5:3.0:0.5", "--stage", "fake:",
                           "--camera", f"{CAMERA},seed={seed}{effects}", "--frames", 20, "-o", out[name], "-q")
        assert r.returncode == 0, r.stderr
    return out


def check(tmp_path, spec: str, *recordings, json_out: bool = True):
    path = tmp_path / "spec.toml"
    path.write_text(spec)
    r = rig_in_process("check", *recordings, "--spec", path, "--jobs", 1, *(["--json"] if json_out else []))
    return r, (json.loads(r.stdout) if json_out and r.stdout else None)


def raw_stops(path: Path) -> dict[str, dict]:
    """Each stop's fill and pooled sigma from the file's datasets, by this file's own lines."""
    out = {}
    with h5py.File(path) as f:
        for label, g in f["stops"].items():
            count, m2, frames = g["count"][()].astype(float), g["m2_m2"][()], float(g.attrs["n_frames"])
            share = count.ravel() / frames
            used = count >= 2
            dof = float(np.sum(count[used] - 1))
            sigma = math.sqrt(float(np.sum(m2[used])) / dof)
            out[label] = {
                "fill": float(np.mean(share)),
                # each pixel's frames independent trials, and at least one sample in the stop's frames
                "fill_se": max(math.sqrt(float(np.sum(share * (1 - share))) / frames) / share.size,
                               1 / (frames * share.size)),
                "valid_fraction": float(np.mean(g["frames/valid_fraction"][()])),
                "z_m": float(g.attrs["measured_position_m"]),
                "sigma_m": sigma, "sigma_se_m": sigma / math.sqrt(2 * dof),  # chi^2 with dof degrees of freedom
            }
    return out


def own_verdict(margins: list[float]) -> str:
    """The documented rule: past 2 standard errors on either side decides; a line takes its worst stop."""
    each = ["fail" if m < -2 else "pass" if m > 2 else "not decided" for m in margins]
    return "fail" if "fail" in each else "not decided" if "not decided" in each else "pass"


def test_fill_verdicts_follow_the_stops_raw_counts(recordings, tmp_path):
    raw = raw_stops(recordings["holes"])
    near = [s for s in raw.values() if s["z_m"] <= 2.0 * 1.01]
    worst = min(near, key=lambda s: s["fill"])
    assert worst["fill"] < 0.95 and all(s["fill"] == 1.0 for s in raw.values() if s["z_m"] < 0.75)  # holes far only
    for s in raw.values():  # the recorder's per-frame shares agree (float32 shares averaged: 1e-6)
        assert s["valid_fraction"] == pytest.approx(s["fill"], abs=1e-6)
    limits = [100 * (worst["fill"] + k * worst["fill_se"]) for k in (-3.0, -1.5, 0.0, 1.5, 3.0)]
    spec = "".join(f"[[fill]]\nfill_pct_min = {x!r}\nto_z_m = 2.0\n" for x in limits)
    r, doc = check(tmp_path, spec, recordings["holes"])
    lines = doc["recordings"][0]["lines"]
    got = [line["verdict"] for line in lines]
    expected = [own_verdict([(100 * s["fill"] - x) / (100 * s["fill_se"]) for s in near]) for x in limits]
    assert got == expected == ["pass", "not decided", "not decided", "not decided", "fail"], (got, expected)
    assert r.returncode == 1  # a line fails
    for item in lines[0]["items"]:  # a mean of 192 shares in another order: within 192 u (and the root's 2 u)
        s = next(s for s in near if abs(s["z_m"] - item["z_m"]) < 1e-9)
        assert item["value"] == pytest.approx(100 * s["fill"], rel=200 * U, abs=0)
        assert item["se"] == pytest.approx(100 * s["fill_se"], rel=200 * U, abs=0)


def test_sigma_at_a_stop_is_judged_with_the_stops_own_pooled_sigma(recordings, tmp_path):
    raw = raw_stops(recordings["clean"])["2.000m"]
    own, own_se = 100 * raw["sigma_m"] / 2.0, 100 * raw["sigma_se_m"] / 2.0  # % of Z
    spec = "".join(f"[[sigma]]\nat_z_m = 2.0\nsigma_pct_of_z_max = {x!r}\n" for x in (own * 1.25, own, own * 0.75))
    r, doc = check(tmp_path, spec, recordings["clean"])
    lines = doc["recordings"][0]["lines"]
    fit, stop = lines[0]["items"]
    # the stop's figure is the pooled sigma of the same pixels, summed in another order: within 200 u
    assert stop["value"] == pytest.approx(own, rel=200 * U, abs=0) and stop["se"] == pytest.approx(own_se, rel=200 * U)
    # the fit of all six stops agrees with this stop's own sigma within their joint error
    assert abs(fit["value"] - own) < 3 * math.hypot(fit["se"], own_se), (fit, own, own_se)
    # so a limit 25 % from this stop's sigma lies past 2 s.e. of both figures; a limit on it, within them
    assert 0.25 * own > 3 * math.hypot(fit["se"], own_se) + 2 * max(fit["se"], own_se)
    assert [line["verdict"] for line in lines] == ["pass", "not decided", "fail"]
    assert r.returncode == 1


def test_a_fleet_is_summarised_per_recording_and_per_line_with_its_exit_status(recordings, tmp_path):
    spec = ("name = \"bench\"\n[[sigma]]\nat_z_m = 2.0\nsigma_pct_of_z_max = 2.0\n"
            "[[fill]]\nfill_pct_min = 99\nto_z_m = 3.0\n[[accuracy]]\ndepth_accuracy_pct_max = 0.5\n")
    r, doc = check(tmp_path, spec, recordings["clean"], recordings["holes"])
    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    jsonschema.validate(doc, SCHEMA)
    assert [v["verdict"] for v in doc["recordings"]] == ["pass", "fail"] and r.returncode == 1
    assert doc["summary"]["recordings"] == {"pass": 1, "fail": 1, "not_decided": 0, "error": 0}
    assert [(x["pass"], x["fail"]) for x in doc["summary"]["lines"]] == [(2, 0), (1, 1), (2, 0)]
    text, _ = check(tmp_path, spec, recordings["clean"], recordings["holes"], json_out=False)
    assert "fleet: 2 recordings; 1 pass every line, 1 fail" in text.stdout and text.returncode == 1
    # a range the fit does not reach is not extrapolated: not decided, exit 3; the passing lines alone, exit 0
    r, doc = check(tmp_path, "[[sigma]]\nat_z_m = 4.0\nsigma_mm_max = 500\n", recordings["clean"])
    assert r.returncode == 3 and "outside the fitted ranges" in doc["recordings"][0]["lines"][0]["reason"]
    r, _ = check(tmp_path, "[fill]\nfill_pct_min = 99\n[accuracy]\ndepth_accuracy_pct_max = 0.5\n", recordings["clean"])
    assert r.returncode == 0


@pytest.mark.parametrize("spec, words", [
    ("[[sigma]]\nat_z_m = 2.0\nsigma_pct_of_z_max =\n", "not valid TOML (Invalid value (at line 3"),
    ("[[sigma]]\nat_z_m = 2000\nsigma_pct_of_z_max = 2\n", "looks like millimetres: at_z_m = 2"),
    ("[[fill]]\nfill_pct_min = 0.99\n", "write fill_pct_min = 99"),
    ("[[fill]]\nfill_min = 99\n", "unknown key 'fill_min'; its keys are fill_pct_min"),
    ("[[noise]]\nx = 1\n", "unknown table [noise]"),
    ("[[sigma]]\nsigma_pct_of_z_max = 2\n", "needs at_z_m"),
    ("[[accuracy]]\ndepth_accuracy_pct_max = \"0.5\"\n", "is not a number"),
    ("name = \"empty\"\n", "holds no line"),
])
def test_a_malformed_spec_is_one_line_naming_it_and_the_fix(tmp_path, spec, words):
    r, _ = check(tmp_path, spec, tmp_path / "never-read.h5", json_out=False)
    assert r.returncode == 2 and r.stdout == "" and r.stderr.count("\n") == 1, r.stderr
    assert words in r.stderr and "spec.toml" in r.stderr, r.stderr


def figures(**kw) -> RecordingFigures:
    stops = [StopFigures(f"{z:.3f}m", z, 1.0, 0.001, -0.3 * z, 0.02) for z in (1.0, 2.0, 3.0)]
    return RecordingFigures("r.h5", k=0.002, lam=2.5, covariance=[[4e-12, -5e-9], [-5e-9, 2e-5]],
                            z_range_m=(1.0, 3.0), stops=stops, **kw)


def test_the_sigma_error_is_the_fits_covariance_carried_to_the_range():
    """Draws of (k, lambda) from the fit's covariance (seeded): their k Z^lambda scatter as sigma_at says, within
    the sample sd's own error, 1 / sqrt(2 n) of it (3 of those: 1.5 % for 20,000 draws)."""
    f = figures()
    draws = np.random.default_rng(5).multivariate_normal([f.k, f.lam], f.covariance, size=20_000)
    for z in (1.0, 2.5):
        sigma, se = sigma_at(f, z)
        assert sigma == f.k * z**f.lam
        assert np.std(draws[:, 0] * z ** draws[:, 1], ddof=1) == pytest.approx(se, rel=3 / math.sqrt(2 * 20_000))


def test_lines_with_nothing_to_judge_say_why(tmp_path):
    (tmp_path / "s.toml").write_text("[[sigma]]\nat_z_m = 2\nsigma_mm_max = 50\n[[fill]]\nfill_pct_min = 99\n"
                                     "from_z_m = 5\n[[accuracy]]\ndepth_accuracy_pct_max = 0.5\nto_z_m = 2.0\n")
    spec = read_spec(tmp_path / "s.toml")
    lines = evaluate(spec, figures(lambda_problem="lambda is not determined")).lines
    assert [v.verdict for v in lines] == ["not decided", "not decided", "fail"]
    assert lines[0].reason.startswith("lambda is not determined") and "no stop" in lines[1].reason
    # |-0.3 %| at 1 m passes 0.5 % by 10 s.e., |-0.6 %| at 2 m fails it by 5; 3 m lies past to_z_m: not judged
    assert [(i.where, i.verdict) for i in lines[2].items] == [("1.000m", "pass"), ("2.000m", "fail")]
    assert evaluate(spec, figures(accuracy_why_not="the wall is not known")).lines[2].reason.startswith("accuracy not")
