"""rig fit --many DIR: every recording of a folder fitted in a pool of processes, each as `rig fit` fits it alone."""

import json
from pathlib import Path

import pytest

from json_schema import validate
from rig.analysis import fit_recording
from rig.cli import main
from simrig import record_perpendicular

SCHEMA = json.loads((Path(__file__).resolve().parents[1] / "docs" / "json-schema.json").read_text())


@pytest.fixture(scope="module")
def shelf(tmp_path_factory) -> Path:
    """Three cameras' recordings and a file that is not one."""
    folder = tmp_path_factory.mktemp("shelf")
    for seed in (1, 2, 3):
        record_perpendicular(folder / f"camera-{seed}.h5", seed=seed, width=24, frames=8, stops_m=[0.5, 1.0, 2.0])
    (folder / "notes.h5").write_text("not a recording")
    return folder


def test_every_recording_is_fitted_as_alone_and_a_bad_one_is_one_line(shelf, capsys):
    assert main(["fit", "--many", str(shelf), "--jobs", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    by_name = {ln.split()[0]: ln for ln in lines[1:]}
    assert set(by_name) == {"camera-1.h5", "camera-2.h5", "camera-3.h5", "notes.h5"}
    assert "error:" in by_name["notes.h5"] and "not an HDF5 file" in by_name["notes.h5"]
    for name in ("camera-1.h5", "camera-2.h5", "camera-3.h5"):
        alone = fit_recording(shelf / name).fit
        assert by_name[name].split()[1:5] == [f"{alone.k:.6g}", f"{alone.se_k:.2g}", f"{alone.lam:.5f}", f"{alone.se_lam:.2g}"]


def test_json_is_one_schema_document_a_line(shelf, capsys):
    assert main(["fit", "--many", str(shelf), "--json"]) == 0
    docs = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    good = [d for d in docs if "schema" in d]
    assert len(good) == 3 and all(validate(d, SCHEMA) == [] for d in good)
    assert {Path(d["file"]).name for d in good} == {"camera-1.h5", "camera-2.h5", "camera-3.h5"}
    assert [d for d in docs if "error" in d][0]["file"].endswith("notes.h5")


def test_a_file_is_not_a_folder(shelf, capsys):
    assert main(["fit", "--many", str(shelf / "camera-1.h5")]) == 2
    assert "--many takes a folder" in capsys.readouterr().err


@pytest.mark.slow
def test_a_reader_that_stops_early_ends_it_quietly(shelf):
    """`rig fit --many DIR --json | head -1`: the pipe closes after the first line; rig stops without a traceback."""
    import subprocess
    import sys

    rig = str(Path(sys.executable).parent / "rig")
    r = subprocess.run(f"'{rig}' fit --many '{shelf}' --json --jobs 1 | head -c 10", shell=True, capture_output=True,
                       text=True, executable="/bin/bash")
    assert r.stdout.startswith("{"), r.stdout
    assert "Traceback" not in r.stderr and "BrokenPipe" not in r.stderr, r.stderr
