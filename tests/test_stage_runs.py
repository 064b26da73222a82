"""A perpendicular experiment end to end: fake camera, real driver, real pyserial, simulated
GRBL or Zaber controller on a pseudo-terminal. Faults injected mid-run stop it with a clear
one-line message that keeps the completed stops, and --resume records the rest."""

from __future__ import annotations

import numpy as np
import pytest

from fakes.grbl_sim import GrblSim
from fakes.zaber_sim import ZaberSim
from protocols import Runner, RunError, perpendicular
from protocols.runner import ProgressEvent
from rig.cli import main
from rig.devices import open_devices
from protocols.recording import Recording

pytestmark = pytest.mark.slow


STOPS = [0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0]
CAMERA = "fake:width=16,height=9,depth_unit_mm=0.1"
FAST = "settle=0&timeout_s=0.5&poll_s=0.01"


def start_sim(kind: str):
    sim = (GrblSim if kind == "grbl" else ZaberSim)(speed_mm_s=20000.0)
    return sim.start()


def stage_string(kind: str, port: str) -> str:
    # GRBL: ask for more feed than the controller's $110 allows; the driver caps it there (fast here)
    return f"{kind}://{port}?offset_m=0.3&{FAST}" + ("&feed=1200000" if kind == "grbl" else "")


@pytest.mark.parametrize("kind", ["grbl", "zaber"])
def test_perpendicular_run_records_the_planned_positions(tmp_path, kind):
    sim = start_sim(kind)
    try:
        devices = open_devices(CAMERA, stage_string(kind, sim.port))
        Runner(devices.camera, devices.stage).run(perpendicular(frames_per_stop=4, settle_s=0.0), tmp_path / "r.h5")
    finally:
        sim.stop()
    with Recording(tmp_path / "r.h5") as rec:
        stops = list(rec.stops())
        assert f'"kind": "stage"' in rec.attrs["stage"] and kind in rec.attrs["stage"]
    assert [s.commanded_position_m for s in stops] == STOPS
    for s in stops:
        assert abs(s.measured_position_m - s.commanded_position_m) < 0.001
        # the fake camera followed the stage: the wall is where the stage says
        assert np.nanmedian(s.stats.mean_m) == pytest.approx(s.measured_position_m, rel=0.005)  # ~1 s.e. at 3 m


FAULTS = [
    ("grbl", "drop_reply", {"count": 3}, "no reply to"),
    ("grbl", "noise", {"count": 3}, "garbled, the last"),
    ("grbl", "unplug", {}, "port disconnected"),
    ("grbl", "position_error", {"mm": 5.0}, "commanded 1.2500 m but measured"),
    ("grbl", "hard_limit", {}, "ALARM:1"),
    ("zaber", "drop_reply", {}, "no reply to"),
    ("zaber", "noise", {}, "garbled reply"),
    ("zaber", "unplug", {}, "port disconnected"),
    ("zaber", "position_error", {"mm": 5.0}, "commanded 1.2500 m but measured"),
    ("zaber", "stall", {}, "stalled"),
]


@pytest.mark.parametrize("fault", ["noise", "drop_reply"])
def test_one_glitch_mid_run_is_asked_again_and_the_run_finishes(tmp_path, fault):
    # GRBL: a garbled or unanswered status report while the carriage moves is asked for again
    sim = start_sim("grbl")
    armed = []

    def arm_while_moving(e: ProgressEvent):
        if e.kind == "stop_done" and e.stop_index == 2 and not armed:
            armed.append(True)
            sim.inject(fault, count=1)  # the next reply (the move's 'ok' or a status report) is lost or garbled

    try:
        devices = open_devices(CAMERA, stage_string("grbl", sim.port))
        result = Runner(devices.camera, devices.stage, progress=arm_while_moving).run(
            perpendicular(frames_per_stop=4, settle_s=0.0), tmp_path / "r.h5")
    finally:
        sim.stop()
    assert armed and len(result.recorded) == len(STOPS)
    with Recording(tmp_path / "r.h5") as rec:
        assert all(abs(s.measured_position_m - s.commanded_position_m) < 1e-6 for s in rec.stops())


@pytest.mark.parametrize("kind,fault,params,phrase", FAULTS, ids=[f"{k}-{f}" for k, f, _, _ in FAULTS])
def test_fault_mid_run_keeps_completed_stops_and_resume_finishes(tmp_path, kind, fault, params, phrase):
    path = tmp_path / "r.h5"
    plan = perpendicular(frames_per_stop=4, settle_s=0.0)
    sim = start_sim(kind)
    armed = []

    def arm_after_third_stop(e: ProgressEvent):
        if e.kind == "stop_done" and e.stop_index == 2 and not armed:
            armed.append(True)
            sim.inject(fault, **params)

    try:
        devices = open_devices(CAMERA, stage_string(kind, sim.port))
        with pytest.raises(RunError) as err:
            Runner(devices.camera, devices.stage, progress=arm_after_third_stop).run(plan, path)
    finally:
        port = sim.port
        sim.stop()
    msg = str(err.value)
    assert msg.startswith(f"{kind} {port}: ") and phrase in msg, msg
    assert "\n" not in msg and msg.count("--resume") == 1
    assert "3 of 11 stops are saved" in msg
    with Recording(path) as rec:
        assert rec.stop_labels() == ["0.500m", "0.750m", "1.000m"]

    sim = start_sim(kind)  # power back on (a new pty: the port may change, as a USB device's can)
    try:
        assert main(["run", "--protocol", "perpendicular", "--frames", "4", "--camera", CAMERA,
                     "--stage", stage_string(kind, sim.port), "-o", str(path), "--resume"]) == 2  # settle_s differs
        devices = open_devices(CAMERA, stage_string(kind, sim.port))
        result = Runner(devices.camera, devices.stage).run(plan, path, resume=True)
    finally:
        sim.stop()
    assert result.skipped == ["0.500m", "0.750m", "1.000m"]
    assert len(result.recorded) == 8
    with Recording(path) as rec:
        assert [s.commanded_position_m for s in rec.stops()] == STOPS


def test_stage_sim_command_serves_a_controller_a_run_can_use(tmp_path):
    import re
    import signal
    import subprocess
    import sys
    from pathlib import Path

    rig = Path(sys.executable).parent / "rig"
    proc = subprocess.Popen([str(rig), "stage-sim", "grbl"], stdout=subprocess.PIPE, stdin=subprocess.PIPE, text=True)
    try:
        first = proc.stdout.readline()
        port = re.search(r"on (/dev/\S+)", first).group(1)
        assert main(["run", "--protocol", "perpendicular", "--frames", "3", "--stops", "0.5,1.0", "--camera", CAMERA,
                     "--stage", stage_string("grbl", port), "-o", str(tmp_path / "s.h5")]) == 0
    finally:
        proc.send_signal(signal.SIGTERM)  # as a supervisor would; SIGINT may be ignored in background jobs
        proc.wait(timeout=10)
    assert proc.returncode == 0 and "stopped" in proc.stdout.read()
    with Recording(tmp_path / "s.h5") as rec:
        assert [s.commanded_position_m for s in rec.stops()] == [0.5, 1.0]
