"""A plan is checked whole before the stage is homed or anything is written (protocols/plan_check.py), and a
resumed run may change the stops it has not recorded yet. Real files, the fake camera at a small width, the
fake stage with a given travel, and a GRBL simulator on a pty for a stage whose travel is known only once open."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import h5py
import pytest

from fakes.grbl_sim import GrblSim
from protocols import Runner, RunError, perpendicular
from protocols.plan_check import (PlanError, RigLimits, check_plan, disk_need_bytes, plan_problems, resume_problems,
                                  stop_recipes, value_problem)
from protocols.recording import Recording
from protocols.runner import ProgressEvent, RunControl
from protocols.stop_journal import completed_stop_files, journal_dir
from rig.cli import main
from rig.devices import open_devices

CAMERA = "fake:width=106,height=60"


def rig_run(capsys, *args: str) -> tuple[int, str]:
    """`rig run ...` in this process; (exit status, the last line on stderr)."""
    code = main(["run", "--protocol", "perpendicular", "--camera", CAMERA, "--frames", "5", *args])
    err = capsys.readouterr().err.strip().splitlines()
    return code, err[-1] if err else ""


def nothing_written(path: Path) -> bool:
    return not path.exists() and not journal_dir(path).exists()


# -- the whole plan before homing -------------------------------------------------------------


def test_the_issues_plan_is_refused_before_homing_with_nothing_recorded(tmp_path, capsys):
    out = tmp_path / "a.h5"
    code, line = rig_run(capsys, "--stops", "0.5,4.0", "-o", str(out))  # the fake stage's travel: 0.3-3.5 m
    assert code == 2
    assert line.startswith("rig: error: the plan cannot finish on this rig: stops_m: 4.000 m is outside the travel "
                           "of fake-stage, 0.300-3.500 m; give stops within 0.300-3.500 m"), line
    assert line.endswith("nothing was recorded") and "--resume" not in line
    assert nothing_written(out)
    # the stage is never homed: the check comes first
    devices = open_devices(CAMERA, "fake:min_m=0.3,max_m=2.0")
    with pytest.raises(RunError, match=r"stops_m: 2.500 m, 3.000 m are outside the travel of fake-stage, 0.300-2.000 m"):
        Runner(devices.camera, devices.stage, sleep=devices.sleep).run(
            perpendicular(stops_m=[0.5, 2.5, 3.0], frames_per_stop=5), out)
    assert not devices.stage._homed and nothing_written(out)


def test_a_serial_stage_is_checked_once_open_and_before_it_homes(tmp_path):
    sim = GrblSim(travel_mm=1000.0, speed_mm_s=20000.0).start()  # with offset 0.3 m: about 0.3-1.3 m
    try:
        devices = open_devices(CAMERA, f"grbl://{sim.port}?offset_m=0.3&settle=0&timeout_s=0.5&poll_s=0.01")
        with pytest.raises(RunError) as err:
            Runner(devices.camera, devices.stage).run(perpendicular(stops_m=[0.5, 1.0, 2.0], frames_per_stop=3),
                                                      tmp_path / "g.h5")
        assert not sim.homed  # the controller never saw $H
    finally:
        sim.stop()
    msg = str(err.value)
    assert "stops_m: 2.000 m is outside the travel of grbl" in msg and "\n" not in msg, msg
    assert nothing_written(tmp_path / "g.h5")


def test_travel_read_from_the_controller_names_130(tmp_path):
    # stock settings: $130=200 mm, so 0.3-0.5 m with homing=0; the fix names the setting a user has to change
    sim = GrblSim.stock(start_mm=0.0).start()
    try:
        devices = open_devices(CAMERA, f"grbl://{sim.port}?offset_m=0.3&homing=0&settle=0&timeout_s=0.5&poll_s=0.01")
        with pytest.raises(RunError) as err:
            Runner(devices.camera, devices.stage).run(perpendicular(stops_m=[0.4, 1.0], frames_per_stop=3),
                                                      tmp_path / "t.h5")
    finally:
        sim.stop()
    msg = str(err.value)
    assert "1.000 m is outside the travel of grbl" in msg, msg
    assert "raise the controller's $130 (X max travel, now 200 mm)" in msg and "nothing was recorded" in msg, msg


@pytest.mark.parametrize("device_options,fixes", [
    ("homing=0", ["$20=0", "homing=1", "rail_min_mm=-1000&travel_mm=1000"]),
    ("homing=1&rail_min_mm=0&travel_mm=500", ["make rail_min_mm and travel_mm lie within them"]),
])
def test_soft_limits_the_rail_cannot_respect_are_refused_before_anything_moves(tmp_path, device_options, fixes):
    # $22=1 $20=1 on the controller: soft limits allow machine X -1000..0 only. Without homing the rail runs from
    # MPos 0 towards +X, so the first move would end in ALARM:2; the plan check knows it before anything moves
    sim = GrblSim(travel_mm=1000.0, speed_mm_s=20000.0, homing=True, soft_limits=True).start()
    try:
        devices = open_devices(CAMERA, f"grbl://{sim.port}?offset_m=0.3&{device_options}&settle=0&timeout_s=0.5"
                                       "&poll_s=0.01")
        with pytest.raises(RunError) as err:
            Runner(devices.camera, devices.stage).run(perpendicular(stops_m=[0.5, 1.0], frames_per_stop=3),
                                                      tmp_path / "s.h5")
        assert not sim.homed and not any(c.startswith("G21 G53 G1") for c in sim.commands)  # nothing moved
        assert not sim.critical
    finally:
        sim.stop()
    msg = str(err.value)
    assert "soft limits are on ($20=1) and allow machine X only within -1000..0 mm" in msg, msg
    assert "ALARM:2" in msg and "\n" not in msg and "nothing was recorded" in msg
    for fix in fixes:
        assert fix in msg, (fix, msg)
    assert nothing_written(tmp_path / "s.h5")


def test_every_problem_is_listed_in_one_line():
    plan = perpendicular(stops_m=[0.5, 4.0], frames_per_stop=5)
    with pytest.raises(PlanError) as err:
        check_plan(plan, RigLimits((0.3, 3.5), "rail", (60, 106)), output=Path("/proc/version/run.h5"))
    assert len(err.value.problems) == 2 and "\n" not in str(err.value)
    assert "4.000 m is outside the travel of rail" in err.value.problems[0]
    assert "is a file, not a folder" in err.value.problems[1]


def test_values_are_checked_by_the_protocols_own_rules():
    assert "at least 2 frames are needed for a variance" in value_problem("perpendicular", "frames_per_stop", 1)
    assert "outside 0 to 75 degrees" in value_problem("tilted", "tilt_deg", 80.0)
    assert "outside 0.05 to 100 m" in value_problem("perpendicular", "stops_m", [0.5, 300.0])
    assert value_problem("perpendicular", "frames_per_stop", 300) is None
    # a plan built by hand is held to the same rules as one from a file
    from drivers.camera import CameraSettings
    from protocols.plan import Capture, Configure, Move, Plan

    def steps():
        yield Configure(CameraSettings())
        yield Move(1.0)
        yield Capture("one", 1)
    assert "at least 2 frames" in plan_problems(Plan("mine", {}, steps))[0]


def test_an_output_that_cannot_be_written_is_refused_before_the_devices_open(tmp_path, capsys):
    (tmp_path / "file").write_text("")
    code, line = rig_run(capsys, "--stops", "0.5,1.0", "-o", str(tmp_path / "file" / "run.h5"))
    assert code == 2 and "is a file, not a folder; choose another output file" in line, line
    code, line = rig_run(capsys, "--stops", "0.5,1.0", "-o", str(tmp_path))
    assert code == 2 and "is a folder; give a file name in it" in line, line
    if os.geteuid() == 0:  # root writes anywhere, except on a read-only file system
        ro = tmp_path / "ro"
        ro.mkdir()
        if subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)]).returncode == 0:
            try:
                code, line = rig_run(capsys, "--stops", "0.5,1.0", "-o", str(ro / "run.h5"))
            finally:
                subprocess.run(["umount", "-l", str(ro)])
            assert code == 2 and "cannot be written (read-only or no permission)" in line, line
    else:
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o500)
        code, line = rig_run(capsys, "--stops", "0.5,1.0", "-o", str(ro / "run.h5"))
        assert code == 2 and "cannot be written (read-only or no permission)" in line, line


# -- the disk ---------------------------------------------------------------------------------


def test_a_plan_too_big_for_the_free_disk_is_refused_before_it_starts(tmp_path, capsys):
    args = ["--stops", "0.5,1.0,1.5,2.0,2.5,3.0"]
    if os.geteuid() == 0:
        disk = tmp_path / "disk"
        disk.mkdir()
        assert subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1500k", "tmpfs", str(disk)]).returncode == 0
        try:
            code, line = rig_run(capsys, *args, "-o", str(disk / "run.h5"))
            left = list(disk.iterdir())
        finally:
            subprocess.run(["umount", "-l", str(disk)])
        assert left == []  # not even a lock file
        assert "MB are free in " + str(disk) in line
    else:  # raw frames of a full-size image, a million a stop: more than any disk here holds
        code, line = main(["run", "--protocol", "perpendicular", "--camera", "fake:", "--frames", "1000000",
                           *args, "-o", str(tmp_path / "run.h5")]), capsys.readouterr().err.strip().splitlines()[-1]
        assert nothing_written(tmp_path / "run.h5")
    assert code == 2
    assert "disk: the recording needs up to" in line and "6 stops" in line and "nothing was recorded" in line, line
    assert "free about" in line and "record fewer stops or frames" in line


def test_the_disk_estimate_bounds_what_a_run_really_takes(tmp_path):
    """The estimate is an upper bound of the peak (the stop files and the assembled copy side by side),
    and not wildly above it."""
    path = tmp_path / "r.h5"
    plan = perpendicular(stops_m=[0.5, 1.0, 1.5, 2.0], frames_per_stop=10)
    journal_bytes = []

    def watch(e: ProgressEvent):
        if e.kind == "stop_done" and e.stop_index == 3:
            journal_bytes.append(sum(p.stat().st_size for p in completed_stop_files(path).values()))

    devices = open_devices("fake:width=212,height=120", "fake:")
    Runner(devices.camera, devices.stage, sleep=devices.sleep, progress=watch).run(plan, path)
    peak = journal_bytes[0] + path.stat().st_size  # just before the stop files are removed
    estimate = disk_need_bytes(stop_recipes(plan), (120, 212), path)
    assert peak <= estimate < 3 * peak, (peak, estimate)


# -- resuming with another plan ---------------------------------------------------------------


def record_first_stop(path: Path, stops: list[float]) -> None:
    """Record the first stop of `stops`, then abort (as a power cut would leave it)."""
    control = RunControl()
    devices = open_devices(CAMERA, "fake:")
    Runner(devices.camera, devices.stage, sleep=devices.sleep, control=control,
           progress=lambda e: control.abort.set() if e.kind == "stop_done" else None).run(
        perpendicular(stops_m=stops, frames_per_stop=5), path)


def test_a_stranded_stop_is_rescued_by_resume_with_corrected_stops(tmp_path, capsys):
    out = tmp_path / "a.h5"
    record_first_stop(out, [0.5, 1.0])
    # what rig before this check left: the header plans 4.0 m, beyond the rail, with 0.5 m recorded
    with h5py.File(out, "a") as f:
        f.attrs["protocol_params"] = json.dumps({**json.loads(f.attrs["protocol_params"]), "stops_m": [0.5, 4.0]})
    code, line = rig_run(capsys, "--stops", "0.5,4.0", "-o", str(out), "--resume")
    assert code == 2 and "4.000 m is outside the travel of fake-stage, 0.300-3.500 m" in line, line
    assert f"{out} is unchanged (it keeps 1 recorded stop, which must stay in the plan); correct the plan" in line
    code, line = rig_run(capsys, "--stops", "0.5,3.0", "-o", str(out), "--resume")
    assert code == 0, line
    with Recording(out) as rec:
        assert rec.stop_labels() == ["0.500m", "3.000m"] and rec.notes() == []
        assert rec.protocol_params["stops_m"] == [0.5, 3.0]
        history = json.loads(rec.attrs["plan_history"])
        assert history[0]["protocol_params"]["stops_m"] == [0.5, 4.0]


def test_later_stops_may_change_recorded_ones_may_not(tmp_path, capsys):
    out = tmp_path / "b.h5"
    record_first_stop(out, [0.5, 1.0, 1.5])
    # dropping the recorded stop, or changing what applies to it, is refused, naming the setting
    code, line = rig_run(capsys, "--stops", "1.0,1.5", "-o", str(out), "--resume")
    assert code == 2 and "stop 0.500m is recorded but stops_m now leaves it out" in line, line
    code, line = main(["run", "--protocol", "perpendicular", "--camera", CAMERA, "--frames", "6", "--stops",
                       "0.5,1.0,1.5", "-o", str(out), "--resume"]), capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and "(plan frames_per_stop 5 in the file, 6 now)" in line, line
    code, line = rig_run(capsys, "--stops", "0.5,1.0,1.5", "--gain", "32", "-o", str(out), "--resume")
    assert code == 2 and "plan gain 16.0 in the file, 32.0 now" in line, line
    with Recording(out) as rec:
        assert rec.stop_labels() == ["0.500m"] and rec.protocol_params["stops_m"] == [0.5, 1.0, 1.5]
    # moving, adding and dropping stops not yet recorded is accepted
    code, _ = rig_run(capsys, "--stops", "0.5,2.0,2.5,3.0", "-o", str(out), "--resume")
    assert code == 0
    with Recording(out) as rec:
        assert rec.stop_labels() == ["0.500m", "2.000m", "2.500m", "3.000m"] and rec.assembled


def test_resume_rules_without_a_file():
    old = perpendicular(stops_m=[0.5, 1.0], frames_per_stop=5).params
    assert resume_problems("perpendicular", old, perpendicular(stops_m=[0.5, 2.0], frames_per_stop=5), {"0.500m"}) == []
    assert resume_problems("perpendicular", old, perpendicular(stops_m=[1.0], frames_per_stop=9), set()) == []
    assert resume_problems("tilted", old, perpendicular(frames_per_stop=5), {"0.500m"}) == [
        "protocol 'tilted' in the file, 'perpendicular' now"]
    from protocols import tilted

    t = tilted(frames=5).params
    assert resume_problems("tilted", t, tilted(frames=5, distance_m=1.0), {"tilted"}) == [
        "stop tilted is recorded but would be recorded differently now: distance_m 0.8 in the file, 1.0 now"]
