"""rig diagnose, blind, on recordings with a hidden effect (rig.scenarios).

The acceptance bar of the project: for every effect, named first in at least 9 of 10 seeds,
the headline error at least halved and within noise once it is added; with nothing hidden,
nothing significant reported in at least 9 of 10 seeds. `rig validate-diagnosis` runs the
same trials and prints the table.
"""

import json
import re
import subprocess
import sys

import h5py
import pytest

from rig.cli import main
from rig.simulation.scenarios import CHOICES, HIDDEN
from rig.simulation.validation import run_trial

SEEDS = range(1000, 1010)


@pytest.mark.parametrize("effect", CHOICES)
def test_hidden_effect_is_found_and_explains_the_error(tmp_path, effect):
    trials = [run_trial(effect, seed, tmp_path) for seed in SEEDS]
    named = [t.named for t in trials]
    assert sum(t.correct for t in trials) >= 9, named
    assert sum(t.halved for t in trials) >= 9
    assert sum(t.within_noise for t in trials) >= 9, [(t.error_after_pct, t.noise_pct) for t in trials]


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
    assert main(["simulate", "--seed", "5", "--effect", "censoring", str(out)]) == 0
    assert main(["diagnose", str(out), "--out", str(tmp_path / "rep")]) == 0
    text = capsys.readouterr().out
    assert "Most likely missing: censoring" in text and "within noise" in text
    page = (tmp_path / "rep" / "diagnosis.html").read_text()
    assert "Most likely missing: censoring" in page and page.count("data:image/png;base64,") == 3
    for name in ("diagnosis-residuals.png", "diagnosis-candidates.png", "diagnosis-before-after.png"):
        assert (tmp_path / "rep" / name).stat().st_size > 10_000


def test_compare_shows_the_error_fall(tmp_path, capsys):
    out = tmp_path / "x.h5"
    assert main(["simulate", "--seed", "2", "--effect", "slant_range", str(out)]) == 0
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
    assert main(["simulate", "--seed", "4", "--effect", "read_noise", str(out)]) == 0
    capsys.readouterr()
    assert main(["compare", str(out), "--models", "active,active+read_noise"]) == 0
    lines = capsys.readouterr().out.splitlines()
    nll = [float(line.split()[-1]) for line in lines if line.startswith("active")]
    assert nll[1] < nll[0]
