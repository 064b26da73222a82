"""`rig compare` says first what differs in the set-up and blames a difference on it where physics says it does; it
gives no verdict in standard errors where the model does not fit a recording; its document follows a published schema.

Recordings made by rig's simulator (the fake camera through the real runner, on disk) with another depth unit, another
baseline, and an effect the power law does not model. What each set-up difference does is computed here from physics
and the recordings' own statistics read with h5py: rounding to a depth unit q adds q^2/12 to the variance where the
noise is well above q (Sheppard), and sigma_Z = Z^2 sigma_d / (f b) scales with 1/b. The documents are checked against
docs/comparison.schema.json by jsonschema, the reference validator.
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
from simrig import record_perpendicular

import rig

SCHEMA = json.loads((Path(__file__).resolve().parents[1] / "docs" / "comparison.schema.json").read_text())
STOPS = [0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
FINE_M, COARSE_M = 0.1e-3, 1.0e-3  # depth units
BASE_M, WIDE_M = 50e-3, 100e-3  # baselines
U = np.finfo(np.float64).eps / 2


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> dict[str, Path]:
    """16 x 9 px, 10 frames at each of 6 stops. fine and coarse: the same camera and noise (seed 3), stored in 0.1 mm
    and in 1 mm; wide: another unit (seed 4) with twice the baseline; floor: another unit (seed 5) with a disparity
    noise floor, which k Z^lambda does not model."""
    root = tmp_path_factory.mktemp("setups")
    made = {"fine": (3, FINE_M, BASE_M, ""), "coarse": (3, COARSE_M, BASE_M, ""), "wide": (4, FINE_M, WIDE_M, ""),
            "floor": (5, FINE_M, BASE_M, "noise_floor(sigma_px=0.05)")}
    out = {}
    for name, (seed, q_m, b_m, effects) in made.items():
        out[name] = root / f"{name}.h5"
        record_perpendicular(out[name], seed=seed, width=16, frames=10, stops_m=STOPS, depth_unit_mm=q_m * 1e3,
                             camera_options=f"baseline_mm={b_m * 1e3:g}", effects=effects)
    return out


@pytest.fixture(scope="module")
def compared(recordings, tmp_path_factory) -> tuple[dict, dict]:
    """rig compare of the four, as JSON: the document and its pairs by (a, b) name."""
    plot = tmp_path_factory.mktemp("plots") / "c.png"
    r = rig_in_process("compare", *recordings.values(), "--jobs", "1", "--plot", plot, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    return doc, {(Path(p["a"]).stem, Path(p["b"]).stem): p for p in doc["differences"]}


def stop_moments(path: Path) -> dict[float, tuple[np.ndarray, np.ndarray]]:
    """{commanded range, m: (samples per pixel, sum of squared deviations per pixel, m^2)}, as the file holds them."""
    with h5py.File(path) as f:
        return {float(g.attrs["commanded_position_m"]): (g["count"][()].astype(float), g["m2_m2"][()])
                for g in f["stops"].values()}


def pooled_variance(count: np.ndarray, m2: np.ndarray) -> tuple[float, float]:
    """(the variance pooled over the pixels with two or more samples, its degrees of freedom)."""
    keep = count >= 2
    dof = float(np.sum(count[keep] - 1))
    return float(np.sum(m2[keep]) / dof), dof


def test_a_depth_unit_difference_is_said_first_and_its_rounding_is_q2_over_12(recordings, compared):
    # physics, from the files: with the same noise, the coarse recording's variance exceeds the fine one's by
    # (q_c^2 - q_f^2) / 12 wherever the noise is well above q_c (Sheppard's correction is exact to exp(-2 pi^2 s^2),
    # s = sigma / q: below 1e-8 for s >= 1); pixel by pixel, weighted over those stops by their standard errors
    fine, coarse = stop_moments(recordings["fine"]), stop_moments(recordings["coarse"])
    est, weights = 0.0, 0.0
    for z in STOPS:
        (n_f, m2_f), (n_c, m2_c) = fine[z], coarse[z]
        if math.sqrt(pooled_variance(n_f, m2_f)[0]) < COARSE_M:
            continue
        both = (n_f >= 2) & (n_c >= 2)
        excess = m2_c[both] / (n_c[both] - 1) - m2_f[both] / (n_f[both] - 1)
        w = excess.size / np.var(excess, ddof=1)  # 1 / the squared standard error of its mean
        est, weights = est + w * excess.mean(), weights + w
    est, se = est / weights, 1 / math.sqrt(weights)
    sheppard = (COARSE_M**2 - FINE_M**2) / 12
    assert abs(est - sheppard) < 4 * se and est > 2 * se, (est, se, sheppard)

    doc, pairs = compared
    pair = pairs["fine", "coarse"]
    verdict = pair["verdict"]
    assert verdict.startswith("fine.h5 against coarse.h5: the set-up differs: depth unit 0.1 mm in fine.h5 against "
                              "1 mm in coarse.h5 (rounding to the depth unit q adds q^2/12 to the variance")
    assert "The likely cause is the depth unit" in verdict and "--model power_law+quantization" in verdict
    assert [d["item"] for d in pair["setup_differences"]] == ["depth_unit_m"]
    depth = pair["setup_differences"][0]
    assert depth["values"] == [pytest.approx(FINE_M, rel=2 * U), pytest.approx(COARSE_M, rel=2 * U)]
    # q / sqrt(12) both here and in rig: a division and a square root, each correctly rounded (2 u)
    sigma_q = [pytest.approx(q / math.sqrt(12), rel=2 * U) for q in (FINE_M, COARSE_M)]
    assert depth["expected"]["rounding_sigma_m"] == sigma_q
    # q^2/12 against the variance pooled at 0.5 m, here from the file: sums of 144 pixels in another order (144 u)
    var_05, _ = pooled_variance(*coarse[0.5])
    assert depth["expected"]["rounding_z_m"][1] == pytest.approx(0.5, abs=0.01)
    assert depth["expected"]["rounding_share"][1] == pytest.approx(COARSE_M**2 / 12 / var_05, rel=160 * U)
    assert depth["expected"]["rounding_visible"] == [False, True]

    # the model that rounds to each recording's own depth unit fits both, and they are alike within their errors
    r = rig_in_process("compare", recordings["fine"], recordings["coarse"], "--model", "power_law+quantization",
                       "--jobs", "1", "--plot", recordings["fine"].with_name("q.png"), "--json")
    quantized = json.loads(r.stdout)["differences"][0]
    assert quantized["judged"] and not any(d["differs"] for d in quantized["parameters"])
    assert "the model's quantization accounts for the depth unit. Alike within their errors" in quantized["verdict"]


def test_a_baseline_difference_is_said_first_and_explains_k_by_1_over_b(recordings, compared):
    # physics, from the files: sigma_Z = Z^2 sigma_d / (f b) with the same fx and sensor, so at every stop the
    # measured sigma (rounding's q^2/12 taken out) is b_wide / b_base times larger with the shorter baseline; the log
    # of a pooled sigma has the standard error 1 / sqrt(2 dof)
    base, wide = stop_moments(recordings["fine"]), stop_moments(recordings["wide"])
    expected = WIDE_M / BASE_M
    for z in STOPS:
        (v_b, dof_b), (v_w, dof_w) = pooled_variance(*base[z]), pooled_variance(*wide[z])
        log_ratio = 0.5 * math.log((v_b - FINE_M**2 / 12) / (v_w - FINE_M**2 / 12))
        assert abs(log_ratio - math.log(expected)) < 4 * math.sqrt(1 / (2 * dof_b) + 1 / (2 * dof_w)), z

    doc, pairs = compared
    pair = pairs["fine", "wide"]
    verdict = pair["verdict"]
    assert verdict.startswith("fine.h5 against wide.h5: the set-up differs: baseline 50 mm in fine.h5 against 100 mm")
    assert "k differs by" in verdict
    assert "the baseline explains it (k scales as 1/(f b): k_a/k_b = 2 expected" in verdict
    assert "another gain, exposure or unit" not in verdict  # the old blame, for a k that differs for no set-up reason
    assert [d["item"] for d in pair["setup_differences"]] == ["baseline_m"]
    assert pair["setup_differences"][0]["expected"] == {"k_relative": [1.0, pytest.approx(BASE_M / WIDE_M, rel=4 * U)]}
    k = next(d for d in pair["parameters"] if d["parameter"] == "k")
    fits = {Path(f["path"]).stem: f for f in doc["fits"]}
    # the fitted k's ratio is the baseline's, within its standard error (delta method on the log of the ratio)
    se_log = math.hypot(*(fits[n]["errors"]["k"] / fits[n]["values"]["k"] for n in ("fine", "wide")))
    assert abs(math.log(k["value_a"] / k["value_b"] / expected)) < 4 * se_log
    assert k["expected_ratio"] == pytest.approx(expected, rel=4 * U)
    assert k["significant"] and not k["differs"] and k["causes"] == ["baseline_m"]


def test_no_verdict_in_standard_errors_where_the_model_does_not_fit(recordings, compared):
    doc, pairs = compared
    fits = {Path(f["path"]).stem: f for f in doc["fits"]}
    # the criterion rig repeatability uses: the fit's headline verdict is beyond noise
    assert fits["floor"]["verdict"].startswith("beyond noise") and fits["coarse"]["verdict"].startswith("beyond noise")
    assert fits["fine"]["verdict"].startswith("every statistic within noise")
    for names in [("fine", "floor"), ("fine", "coarse"), ("coarse", "floor"), ("wide", "floor")]:
        pair = pairs[names]
        assert "differs by" not in pair["verdict"] and "Alike" not in pair["verdict"]
        # the noise's parameters get no verdict; the bias against the stage has its own errors and keeps one
        assert not pair["judged"] and all(d["significant"] is None for d in pair["parameters"]
                                          if not d["parameter"].startswith("bias."))
        assert "No verdict in standard errors: power_law does not fit" in pair["verdict"]
    pair = pairs["fine", "floor"]
    floor = fits["floor"]
    assert pair["verdict"].startswith("fine.h5 against floor.h5: the same set-up (depth unit, baseline, intrinsics, "
                                      "resolution, exposure, gain, projector, firmware, camera model, camera serial)")
    # the worst statistic is named, then the headline (a recording can fail on fill or kurtosis with a small headline)
    worst = floor["verdict"].removeprefix("beyond noise; ")
    assert worst.startswith("worst: ")
    assert (f"power_law does not fit floor.h5 within noise ({worst}; headline error {floor['headline_pct']:.2f} % "
            f"against {floor['noise_pct']:.2f} % of noise)") in pair["not_judged"]
    assert "rig diagnose floor.h5" in pair["not_judged"]
    assert pairs["fine", "wide"]["judged"]  # both fit: judged


def test_the_documents_follow_their_published_schema(recordings, compared, tmp_path):
    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    doc, _ = compared
    jsonschema.validate(doc, SCHEMA)
    assert doc["schema"] == "rig.comparison/2" and doc["rig_version"] == rig.package_version()
    assert [d["item"] for d in doc["setup_differences"]] == ["depth_unit_m", "baseline_m"]
    assert len(doc["differences"]) == 6 and all(isinstance(p, dict) for p in doc["differences"])
    # the shape of rig.comparison/1 (a list of lists) is not this schema's
    old = dict(doc, differences=[p["parameters"] for p in doc["differences"]])
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(old, SCHEMA)
    # rig repeatability shares the schema, and says first that the runs are not of one set-up
    r = rig_in_process("repeatability", recordings["fine"], recordings["wide"], "--jobs", "1",
                       "--plot", tmp_path / "r.png", "--json")
    rep = json.loads(r.stdout)
    jsonschema.validate(rep, SCHEMA)
    assert rep["verdicts"][0].startswith("The runs are not of one set-up, so their scatter is not only the noise's: "
                                         "baseline 50 mm in fine.h5 against 100 mm in wide.h5")
    assert "the set-up differs in baseline, which changes k" in rep["verdicts"][0]


def test_what_neither_recording_records_is_no_difference(tmp_path):
    """Two imports of one bag's frames that differ only in the depth unit (16UC1 counts in mm and the same depth as
    32FC1 metres, which the import keeps on its 1 mm grid with a given 0.5 mm unit): a ROS bag records no exposure
    or gain, so both are NaN in each recording. Only the depth unit differs; NaN against NaN is "not recorded",
    not a difference (an outside review of issue 48 found "exposure nan us in a.h5 against nan us in b.h5")."""
    from ros_bags import Camera, write_cameras

    from rig.cli import import_main

    frames = np.random.default_rng(1).normal(1500, 4, (8, 6, 8)).round().astype(np.uint16)
    counts = write_cameras(tmp_path / "counts", [Camera(frames)])
    metres = write_cameras(tmp_path / "metres", [Camera((frames * np.float32(1e-3)).astype(np.float32), encoding="32FC1")])
    args = ["--projector", "on", "--distance-m", "1.5", "-q"]
    assert import_main([str(counts), "-o", str(tmp_path / "a.h5"), *args]) == 0
    assert import_main([str(metres), "-o", str(tmp_path / "b.h5"), *args, "--depth-unit-m", "0.0005"]) == 0
    r = rig_in_process("compare", tmp_path / "a.h5", tmp_path / "b.h5", "--model", "power_law",
                       "--json", "--plot", tmp_path / "c.png")
    doc = json.loads(r.stdout)
    assert [d["item"] for d in doc["setup_differences"]] == ["depth_unit_m"], doc["setup_differences"]
    assert "exposure" not in r.stdout.split("\n")[0] and "nan" not in json.dumps(doc["setup_differences"])
