"""What `rig fit` and `rig diagnose` write besides their printout: outputs checked before the work starts,
the per-stop table (`fit --table`), and the HTML report's metadata. Real commands on one small recording."""

import subprocess
import sys
from pathlib import Path

import pytest

from rig.reports.writable import output_problem
from simrig import record_perpendicular

RIG = str(Path(sys.executable).parent / "rig")


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("outputs") / "small.h5"
    record_perpendicular(path, width=32, frames=8, stops_m=[0.5, 1.0, 1.5, 2.0])
    return path


@pytest.mark.parametrize("args,option", [
    (["diagnose", "{rec}", "--out", "{file}/report"], "the report to"),
    (["diagnose", "{rec}", "--out", "{file}"], "the report to"),
    (["fit", "{rec}", "--plot", "{file}/fit.png"], "--plot"),
    (["fit", "{rec}", "--model", "active", "--plot", "{file}/fit.png"], "--plot"),
    (["validate-diagnosis", "--seeds", "1", "--effects", "none", "--json", "{file}/trials.json"], "--json"),
])
def test_an_unwritable_output_fails_at_once_in_one_line(recording, tmp_path, args, option):
    """A path through a regular file cannot be written by anyone, root included: the command says so before
    it reads the recording (with -v every step it began would be listed on stderr)."""
    regular = tmp_path / "a-file"
    regular.write_text("not a folder")
    args = [a.replace("{rec}", str(recording)).replace("{file}", str(regular)) for a in args]
    r = subprocess.run([RIG, "-v", *args], capture_output=True, text=True)
    assert r.returncode == 2
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"rig: error: cannot write {option}"), r.stderr
    assert f"{regular} is a file" in lines[0] and "you can write to" in lines[0]
    assert r.stdout == "" and regular.read_text() == "not a folder"


def test_a_writable_output_is_tried_and_left_clean(tmp_path):
    assert output_problem(tmp_path / "new" / "deeper" / "fit.png") is None
    assert output_problem(tmp_path / "report", folder=True) is None
    assert list(tmp_path.iterdir()) == []  # the test file is gone and no folder was made
    assert "is a folder, not a file" in output_problem(tmp_path)
