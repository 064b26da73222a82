"""The GRBL driver against the real GRBL 1.1h firmware (grbl-sim, tests/grbl_firmware.py), not our simulator.

Whole runs (fake camera, Runner, real pyserial on the firmware's pty) on the settings a lab meets: stock ones with
$130 raised to the rail, inches, a startup line, work positions in reports, soft limits with and without homing.
Then the ways a run fails mid-move (a hold pressed on the controller, a reset, a link that stays garbled, a stalled
link, an unplugged controller): the firmware must never answer ALARM:3 to the driver's stop, and --resume must
finish with the positions right. "Right" is checked twice: the driver's measured position against the commanded
one, and the carriage's physical place on the simulated rail (CARRIAGE.TXT, which the firmware's step pulses
move) against where that distance puts it.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from grbl_firmware import GrblFirmware, require_firmware
from protocols import Runner, RunError, perpendicular
from protocols.recording import Recording
from protocols.runner import ProgressEvent
from rig.devices import open_devices

CAMERA = "fake:width=16,height=9,depth_unit_mm=0.1"
DRIVER = "settle=0&timeout_s=0.5&poll_s=0.02"
#: 100 mm/s at 500 mm/s^2: the moves of these tests take under a second
FAST = {110: 6000, 120: 500}
#: homing on the rail's +X switch ($23=0, stock), quick enough for a test
HOMING = {22: 1, 25: 3000, 24: 300, 27: 2}
RAIL_MM = 300.0
OFFSET_M = 0.5

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("firmware_built")]


@pytest.fixture(scope="module")
def firmware_built():
    require_firmware()


def rail_x_mm(fw: GrblFirmware, position_m: float, *, homing: bool, x0_mm: float, pulloff_mm: float = 2.0) -> float:
    """Where the carriage must be on the rail (mm from its -X end) for a camera-to-wall distance: without homing,
    MPos 0 is where it was at power-up and the rail runs to +X; with homing towards +X, rail zero is the +X switch
    less the pull-off and the rail runs to -X (docs/stages.md)."""
    rail_mm = (position_m - OFFSET_M) * 1000.0
    return (fw.rail_mm - pulloff_mm - rail_mm) if homing else x0_mm + rail_mm


class Run:
    """A perpendicular run against the firmware that notes where the carriage physically is at each stop."""

    def __init__(self, fw: GrblFirmware, path: Path, stops: list[float], options: str = ""):
        self.fw, self.path, self.stops, self.options = fw, path, stops, options
        self.physical: dict[float, float] = {}
        #: called with each stop's distance once the stage is there, before its capture
        self.at_stop = lambda z: None

    def __call__(self, *, resume: bool = False) -> list[str]:
        devices = open_devices(CAMERA, f"grbl://{self.fw.port}?offset_m={OFFSET_M}&{DRIVER}&{self.options}")

        def note(e: ProgressEvent) -> None:
            if e.kind == "stop_start":  # the stage has arrived and the capture begins
                self.physical[self.stops[e.stop_index]] = self.fw.physical_x_mm()
                self.at_stop(self.stops[e.stop_index])

        plan = perpendicular(stops_m=self.stops, frames_per_stop=2, settle_s=0.0)
        return Runner(devices.camera, devices.stage, progress=note).run(plan, self.path, resume=resume).recorded

    def check_positions(self, *, homing: bool, x0_mm: float) -> None:
        with Recording(self.path) as rec:
            stops = list(rec.stops())
        assert [s.commanded_position_m for s in stops] == self.stops
        for s in stops:
            assert s.measured_position_m == pytest.approx(s.commanded_position_m, abs=1e-6)
        for z, x in self.physical.items():  # the steps the firmware sent put the carriage there, to a step (4 um)
            assert x == pytest.approx(rail_x_mm(self.fw, z, homing=homing, x0_mm=x0_mm), abs=0.01), z


class Trigger(threading.Thread):
    """`action()`, run `delay_s` after the client has sent the move to machine X `x_mm` (`when_moving_to`)."""

    def __init__(self, fw: GrblFirmware, x_mm: float, delay_s: float, action, wait_s: float = 60.0) -> None:
        super().__init__(daemon=True)
        self.fw, self.pattern = fw, f"G53 G1 X{x_mm:.3f} ".encode()
        self.delay_s, self.action, self.wait_s = delay_s, action, wait_s
        self.fired = False

    def run(self) -> None:
        deadline = time.monotonic() + self.wait_s
        while self.pattern not in self.fw.sent_bytes():
            if time.monotonic() > deadline:
                return
            time.sleep(0.01)
        time.sleep(self.delay_s)
        self.action()
        self.fired = True

    def done(self) -> None:
        """Fail, naming what was waited for, if the move never came (the fault was never injected)."""
        self.join(timeout=5.0)
        assert self.fired, (f"the client never sent {self.pattern.decode().strip()!r} within {self.wait_s:g} s (or the "
                            f"action did not end within 5 s after): the fault was not injected; sent so far: "
                            f"{self.fw.sent_bytes()[-200:]!r}")


def when_moving_to(fw: GrblFirmware, x_mm: float, delay_s: float, action) -> Trigger:
    """Run `action()` `delay_s` after the client has sent the move to machine X `x_mm`; `.done()` checks it ran."""
    trigger = Trigger(fw, x_mm, delay_s, action)
    trigger.start()
    return trigger


def report(fw: GrblFirmware) -> str:
    """A status report asked for by the harness ('?' alone: in a hold GRBL reads no lines, so no `ok` comes)."""
    asked = fw.now()
    fw.press(b"?")
    return fw.wait_for_line(r"^<", after=asked)


def alarms(fw: GrblFirmware) -> list[str]:
    return [t.data for t in fw.lines if t.data.startswith("ALARM:")]


# --- runs on the settings a lab meets -------------------------------------------------------------------------


def test_a_sweep_on_stock_settings_with_the_travel_raised_to_the_rail(tmp_path):
    # a freshly flashed controller ($110=500 mm/min, $120=10 mm/s^2, no homing, no soft limits) whose $130 was
    # raised to the rail, and a device string that says only homing=0
    with GrblFirmware(tmp_path / "fw", rail_mm=RAIL_MM, x0_mm=5.0, settings={130: RAIL_MM}) as fw:
        run = Run(fw, tmp_path / "s.h5", [0.5, 0.52, 0.54], "homing=0")
        assert run() == ["0.500m", "0.520m", "0.540m"]
        run.check_positions(homing=False, x0_mm=5.0)
        with Recording(run.path) as rec:
            assert '"$110": 500.0' in rec.attrs["stage"] and '"$130": 300.0' in rec.attrs["stage"]
        assert not alarms(fw)


@pytest.mark.parametrize("settings,startup", [
    ({13: 1}, ()),  # reports in inches
    ({}, ("G20",)),  # a startup line leaves the parser in inches; moves are sent with G21
    ({10: 0}, ()),  # work positions (WPos) in reports: MPos = WPos + WCO
    ({10: 2}, ()),  # WPos and the buffer field
    ({10: 3}, ()),  # MPos and the buffer field
], ids=["report-inches", "startup-G20", "wpos", "wpos-buffer", "mpos-buffer"])
def test_report_and_parser_settings_are_read_right(tmp_path, settings, startup):
    with GrblFirmware(tmp_path / "fw", rail_mm=RAIL_MM, x0_mm=5.0, settings={130: RAIL_MM, **FAST, **settings},
                      startup_lines=startup) as fw:
        if 10 in settings and not settings[10] & 1:
            fw.query("G10 L2 P1 X7.5")  # a work offset (G54) a G-code sender left behind: WPos = MPos - 7.5
        run = Run(fw, tmp_path / "s.h5", [0.5, 0.55, 0.6], "homing=0")
        run()
        run.check_positions(homing=False, x0_mm=5.0)
        assert not alarms(fw)


def test_soft_limits_with_homing(tmp_path):
    # $22=1 $20=1: the controller powers up locked in Alarm; the driver homes ($H) on the +X switch, and the
    # rail runs towards -X inside the soft limits (-$130..0)
    settings = {130: RAIL_MM, 20: 1, **HOMING, **FAST}
    with GrblFirmware(tmp_path / "fw", rail_mm=RAIL_MM, x0_mm=150.0, settings=settings) as fw:
        run = Run(fw, tmp_path / "s.h5", [0.5, 0.6, 0.75])
        run()
        run.check_positions(homing=True, x0_mm=150.0)
        assert not alarms(fw)


def test_soft_limits_without_homing_are_refused_before_anything_moves(tmp_path):
    settings = {130: RAIL_MM, 20: 1, **HOMING, **FAST}
    with GrblFirmware(tmp_path / "fw", rail_mm=RAIL_MM, x0_mm=150.0, settings=settings) as fw:
        with pytest.raises(RunError) as err:
            Run(fw, tmp_path / "s.h5", [0.5, 0.6], "homing=0")()
        sent = fw.sent_bytes()
        assert b"G1" not in sent and b"$X" not in sent and b"$H" not in sent  # nothing moved, nothing unlocked
        assert not alarms(fw)
    msg = str(err.value)
    assert "soft limits are on ($20=1) and allow machine X only within -300..0 mm" in msg, msg
    assert "$20=0" in msg and "homing=1" in msg and "nothing was recorded" in msg and "\n" not in msg


# --- failing mid-move without losing the position, and resuming ----------------------------------------------


def fail_mid_move_then_resume(tmp_path, fault, phrase: str, *, options: str = "", settings=None, cleanup=None):
    """Stops 0.5, 0.6, 0.7 m without homing; `fault(fw)` runs 0.3 s into the move to 0.6 m. The run must stop
    with a message containing `phrase`, the firmware must never have said ALARM:3, and --resume must finish with
    every position right."""
    with GrblFirmware(tmp_path / "fw", rail_mm=RAIL_MM, x0_mm=5.0,
                      settings={130: RAIL_MM, 110: 1200, 120: 100, **(settings or {})}) as fw:
        run = Run(fw, tmp_path / "s.h5", [0.5, 0.6, 0.7], f"homing=0&{options}")
        trigger = when_moving_to(fw, 100.0, 0.3, lambda: fault(fw))
        with pytest.raises(RunError) as err:
            run()
        trigger.done()
        if cleanup:
            cleanup(fw)
        fw.clear_faults()
        time.sleep(1.0)  # a hold the driver left in place completes; late bytes arrive
        assert "ALARM:3" not in alarms(fw), [t.data for t in fw.lines][-20:]
        state = report(fw)
        assert state.startswith(("<Idle", "<Hold:0")), state  # stopped where the controller knows it is
        msg = str(err.value)
        assert phrase in msg and "\n" not in msg and "--resume" in msg, msg
        assert run(resume=True) == ["0.600m", "0.700m"]
        run.check_positions(homing=False, x0_mm=5.0)
        assert "ALARM:3" not in alarms(fw)
        return msg


def test_a_hold_pressed_on_the_controller_is_stopped_safely_and_resumed(tmp_path):
    msg = fail_mid_move_then_resume(tmp_path, lambda fw: fw.press(b"!"), "feed hold during", options="stall_s=1")
    assert "a reset once the hold was complete: position kept" in msg, msg


def test_a_link_that_stays_garbled_is_not_reset_blind(tmp_path):
    msg = fail_mid_move_then_resume(tmp_path, lambda fw: fw.garble_status_reports(None, "letter"), "garbled")
    assert "MPPs" in msg and "so the controller was not reset" in msg, msg


def test_a_stalled_link_is_not_reset_blind(tmp_path):
    msg = fail_mid_move_then_resume(tmp_path, lambda fw: fw.stall(6.0), "no reply to '?'",
                                    cleanup=lambda fw: time.sleep(6.0))
    assert "so the controller was not reset" in msg, msg


def test_a_move_never_acknowledged_is_stopped_safely(tmp_path):
    # the move's 'ok' is held past both tries: the move may have started, so the driver holds before it resets
    def hold_the_ok(fw: GrblFirmware) -> None:
        fw.delay_next_reply(2.0, prefix=b"ok")

    with GrblFirmware(tmp_path / "fw", rail_mm=RAIL_MM, x0_mm=5.0, settings={130: RAIL_MM, 110: 1200, 120: 100}) as fw:
        run = Run(fw, tmp_path / "s.h5", [0.5, 0.6, 0.7], "homing=0")
        run.at_stop = lambda z: hold_the_ok(fw) if z == 0.5 else None  # the next 'ok' is the move to 0.6 m's
        with pytest.raises(RunError) as err:
            run()
        run.at_stop = lambda z: None
        assert "ALARM:3" not in alarms(fw)
        time.sleep(1.0)
        assert report(fw).startswith(("<Idle", "<Hold:0"))
        msg = str(err.value)
        assert "no reply to 'G21 G53 G1 X" in msg and "in 2 tries" in msg and "position kept" in msg, msg
        assert run(resume=True)
        run.check_positions(homing=False, x0_mm=5.0)
        assert "ALARM:3" not in alarms(fw)


@pytest.mark.parametrize("glitch", ["letter", "separator", "non_ascii", "truncate", "drop", "late"])
def test_one_glitch_mid_move_is_asked_again_and_the_run_finishes(tmp_path, glitch):
    def inject(fw: GrblFirmware) -> None:
        if glitch == "drop":
            fw.drop_next(b"?")
        elif glitch == "late":
            fw.delay_next_reply(0.8, prefix=b"<")  # past the 0.5 s the driver waits for one report
        else:
            fw.garble_next_status(glitch)

    with GrblFirmware(tmp_path / "fw", rail_mm=RAIL_MM, x0_mm=5.0,
                      settings={130: RAIL_MM, 110: 1200, 120: 100}) as fw:
        run = Run(fw, tmp_path / "s.h5", [0.5, 0.6, 0.7], "homing=0")
        trigger = when_moving_to(fw, 100.0, 0.3, lambda: inject(fw))
        assert run() == ["0.500m", "0.600m", "0.700m"]
        trigger.done()
        run.check_positions(homing=False, x0_mm=5.0)
        assert not alarms(fw)


# --- a reset and an unplugged controller: the position is gone, homing finds it again -------------------------


def test_a_reset_mid_move_needs_homing_and_is_refused_without_it(tmp_path):
    settings = {130: RAIL_MM, 110: 1200, 120: 100}
    with GrblFirmware(tmp_path / "fw", rail_mm=RAIL_MM, x0_mm=5.0, settings=settings) as fw:
        run = Run(fw, tmp_path / "s.h5", [0.5, 0.6, 0.7], "homing=0")
        trigger = when_moving_to(fw, 100.0, 0.3, lambda: fw.press(b"\x18"))  # someone resets the controller mid-move
        with pytest.raises(RunError) as err:
            run()
        trigger.done()
        assert "ALARM:3" in alarms(fw) and "ALARM:3" in str(err.value)
        time.sleep(1.0)
        before = len(fw.sent_bytes())
        with pytest.raises(RunError) as err:
            run(resume=True)
        assert b"$X" not in fw.sent_bytes()[before:]  # never unlocked: its position is not trusted
    msg = str(err.value)
    assert "machine position may be lost" in msg and "homing=1" in msg and "1 of 3 stops are saved" in msg, msg


def test_an_unplugged_controller_resumes_on_a_new_port_after_homing(tmp_path):
    settings = {130: RAIL_MM, **HOMING, 110: 1200, 120: 100}
    with GrblFirmware(tmp_path / "fw", rail_mm=RAIL_MM, x0_mm=150.0, settings=settings) as fw:
        run = Run(fw, tmp_path / "s.h5", [0.5, 0.6, 0.7])
        old_port = fw.port
        trigger = when_moving_to(fw, -102.0, 0.3, fw.kill)  # the cable is pulled mid-move: the firmware dies with it
        with pytest.raises(RunError) as err:
            run()
        trigger.done()
        assert "port disconnected" in str(err.value) or "no such serial port" in str(err.value), str(err.value)
        fw.restart()  # plugged in again: a new port, MPos 0 wherever the carriage stopped, locked in Alarm
        assert fw.port != old_port
        assert run(resume=True) == ["0.600m", "0.700m"]
        run.check_positions(homing=True, x0_mm=150.0)
