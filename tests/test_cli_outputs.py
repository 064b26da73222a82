"""What `rig fit` and `rig diagnose` write besides their printout: outputs checked before the work starts,
the per-stop table (`fit --table`), and the HTML report's metadata. The commands run in this process
(tests/cli_in_process.py) on one small recording."""

from pathlib import Path

import numpy as np
import pytest
from cli_in_process import rig_in_process

from rig.reports.writable import output_problem

pytestmark = pytest.mark.slow


@pytest.fixture
def recording(small_recording) -> Path:
    return small_recording


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
    r = rig_in_process("-v", *args)
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


@pytest.mark.numeric
def test_fit_table_reads_back_as_the_fit(recording, tmp_path):
    import csv
    import json

    from rig.analysis import fit_recording

    table = tmp_path / "tables" / "stops.csv"
    r = rig_in_process("fit", recording, "--table", table)
    assert r.returncode == 0 and f"table: {table}" in r.stdout
    with open(table, newline="") as f:
        rows = list(csv.DictReader(f))
    fit = fit_recording(recording)
    assert list(rows[0]) == ["stop", "range_m", "pixels", "samples", "measured_sigma_m", "model_sigma_m", "fill_rate",
                             "truth_m", "truth_source", "depth_accuracy_pct", "depth_accuracy_se_pct", "spatial_rms_m",
                             "spatial_rms_noise_m", "model_bias_m"]
    assert [row["stop"] for row in rows] == ["0.500m", "1.000m", "1.500m", "2.000m"] == fit.measured.label
    assert sum(int(row["pixels"]) for row in rows) == fit.fit.n_pixels
    assert sum(int(row["samples"]) for row in rows) == fit.fit.n_samples
    # the table sums each stop's pixels chunk by chunk, the fit's pooled sigma all at once: the same k terms added in
    # other orders, each sum within (k - 1) u of exact; the range is a ratio of two sums, within (4 k - 2) u of the
    # fit's, sigma the root of one, within (2 k + 1) u (the numbers are written as Python writes them: they read back
    # exactly). 2.6e-13 and 1.3e-13 for these 576 pixels a stop; abs=0: pytest.approx's 1e-12 would be 1e-8 of sigma
    u = np.finfo(np.float64).eps / 2
    for row, z, sigma in zip(rows, fit.measured.z_m, fit.measured.sigma_m):
        k = int(row["pixels"])
        assert float(row["range_m"]) == pytest.approx(z, rel=(4 * k - 2) * u, abs=0)
        assert float(row["measured_sigma_m"]) == pytest.approx(sigma, rel=(2 * k + 1) * u, abs=0)
        assert float(row["model_sigma_m"]) == pytest.approx(fit.fit.sigma_m(z), rel=2e-3)  # k Z^lambda at the stop
        assert 0.5 < float(row["fill_rate"]) <= 1.0
    with_model = rig_in_process("fit", recording, "--model", "active", "--no-held-out", "--json", "--table",
                                tmp_path / "active.csv")
    assert with_model.returncode == 0 and json.loads(with_model.stdout)["fits"][0]["model"] == "active"
    assert "table: " in with_model.stderr  # stdout holds the JSON alone
    with open(tmp_path / "active.csv", newline="") as f:
        active = list(csv.DictReader(f))
    assert [a["stop"] for a in active] == [row["stop"] for row in rows]
    k_active = [float(a["model_sigma_m"]) / float(a["range_m"]) ** 3 for a in active]  # active: k Z^3 at each stop
    assert max(k_active) == pytest.approx(min(k_active), rel=1e-3)


def test_fit_table_to_an_unwritable_place_fails_at_once(recording, tmp_path):
    regular = tmp_path / "a-file"
    regular.write_text("")
    r = rig_in_process("fit", recording, "--table", regular / "stops.csv")
    assert r.returncode == 2 and r.stderr.startswith("rig: error: cannot write --table") and r.stdout == ""


def test_the_html_report_carries_the_runs_metadata(recording, tmp_path):
    import datetime as dt
    from html.parser import HTMLParser
    from importlib.metadata import version

    from protocols.recording import Recording

    class RunRows(HTMLParser):
        def __init__(self):
            super().__init__()
            self.rows, self.key, self.in_td = {}, None, False

        def handle_starttag(self, tag, attrs):
            attrs = dict(attrs)
            if tag == "tr" and "data-key" in attrs:
                self.key = attrs["data-key"]
            self.in_td = tag == "td" and self.key is not None

        def handle_endtag(self, tag):
            if tag == "tr":
                self.key = None
            self.in_td = False

        def handle_data(self, data):
            if self.in_td:
                self.rows[self.key] = self.rows.get(self.key, "") + data

    r = rig_in_process("diagnose", recording, "--out", tmp_path / "report")
    assert r.returncode == 0, r.stderr
    page = RunRows()
    page.feed((tmp_path / "report" / "diagnosis.html").read_text())
    run = page.rows
    with Recording(recording) as rec:
        started, ended = rec.attrs["started_utc"], rec.attrs["ended_utc"]
    assert run["file"] == str(recording) and run["recorded_utc"] == f"{started} to {ended}"
    made = dt.datetime.fromisoformat(run["report_utc"])
    assert abs((dt.datetime.now(dt.timezone.utc) - made).total_seconds()) < 600
    assert run["rig_version"] == version("rig") == run["recorded_with"]
    assert run["camera_model"] == "Fake D435 (simulated)" and run["camera_serial"] == "FAKE-0001"
    assert run["camera_firmware"] == "sim"
    assert run["exposure"] == "3300 us" and run["gain"] == "32" and run["projector"] == "on"
    assert run["stage"] == "fake-stage, travel 0.3-3.5 m (simulated)" and run["protocol"] == "perpendicular"
    assert run["stops"] == "4: 0.500m, 1.000m, 1.500m, 2.000m; 8 frames each"
