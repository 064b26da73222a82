"""`rig export` and the evaluator beside it (rig/noise_model.py, docs/noise-model.md).

The evaluator is a second, numpy-only implementation of sigma: it must give rig's own prediction
(`Model.predict_noise`) on every pixel-stop of a recording to 1e-9, for every term it knows, and its standard error
must be the delta method of rig's analytic derivatives (`rig.models.parts.tangents`). The file is checked against
docs/noise-model.schema.json by jsonschema, the reference validator, not by code of ours.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from cli_in_process import rig_in_process
from noise_model_port import PortedModel, rounding_bound, se_bound
from protocols.recording import Recording

from rig.models import load_samples, parse_model
from rig.models.data.pattern_light import light_rows
from rig.models.parts.result import ModelFit
from rig.models.parts.tangents import Tangents
from rig.noise_model import TERMS, NoiseModel, NoiseModelError
from rig.models.export import noise_model_document

ROOT = Path(__file__).resolve().parents[1]
SCHEMA = json.loads((ROOT / "docs" / "noise-model.schema.json").read_text())
#: every term of sigma the evaluator knows, over three models (a term appears once per model)
MODELS = ["power_law+slant_range+incidence+read_noise+noise_floor+empirical(radius)+empirical(position)+censoring",
          "active+ambient+drift+measured_light+empirical(range)+empirical(brightness)+empirical(incidence)",
          "passive+noise_floor+empirical(slant)+outliers+quantization+empirical(tails)"]


def test_the_models_cover_every_term_the_evaluator_knows():
    named = {e.name for spec in MODELS for e in parse_model(spec).effects}
    assert set(TERMS) <= named


def _data(path: Path):
    """The recording's pixel-stops, with the true range set to the measured mean (the evaluator's z is the true
    range; rig's models estimate it from the neighbours' variance) and the measured inputs made to vary."""
    with Recording(path) as rec:
        d = load_samples(rec).positive_variance()
    d.__dict__["z0_m"] = d.z_m
    rng = np.random.default_rng(7)
    d.ambient_ratio = rng.uniform(0.0, 0.5, len(d))
    d.drift_var_m2 = rng.uniform(0.0, 1e-8, len(d))
    d.cos_inc = rng.uniform(0.01, 1.0, len(d))  # a perpendicular wall's are all near 1: reach the clip at 0.05 too
    assert np.isfinite(d.ir).mean() > 0.9
    return d


def _fit_with(model, d, seed: int) -> ModelFit:
    """A ModelFit of `model` at values drawn near its starts (not fitted: the formulas, not the fit, are compared),
    with a random covariance."""
    rng = np.random.default_rng(seed)
    values = {n: p.value for n, p in model.parameters()}
    for e in model.effects:  # the empirical shapes' knots, and the censoring's starting cut, come from the data
        values.update({f"{e.name}.{k}": v for k, v in e.start(d, model.predict_noise(values, d)).items()})
    for n, _ in model.free():
        if n.startswith("empirical"):
            values[n] = float(rng.normal(0.0, 0.3))
    values["k"] *= 1.1
    names = [n for n, _ in model.free()]
    a = rng.normal(size=(len(names), len(names))) * 1e-3
    cov = a @ a.T + 1e-9 * np.eye(len(names))
    return ModelFit(model, values, dict(zip(names, np.sqrt(np.diag(cov)))), 0.0, len(d), int(d.n.sum()), covariance=cov)


def _inputs(evaluator: NoiseModel, d) -> dict[str, np.ndarray]:
    known = {"cos_incidence": lambda: d.cos_inc, "ir_dn": lambda: d.ir, "ambient_ratio": lambda: d.ambient_ratio,
             "drift_var_m2": lambda: d.drift_var_m2,
             "pattern_dn": lambda: light_rows(d, evaluator.values["measured_light.window_px"])}
    return {n: known[n]() for n in evaluator.inputs}


@pytest.mark.numeric
@pytest.mark.parametrize("spec", MODELS)
def test_the_evaluator_gives_rigs_sigma_and_its_error_on_every_pixel_stop(small_recording, spec):
    d = _data(small_recording)
    model = parse_model(spec)
    fit = _fit_with(model, d, seed=len(spec))
    with Recording(small_recording) as rec:
        doc = json.loads(json.dumps(noise_model_document(fit, d, rec, small_recording)))  # as a file holds it
    jsonschema.validate(doc, SCHEMA)
    evaluator = NoiseModel.from_dict(doc)
    names = [n for n, _ in model.free()]
    t = Tangents(names, len(d))
    pred = model.predict_noise(fit.values, d, t)
    sigma, se = evaluator.sigma(d.z_m, d.u_px, d.v_px, with_error=True, **_inputs(evaluator, d))
    assert len(d) > 500
    # 1.6e-14 to 5.2e-14 here (was 1e-9; 6 u seen)
    bound = rounding_bound(evaluator, d.z_m, d.u_px, d.v_px, _inputs(evaluator, d))
    gap = np.abs(sigma - np.sqrt(pred.var_m2)) / sigma
    assert np.all(gap <= bound), np.max(gap / bound)
    g = t.var / (2.0 * np.sqrt(pred.var_m2))  # d sigma / d theta, analytic
    se_rig = np.sqrt(np.einsum("in,ij,jn->n", g, fit.covariance, g))
    # the evaluator differences its own variance over +-h, h = 1e-4 of each parameter's standard error: the
    # truncation, h^2 f''' / 6 f', and the rounding, u f / (h f'), are both far below 1e-5 (5e-8 seen): an
    # approximation's tolerance, not the floating point's
    np.testing.assert_allclose(se, se_rig, rtol=1e-5)
    assert np.all(se > 0)


@pytest.mark.numeric
def test_rig_export_writes_a_valid_file_whose_sigma_is_the_fits_own(small_recording, tmp_path):
    out = tmp_path / "models" / "camera-noise.json"  # a folder not made yet is made, as for every output (it was a traceback)
    r = rig_in_process("export", small_recording, "--model", "active+slant_range+empirical(radius)", "-o", out,
                       "--sigma-map", "0.5,1,2", "--jobs", "1", "-q")
    assert r.returncode == 0, r.stderr
    assert f"model: {out}" in r.stdout and "sigma maps:" in r.stdout
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, SCHEMA)
    assert doc["model"] == "active+slant_range+empirical(radius)"
    assert [t["kind"] for t in doc["sigma_terms"]] == ["physical", "empirical"]
    assert any("empirical shape" in n for n in doc["notes"])
    with Recording(small_recording) as rec:
        cal = rec.calibration
    assert doc["camera"]["intrinsics"]["fx"] == cal.fx and doc["camera"]["depth_unit_m"] == cal.depth_scale_m
    assert doc["valid"]["z_m"][0] < 0.55 and doc["valid"]["z_m"][1] > 1.95
    # the fitted values, put back into rig's model, give the evaluator's sigma on every pixel-stop
    d = _data(small_recording)
    model = parse_model(doc["model"])
    shape = model.effects[-1]
    shape.knots = np.array(doc["sigma_terms"][1]["knots"])
    values = {p["name"]: p["value"] for p in doc["parameters"]}
    evaluator = NoiseModel.load(out)
    sigma, rigs = evaluator.sigma(d.z_m, d.u_px, d.v_px), np.sqrt(model.predict_noise(values, d).var_m2)
    assert np.all(np.abs(sigma - rigs) <= rounding_bound(evaluator, d.z_m, d.u_px, d.v_px, {}) * sigma)
    # the errors the file gives are the fit's own
    errors = {p["name"]: p["error"] for p in doc["parameters"] if p["free"]}
    c = np.array(doc["covariance"]["matrix"])
    # the errors are sqrt(diag C), or sqrt(diag C) g where frames are not independent and C is widened by g^2: 3 u
    assert np.allclose(np.sqrt(np.diag(c)), [errors[n] for n in doc["covariance"]["parameters"]],
                       rtol=2 * np.finfo(np.float64).eps, atol=0)
    maps = np.load(out.parent / "camera-noise.sigma-map.npy")
    assert maps.shape == (3, cal.height, cal.width)
    assert np.all(np.diff(maps[:, cal.height // 2, cal.width // 2]) > 0)  # sigma grows with range at the centre
    # the map is the evaluator at every pixel of the image (rig.reports.sigma_map): the same function on the same
    # image of positions gives the same values, to the last bit
    v, u = np.mgrid[0:cal.height, 0:cal.width].astype(float)
    np.testing.assert_array_equal(maps[1], evaluator.sigma(np.full(u.shape, 1.0), u, v))
    assert (out.parent / "camera-noise.sigma-map.png").stat().st_size > 5000


@pytest.mark.numeric
def test_the_evaluator_runs_with_numpy_alone_in_a_ten_line_script(small_recording, tmp_path):
    """The file copied out of rig into a folder of its own and imported from there: it loads nothing of rig, scipy,
    numba or h5py (rig is installed in this interpreter, so an import of it would succeed and show)."""
    out = tmp_path / "model.json"
    assert rig_in_process("export", small_recording, "-o", out, "-q").returncode == 0
    shutil.copy(ROOT / "rig" / "noise_model.py", tmp_path / "noise_model.py")
    script = (
        "import sys\n"
        "from noise_model import NoiseModel\n"
        "m = NoiseModel.load(sys.argv[1])\n"
        "s, se = m.sigma([0.5, 1.0, 2.0], 16.0, 9.0, with_error=True)\n"
        "print(*s, *se)\n"
        "print(sorted(k.split('.')[0] for k in sys.modules if k.split('.')[0] in ('rig', 'scipy', 'numba', 'h5py')))\n")
    r = subprocess.run([sys.executable, "-E", "-s", "-c", script, str(out)], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    numbers, loaded = r.stdout.splitlines()
    assert loaded == "[]"
    s = np.array(numbers.split(), dtype=float)
    doc = json.loads(out.read_text())
    k, lam = (next(p["value"] for p in doc["parameters"] if p["name"] == n) for n in ("k", "lambda"))
    # the paper's model, k Z^lambda: the evaluator's sqrt(k^2 exp(2 lambda ln Z)) is within (2 |2 lambda ln Z| + 3) u
    # of it (the exponent's error 4 u |2 lambda ln Z|, halved by the root), numpy's pow and product within 3 u
    z = np.array([0.5, 1.0, 2.0])
    u = np.finfo(np.float64).eps / 2
    assert np.all(np.abs(s[:3] - k * z**lam) <= (2 * np.abs(2 * lam * np.log(z)) + 6) * u * s[:3]), (s[:3], k * z**lam)
    assert np.all(s[3:] > 0) and np.all(s[3:] < 0.05 * s[:3])


def test_what_the_evaluator_cannot_do_is_one_line_naming_the_fix(small_recording, tmp_path):
    d = _data(small_recording)
    model = parse_model("active+empirical(brightness)")
    with Recording(small_recording) as rec:
        doc = noise_model_document(_fit_with(model, d, 3), d, rec, small_recording)
    m = NoiseModel.from_dict(doc, "cam.json")
    with pytest.raises(NoiseModelError, match=r"need ir_dn as well as \(z, u, v\); pass ir_dn=\.\.\. to sigma\(\)"):
        m.sigma(1.0, 10.0, 5.0)
    with pytest.raises(NoiseModelError, match="takes no cos_incidence"):
        m.sigma(1.0, 10.0, 5.0, ir_dn=80.0, cos_incidence=1.0)
    user = dict(doc, sigma_terms=[*doc["sigma_terms"], {"effect": "beam_falloff", "stage": 10, "kind": "user",
                                                        "parameters": ["beam_falloff.n"], "user_file": "beam.py"}])
    with pytest.raises(NoiseModelError, match=r"'beam_falloff' \(from beam.py\), which this evaluator does not know"):
        NoiseModel.from_dict(user, "cam.json")
    with pytest.raises(NoiseModelError, match="not a rig.noise-model/1 file"):
        NoiseModel.from_dict({"schema": "rig.result/1"})
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(NoiseModelError, match="cannot read the noise model"):
        NoiseModel.load(tmp_path / "bad.json")
    r = rig_in_process("export", small_recording, "--model", "active+empirical(brightness)", "--sigma-map", "1",
                       "-o", tmp_path / "m.json")
    assert r.returncode == 2 and not (tmp_path / "m.json").exists()  # refused before the fit
    assert r.stderr.count("\n") == 1 and "--sigma-map: the model's terms need ir_dn at each pixel" in r.stderr
    r = rig_in_process("export", small_recording, "--sigma-map", "1,x", "-o", tmp_path / "m.json")
    assert r.returncode == 2 and "give ranges in metres" in r.stderr


@pytest.mark.parametrize("doc, model_file", [("noise-model.md", "camera-noise.json"),
                                             ("calibration-week.md", "week/camera-noise.json")])
def test_the_docs_example_runs_as_written(small_recording, tmp_path, monkeypatch, doc, model_file):
    """A docs page's Python block, on a file rig export wrote where the page says, in a folder of its own."""
    text = (ROOT / "docs" / doc).read_text()
    block = text.split("```python\n", 1)[1].split("```", 1)[0]
    (tmp_path / model_file).parent.mkdir(exist_ok=True)
    assert rig_in_process("export", small_recording, "--model", "active+slant_range+noise_floor",
                          "-o", tmp_path / model_file, "-q").returncode == 0
    monkeypatch.chdir(tmp_path)
    r = subprocess.run([sys.executable, "-c", block], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert "mm" in lines[0]
    if doc == "noise-model.md":
        assert "mm +/-" in lines[0] and lines[2] == "()"
        assert lines[1] == "[False False False]"  # this recording is 32 px wide: the example's pixels lie outside it


def _read_vectors(path: Path) -> dict[str, np.ndarray]:
    """The CSV as docs/noise-model.md describes it, read with the csv module: a header row, then numbers."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return {name: np.array([float(r[i]) for r in rows[1:]]) for i, name in enumerate(rows[0])}


def _port_agrees(doc: dict, vectors: dict[str, np.ndarray]) -> int:
    """Every row of the vectors against the port written from the docs alone (tests/noise_model_port.py): sigma within
    two implementations' rounding (`rounding_bound`), the standard error within what that rounding does to the
    differences over the same steps (`se_bound`), NaN exactly where the vectors have NaN. Returns the rows checked."""
    port, evaluator = PortedModel(doc), NoiseModel.from_dict(doc)
    names = ["z_m", "u_px", "v_px", *evaluator.inputs]
    assert list(vectors) == [*names, "sigma_m", "sigma_se_m"]
    bound = rounding_bound(evaluator, vectors["z_m"], vectors["u_px"], vectors["v_px"],
                           {n: vectors[n] for n in evaluator.inputs})
    for i in range(len(vectors["z_m"])):
        z, u, v, *rest = (float(vectors[n][i]) for n in names)
        var, sigma, g = port.gradient(z, u, v, dict(zip(evaluator.inputs, rest)))
        se = port.standard_error(g)
        assert abs(sigma - vectors["sigma_m"][i]) <= bound[i] * sigma, (i, sigma, vectors["sigma_m"][i])
        if math.isnan(se):
            assert math.isnan(vectors["sigma_se_m"][i]), i
        else:
            assert abs(se - vectors["sigma_se_m"][i]) <= se_bound(port, bound[i], var, sigma, g), \
                (i, se, vectors["sigma_se_m"][i])
    return len(vectors["z_m"])


@pytest.mark.numeric
@pytest.mark.parametrize("spec", MODELS)
def test_a_port_written_from_the_docs_alone_reproduces_the_test_vectors(small_recording, tmp_path, spec):
    """Every term of sigma, through the vectors file: inputs over and beyond the fitted region (shapes' flat ends,
    the incidence clip, an ambient ratio not measured)."""
    from rig.reports.port_vectors import ROWS, write_vectors

    d = _data(small_recording)
    model = parse_model(spec)
    with Recording(small_recording) as rec:
        doc = json.loads(json.dumps(noise_model_document(_fit_with(model, d, seed=len(spec)), d, rec, small_recording)))
    vectors = _read_vectors(write_vectors(NoiseModel.from_dict(doc), tmp_path / "v.csv"))
    assert _port_agrees(doc, vectors) == ROWS
    z = vectors["z_m"]
    assert z.min() < doc["valid"]["z_m"][0] and z.max() > doc["valid"]["z_m"][1]  # past the fitted ranges
    if "cos_incidence" in vectors:
        assert vectors["cos_incidence"].min() < 0.05  # the clip
    if "ambient_ratio" in vectors:
        assert np.isnan(vectors["ambient_ratio"]).any() and np.isfinite(vectors["ambient_ratio"]).any()


@pytest.mark.numeric
def test_rig_export_writes_test_vectors_and_a_float32_tiff_sigma_map(small_recording, tmp_path):
    """The vectors from the command, checked by the port; the TIFF read back by tifffile (values, dtype, metadata)
    and, as a reader that is not the writer, by Pillow."""
    import tifffile
    from PIL import Image

    out = tmp_path / "cam.json"
    r = rig_in_process("export", small_recording, "--model", "active+slant_range+noise_floor", "-o", out,
                       "--sigma-map", "0.5,1,2", "--test-vectors", "-q")
    assert r.returncode == 0, r.stderr
    assert f"test vectors: {tmp_path / 'cam.test-vectors.csv'} (256 rows)" in r.stdout
    doc = json.loads(out.read_text())
    assert _port_agrees(doc, _read_vectors(tmp_path / "cam.test-vectors.csv")) == 256
    maps = np.load(tmp_path / "cam.sigma-map.npy")
    with tifffile.TiffFile(tmp_path / "cam.sigma-map.tif") as tif:
        image, meta = tif.asarray(), tif.shaped_metadata[0]
        assert len(tif.pages) == 3
    assert image.dtype == np.float32 and image.shape == maps.shape
    # float32 of the same doubles: round to nearest, within half an ulp, 2^-24 relatively (sigma is a normal float)
    assert np.all(np.abs(image.astype(float) - maps) <= 2.0**-24 * maps)
    np.testing.assert_array_equal(image, maps.astype(np.float32))
    assert meta["unit"] == "m" and meta["model"] == "active+slant_range+noise_floor" and meta["z_m"] == [0.5, 1.0, 2.0]
    assert meta["camera"]["intrinsics"] == doc["camera"]["intrinsics"]
    assert meta["camera"]["fb_px_m"] == doc["camera"]["fb_px_m"] and meta["noise_model_file"] == str(out)
    with Image.open(tmp_path / "cam.sigma-map.tif") as im:
        assert im.mode == "F" and im.n_frames == 3
        for page in range(3):
            im.seek(page)
            np.testing.assert_array_equal(np.array(im), image[page])
    # the pages against the port, pixel by pixel at 1 m (a wall perpendicular to the axis: no incidence input here)
    port, bound = PortedModel(doc), 2.0**-24
    v, u = np.mgrid[0:image.shape[1], 0:image.shape[2]]
    exact = np.array([[port.sigma_m(1.0, float(uu), float(vv)) for uu, vv in zip(ur, vr)] for ur, vr in zip(u, v)])
    gap = rounding_bound(NoiseModel.from_dict(doc), np.full(u.shape, 1.0), u, v, {}) + bound
    assert np.all(np.abs(image[1] - exact) <= gap * exact)


@pytest.fixture(scope="module")
def undetermined(tmp_path_factory) -> dict[str, Path]:
    """Recordings of the simulator that leave parameters undetermined: 8 px wide at four ranges, where censoring's
    cut sits on its bound (no covariance at all), and 4 x 2 px at two ranges, where y^2 takes one value and
    empirical(position)'s a_yy trades off with k (their variances come out negative)."""
    from simrig import record_perpendicular

    folder = tmp_path_factory.mktemp("undetermined-export")
    return {"active+slant_range+censoring": record_perpendicular(folder / "narrow.h5", width=8, frames=8,
                                                                  stops_m=[0.5, 1.0, 1.5, 2.0])[0],
            "active+empirical(position)": record_perpendicular(folder / "tiny.h5", width=4, frames=8,
                                                                stops_m=[0.5, 1.0])[0]}


@pytest.mark.parametrize("spec", ["active+slant_range+censoring", "active+empirical(position)"])
def test_an_undetermined_parameter_has_null_variances_and_sigma_a_nan_error(undetermined, tmp_path, spec):
    out = tmp_path / "cam.json"
    r = rig_in_process("export", undetermined[spec], "--model", spec, "-o", out, "--test-vectors", "-q")
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    jsonschema.validate(doc, SCHEMA)
    errors = {p["name"]: p["error"] for p in doc["parameters"] if p["free"]}
    names = doc["covariance"]["parameters"]
    c = np.array(doc["covariance"]["matrix"], dtype=float)  # null -> NaN
    assert "k" in [n for n, e in errors.items() if e is None]
    for i, n in enumerate(names):
        if errors[n] is None:  # undetermined: null in its row and column, nothing negative
            assert np.all(np.isnan(c[i])) and np.all(np.isnan(c[:, i]))
        else:
            assert c[i, i] > 0 and errors[n] == pytest.approx(math.sqrt(c[i, i]), rel=2 * np.finfo(float).eps)
    assert any("do not determine k" in n for n in doc["notes"])
    sigma, se = NoiseModel.load(out).sigma(np.array([0.5, 1.0, 2.0]), np.array([0.0, 1.5, 3.0]), 1.0, with_error=True)
    assert np.all(np.isfinite(sigma) & (sigma > 0)) and np.all(np.isnan(se))  # k enters everywhere
    vectors = _read_vectors(tmp_path / "cam.test-vectors.csv")
    assert np.all(np.isnan(vectors["sigma_se_m"])) and _port_agrees(doc, vectors) == 256


def test_the_error_is_nan_only_where_an_undetermined_parameter_enters(small_recording):
    """A fit whose a_x came out with a negative variance (a flat direction): the file nulls its row and column, and
    sigma's error is NaN off the centre column and finite on it, where x = 0 and a_x does not enter."""
    d = _data(small_recording)
    model = parse_model("active+empirical(position)")
    fit = model.fit(d)
    names = [n for n, _ in model.free()]
    cov = np.array(fit.covariance)
    i = names.index("empirical(position).a_x")
    cov[i, i] = -4.2e7
    errors = {**fit.errors, "empirical(position).a_x": math.nan}
    with Recording(small_recording) as rec:
        doc = json.loads(json.dumps(noise_model_document(replace(fit, covariance=cov, errors=errors), d, rec,
                                                         small_recording)))
    assert doc["covariance"]["matrix"][i] == [None] * len(names)
    assert all(row[i] is None for row in doc["covariance"]["matrix"])
    cx = doc["camera"]["intrinsics"]["cx"]
    u = np.array([cx, cx, 0.0, 2 * cx])
    sigma, se = NoiseModel.from_dict(doc).sigma(np.array([0.7, 1.6, 0.7, 1.6]), u, np.array([0.0, 17.0, 5.0, 9.0]),
                                                with_error=True)
    assert np.all(np.isfinite(se[:2]) & (se[:2] > 0)) and np.all(np.isnan(se[2:]))
    port = PortedModel(doc)
    assert [math.isnan(port.sigma(z, uu, vv)[1]) for z, uu, vv in zip((0.7, 1.6, 0.7, 1.6), u, (0.0, 17.0, 5.0, 9.0))] \
        == [False, False, True, True]


@pytest.mark.parametrize("spec", MODELS)
def test_each_parameter_has_one_unit_in_the_export_and_in_rig_result(small_recording, spec):
    """The same unit in rig.noise-model/1 and rig.result/1 (docs/json.md: "1" for a pure number, lambda's), and every
    term's stage the step docs/noise-model.md ("Conventions") names for it."""
    from rig.reports.result_json import fit_json

    d = _data(small_recording)
    model = parse_model(spec)
    fit = _fit_with(model, d, seed=1)
    with Recording(small_recording) as rec:
        doc = noise_model_document(fit, d, rec, small_recording)
    units = {p["name"]: p["unit"] for p in doc["parameters"]}
    assert units == fit_json(fit)["units"] and units["lambda"] == "1" and "" not in units.values()
    documented = {"slant_range": 10, "incidence": 10, "measured_light": 10, "read_noise": 20, "ambient": 20, "noise_floor": 30, "drift": 40,
                  "censoring": 50, "quantization": 60, "outliers": 70, "empirical(tails)": 80}
    for t in doc["sigma_terms"] + doc["after_sigma"]:
        assert t["stage"] == documented.get(t["effect"], 45 if t in doc["sigma_terms"] else 80), t["effect"]


def test_a_newer_model_file_asks_for_a_newer_evaluator_not_an_export():
    """issue 51: a rig.noise-model/2 file was told to "export the model with rig export"; the fix is a newer rig."""
    with pytest.raises(NoiseModelError, match=r"<dict> is a rig.noise-model/2 file, newer than this evaluator's "
                                              r"rig.noise-model/1; update rig"):
        NoiseModel.from_dict({"schema": "rig.noise-model/2"})
    with pytest.raises(NoiseModelError, match="is not a rig.noise-model/1 file .*; export the model with rig export"):
        NoiseModel.from_dict({"schema": "something/3"})


def test_a_malformed_model_file_is_one_noise_model_error_and_nan_is_refused(small_recording):
    """Issue 52: NoiseModel.load of a damaged file raised bare KeyError / TypeError / ValueError, and NaN parameters
    gave NaN sigma silently. Each damage below is one NoiseModelError naming the file; nothing else escapes."""
    import copy

    d = _data(small_recording)
    with Recording(small_recording) as rec:
        doc = noise_model_document(_fit_with(parse_model("active"), d, 3), d, rec, small_recording)
    assert NoiseModel.from_dict(copy.deepcopy(doc), "ok.json").sigma(1.0, 10.0, 5.0) > 0

    def damaged(change):
        bad = copy.deepcopy(doc)
        change(bad)
        return bad

    cases = {
        "parameters": lambda b: b.pop("parameters"),
        "NaN k": lambda b: b["parameters"][0].update(value=float("nan")),
        "text k": lambda b: b["parameters"][0].update(value="0.002"),
        "no camera": lambda b: b.pop("camera"),
        "no fx": lambda b: b["camera"]["intrinsics"].pop("fx"),
        "terms": lambda b: b.update(sigma_terms={"effect": "power_law"}),
        "valid": lambda b: b["valid"].pop("z_m"),
        "covariance": lambda b: b.pop("covariance"),
        "settings": lambda b: b.update(settings=None),
    }
    for name, change in cases.items():
        with pytest.raises(NoiseModelError, match=r"^cam\.json") as e:
            NoiseModel.from_dict(damaged(change), "cam.json")
        assert "\n" not in str(e.value) and "rig export" in str(e.value), (name, e.value)
