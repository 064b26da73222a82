"""docs/effects.md's worked example, run as written: a beam fall-off the catalogue lacks is found
'not explained' along radius, and the ten-line effect file names it and brings every statistic within noise."""

import json
import os
import re
from pathlib import Path

from rig.cli import main
import pytest

pytestmark = pytest.mark.slow


ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "effects.md"


def guide_commands() -> list[list[str]]:
    """The `rig ...` lines of the guide's sh blocks, in order."""
    blocks = re.findall(r"```sh\n(.*?)```", GUIDE.read_text(), flags=re.S)
    lines = [line.split("#")[0].strip() for block in blocks for line in block.splitlines()]
    return [line.split()[1:] for line in lines if line.startswith("rig ")]


def test_the_worked_example_runs_as_written(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    os.symlink(ROOT / "examples", tmp_path / "examples")
    commands = guide_commands()
    assert [c[0] for c in commands] == ["simulate", "diagnose", "diagnose", "fit"]
    outputs = []
    for args in commands:
        assert main(args) == 0, args
        outputs.append(capsys.readouterr().out)
    first, second, fit = outputs[1], outputs[2], outputs[3]
    # without the effect: the catalogue does not explain it, the residual follows radius, the shape does
    assert "Not explained by the catalogue" in first and "follows radius" in first
    assert "empirical(radius)" in first and "every statistic within noise" in first.split("Not explained")[1]
    assert "Most likely missing: beam_falloff" not in first
    assert (tmp_path / "beam-diagnosis" / "diagnosis-shape-radius.png").stat().st_size > 10_000
    # with the user's ten lines: named first, and within noise
    assert "Most likely missing: beam_falloff" in second
    assert "With active+beam_falloff every statistic is within noise" in second
    # the fitted exponent agrees with the simulated one within 3 standard errors
    n, se = map(float, re.search(r"beam_falloff\.n = ([0-9.]+) \+/- ([0-9.e-]+)", fit).groups())
    truth = json.loads((tmp_path / "beam.answer.json").read_text())["parameters"]["n"]
    assert abs(n - truth) < 3 * se, (n, se, truth)
    assert "every statistic within noise" in fit
