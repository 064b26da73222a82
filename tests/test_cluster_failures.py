"""A fleet on a real Dask cluster (`--scheduler`): relative paths reach workers that run in another working
directory. The scheduler runs in this process (distributed.LocalCluster, TCP)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from simrig import record_perpendicular


def _fleet(folder: Path, seeds=(1, 2)) -> Path:
    folder.mkdir(parents=True)
    for s in seeds:
        record_perpendicular(folder / f"cam-{s}.h5", seed=s, width=16, frames=4, stops_m=[0.5, 1.0, 2.0])
    return folder


def _cluster(workers: int):
    from distributed import LocalCluster

    return LocalCluster(n_workers=workers, threads_per_worker=1, processes=False, dashboard_address=None,
                        protocol="tcp://")


@pytest.mark.slow
def test_relative_paths_reach_workers_in_another_working_directory(tmp_path, monkeypatch):
    """rig runs in lab/ and names lab/fleet as `fleet`; the cluster's workers (threads of this process) run in
    elsewhere/, where `fleet` does not exist. `rig fit --many fleet` and the fits of `rig compare` and `rig
    repeatability` (`fit_all_for_comparison`, without their plots) work there, and report each recording as given."""
    lab, elsewhere = tmp_path / "lab", tmp_path / "elsewhere"
    _fleet(lab / "fleet")
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    in_lab = ("import json, sys; from rig.cli import main; a = sys.argv[1]; "
              "print('status', main(['fit', '--many', 'fleet', '--json', '--scheduler', a]), flush=True); "
              "from rig.fleet.many import fit_all_for_comparison; from rig.recordings.recording_fits import FitJob; "
              "jobs = [FitJob(p) for p in ('fleet/cam-1.h5', 'fleet/cam-2.h5', './fleet/cam-1.h5')]; "
              "print(json.dumps(sorted((r.path, r.error, r.values['lambda']) for r in fit_all_for_comparison(jobs, "
              "scheduler=a))))")
    with _cluster(workers=1) as cluster:
        r = subprocess.run([sys.executable, "-c", in_lab, cluster.scheduler_address], cwd=lab, capture_output=True,
                           text=True, timeout=120)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    fitted, compared = r.stdout.split("status ")
    docs = [json.loads(line) for line in fitted.splitlines()]
    assert sorted(d["file"] for d in docs) == ["fleet/cam-1.h5", "fleet/cam-2.h5"]
    assert all(d["fits"][0]["values"]["lambda"] > 0 for d in docs) and compared.startswith("0\n")
    fits = json.loads(compared[2:])
    assert [f[:2] for f in fits] == [["./fleet/cam-1.h5", ""], ["fleet/cam-1.h5", ""], ["fleet/cam-2.h5", ""]]
    assert fits[0][2] == fits[1][2] > 0  # one fit of cam-1, reported under both of its names
