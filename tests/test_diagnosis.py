"""rig diagnose, blind, on recordings with a hidden effect (rig.simulation.scenarios).

The acceptance bar (issue 13): a catalogue effect is named first, the error beyond noise at least
halved and every statistic within noise once it is added; a pair is found whole; for an effect
the catalogue lacks, the diagnosis makes no false "within noise" claim with catalogue effects
alone, names a covariate the effect explains, and the empirical terms bring every statistic
within noise. The test suite runs one fixed seed of each scenario it can afford; the full table
(10 seeds of every scenario, docs/models.md) is `rig validate-diagnosis --seeds 10`.
"""

import json
import re

import h5py
import pytest

from rig.cli import main
from rig.simulation.scenarios import ALL_SCENARIOS, BIAS, HIDDEN, NOT_INDEPENDENT, OUTSIDE, SATURATED_IR
from rig.simulation.validation import run_trial

pytestmark = pytest.mark.slow


SEED = 1000
#: the suite's trials are a quarter of the pixels of the docs' table (53 px wide, not 106; 100 frames a stop):
#: 4-30 s of CPU a trial instead of 35-140 s, within the suite's budget. At seed 1000 every scenario ends as it
#: does at full size (measured: the same effects named, the same one short of noise)
SIZE = dict(width=53)
#: known shortfalls, run and required to fail until they are fixed (issue 30). light_falloff (within noise in 1
#: trial of 10 in docs/models.md's table) was one until its clipped IR at 0.5 m (16 % of the pixels, seed 1000) was
#: kept out of brightness (issue 31): read_noise + slant_range now end within noise on this seed (0.34 %, noise
#: 0.37 %); the 10-seed table has not been measured again since
SHORTFALLS: dict[str, str] = {}
#: noisy_confidence, the slowest trial, is left to the docs' table (rig validate-diagnosis); the suite does not run it
SUITE = [pytest.param(s, marks=pytest.mark.xfail(strict=True, reason=SHORTFALLS[s])) if s in SHORTFALLS else s
         for s in ALL_SCENARIOS
         if s not in ("noisy_confidence", "mottled_beam", *NOT_INDEPENDENT, *SATURATED_IR, *OUTSIDE, *BIAS)]
# temporal_filter (frames not independent) runs cheaper, without the path: tests/test_independence.py; and
# ambient_saturated_ir (IR clipped near the wall) on a smaller image: tests/test_ir_saturation.py; the outside
# scenes (fakes/outside, 26-100 s of CPU a diagnosis) are the docs' table's alone; one runs below as a trial.
# mottled_beam ends beyond noise without the effect the diagnosis does not try on its own (docs/models.md, 0/10); the
# model that names it is tests/test_measured_light.py's; the miscalibrations (BIAS) are tests/test_bias_loop.py's


def test_an_outside_scene_runs_as_a_trial_from_its_folder(tmp_path):
    """The outside scenes enter the blind test as a lab's folder would (fakes/outside, then `rig import`): the
    drift scene, the cheapest to diagnose, is imported and judged as kind "outside"."""
    t = run_trial("outside_thermal_drift", 1, tmp_path)
    assert t.kind == "outside" and t.correct and t.path, t
    assert t.error_before_pct > t.error_after_pct and t.covariate_right, t
    assert not list(tmp_path.glob("*-frames")), "the rendered folder is removed once imported"


@pytest.mark.parametrize("effect", SUITE)
def test_the_diagnosis_finds_what_is_hidden(tmp_path, effect):
    t = run_trial(effect, SEED, tmp_path, **SIZE)
    where = (f"{effect}: path {t.path}, residual follows {t.covariate!r}, error {t.error_before_pct:.2f} % -> "
             f"{t.error_catalogue_pct:.2f} % -> {t.error_after_pct:.2f} % (noise {t.noise_pct:.2f} %), "
             f"worst {t.worst!r}")
    assert t.correct, where
    if t.kind == "open":
        assert not t.claims_within_catalogue and t.covariate_right, where
    else:
        assert t.halved, where
    assert t.within_noise, where


def test_simulate_keeps_the_answer_out_of_the_recording(tmp_path, capsys):
    out = tmp_path / "x.h5"
    assert main(["simulate", "--scenario", "hidden", "--seed", "3", "--effect", "slant_range", str(out)]) == 0
    answer = json.loads((tmp_path / "x.answer.json").read_text())
    assert answer["hidden_effect"] == "slant_range" and answer["seed"] == 3
    raw = out.read_bytes()
    for name in HIDDEN:  # no effect's name as a word anywhere in the file (attributes are stored as plain bytes;
        # 'ambient_frames', a protocol parameter, and 'ambient_ir_mean', a dataset, are not the answer)
        assert not re.search(rb"\b" + name.encode() + rb"\b", raw), name
    with h5py.File(out) as f:
        assert "effects" not in f.attrs["camera"]


def test_diagnose_command_writes_report_and_plots(tmp_path, capsys):
    out = tmp_path / "x.h5"
    assert main(["simulate", "--seed", "5", "--effect", "censoring", "--width", "53", str(out)]) == 0
    assert main(["diagnose", str(out), "--out", str(tmp_path / "rep")]) == 0
    text = capsys.readouterr().out
    assert "Most likely missing: censoring" in text and "within noise" in text
    page = (tmp_path / "rep" / "diagnosis.html").read_text()
    assert "Most likely missing: censoring" in page and page.count("data:image/png;base64,") == 3
    for name in ("diagnosis-residuals.png", "diagnosis-candidates.png", "diagnosis-before-after.png"):
        assert (tmp_path / "rep" / name).stat().st_size > 10_000


def test_compare_shows_the_error_fall(tmp_path, capsys):
    out = tmp_path / "x.h5"
    assert main(["simulate", "--seed", "2", "--effect", "slant_range", "--width", "53", str(out)]) == 0
    capsys.readouterr()
    assert main(["compare", str(out), "--models", "active,active+slant_range", "--no-held-out"]) == 0
    lines = capsys.readouterr().out.splitlines()
    base = next(line for line in lines if line.startswith("active "))
    both = next(line for line in lines if line.startswith("active+slant_range"))
    err = lambda line: float(line.split()[2])  # noqa: E731
    assert err(base) > 5 and err(both) < 0.5 * err(base)
    assert " no " in base and " yes " in both


def test_held_out_score_prefers_the_true_model(tmp_path, capsys):
    out = tmp_path / "x.h5"
    assert main(["simulate", "--seed", "4", "--effect", "read_noise", "--width", "53", str(out)]) == 0
    capsys.readouterr()
    assert main(["compare", str(out), "--models", "active,active+read_noise", "--jobs", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    nll = [float(line.split()[-1]) for line in lines if line.startswith("active")]
    assert nll[1] < nll[0]


def test_a_coarse_unit_the_approximate_conditioning_missed_ends_within_noise(tmp_path):
    """Seed 1004 (a 1.39 mm unit, sigma 0.25 q at the near stop): with the rounded variance conditioned
    approximately on the pixel's mean, the near stop read 1 % above the model and the verdict was 'beyond
    noise: sigma by brightness'; conditioned exactly (rig/models/data/rounding_table.py) it is within noise."""
    t = run_trial("coarse_depth_unit", 1004, tmp_path)
    assert t.correct and t.within_noise, (t.path, t.error_after_pct, t.noise_pct, t.worst)


def test_an_effect_that_cannot_be_fitted_is_named_with_its_reason(tmp_path):
    """A candidate whose fit fails (here: an effect that raises ValueError past its start values) is not ranked,
    and the report says which effect and why instead of leaving it out silently."""
    from rig.diagnosis import diagnose
    from rig.diagnosis.text import render_text
    from rig.models import Catalogue, ModelData
    from rig.models.parts.component import Effect
    from rig.models.parts.parameters import Param
    from rig.models.parts.prediction import EffectStage

    class Fragile(Effect):
        name = "fragile"
        stage = EffectStage.DISPARITY
        params = (Param("gain", 1.0, 0.5, 2.0, "1", "a factor on the variance"),)

        def apply(self, pred, p, d):
            if p.gain != 1.0:
                raise ValueError("fragile: no model for a gain other than 1")
            pred.var_m2 = pred.var_m2 * p.gain

    out = tmp_path / "x.h5"
    assert main(["simulate", "--seed", "5", "--effect", "slant_range", "--width", "53", str(out)]) == 0
    d = ModelData.from_recording(out)
    diag = diagnose(d, source=str(out), catalogue=Catalogue().with_effects([Fragile()], "this test"))
    assert ("fragile", "fragile: no model for a gain other than 1") in diag.steps[0].not_fitted
    assert "fragile" not in [c.effect.name for c in diag.candidates]
    assert "fragile          could not be fitted on top of active: fragile: no model for a gain other than 1" \
        in render_text(diag)
