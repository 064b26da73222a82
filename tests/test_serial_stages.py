"""The GRBL and Zaber drivers against the simulated controllers, through pyserial on a real pty."""

from __future__ import annotations

import re
import threading
import time

import pytest

from drivers.errors import StageError
from drivers.registry import DeviceSpec, factory
from drivers.serial import GrblStage, ZaberStage
from fakes.grbl_sim import GrblSim
from fakes.zaber_sim import ZaberSim

pytestmark = pytest.mark.slow


FAST_SIM = {"speed_mm_s": 20000.0}
#: a GRBL built with HOMING_FORCE_SET_ORIGIN homing towards -X with no pull-off: machine X is the distance from the
#: home switch, so these tests can compare the carriage with the rail directly (stock geometry: test_grbl_stock.py)
ORIGIN_AT_SWITCH = {"force_origin": True, "settings": {23: 1, 27: 0.0}}
FAST_DRIVER = {"settle_s": 0.0, "timeout_s": 0.3, "poll_s": 0.01}


def make_sim(kind: str, **options):
    sim = GrblSim(**{**FAST_SIM, **ORIGIN_AT_SWITCH, **options}) if kind == "grbl" else ZaberSim(**{**FAST_SIM, **options})
    return sim.start()


def make_stage(kind: str, port: str, **options):
    if kind == "grbl":  # the feed the driver asks for; the controller caps it at its $110 (fast here)
        return GrblStage(port, **{**FAST_DRIVER, "feed_mm_min": 1e7, **options})
    return ZaberStage(port, **{**FAST_DRIVER, **options})


def bare(lines: list[str]) -> list[str]:
    """Zaber messages without their message id and checksum: '/1 1 07 get pos:C3' -> '/1 1 get pos'."""
    return [re.sub(r"^([/@]\d+ \d+) \d+ ", r"\1 ", line.rsplit(":", 1)[0] if ":" in line else line) for line in lines]


@pytest.fixture(params=["grbl", "zaber"])
def homed(request):
    """(sim, stage) for each controller, connected and homed."""
    sim = make_sim(request.param)
    stage = make_stage(request.param, sim.port)
    stage.open()
    stage.home()
    yield sim, stage
    stage.close()
    sim.stop()


def raises_for_port(sim, *phrases: str):
    """Expect a one-line StageError that names the sim's port and contains each phrase."""

    class Check:
        def __enter__(self):
            return self

        def __exit__(self, typ, exc, tb):
            assert typ is StageError or (typ is not None and issubclass(typ, StageError)), f"no StageError, got {typ}"
            message = str(exc)
            assert message.startswith(f"{sim.kind} {sim.port}: "), message
            assert "\n" not in message
            for phrase in phrases:
                assert phrase in message, f"{phrase!r} not in {message!r}"
            self.message = message
            return True

    return Check()


# --- connecting, homing, moving ------------------------------------------------------------------


def test_grbl_connects_with_soft_reset_and_homes():
    with make_sim("grbl") as sim, make_stage("grbl", sim.port) as stage:
        assert stage.firmware == "1.1h"
        assert "^X" in sim.commands
        assert sim.state == "Alarm" and not sim.homed  # homing enabled: locked until $H
        stage.home()
        assert sim.homed and sim.state == "Idle"
        assert "$H" in sim.commands and "G90 G21" in sim.commands
        assert stage.position_m() == pytest.approx(0.3)  # rail zero is offset_m


def test_zaber_connect_reads_travel_from_the_device():
    with make_sim("zaber", travel_mm=2000.0) as sim, make_stage("zaber", sim.port, offset_m=0.4) as stage:
        lo, hi = stage.limits_m
        assert lo == pytest.approx(0.4)
        assert hi == pytest.approx(0.4 + sim.limit_max_steps * 0.1905e-6)
        assert "/1 1 get limit.max" in bare(sim.commands)
        stage.home()
        assert sim.homed and sim.top_flag() == "--"


@pytest.mark.parametrize("kind", ["grbl", "zaber"])
@pytest.mark.parametrize("offset_m,direction", [(0.3, 1), (3.3, -1)])
def test_moves_land_where_commanded(kind, offset_m, direction):
    with make_sim(kind) as sim, make_stage(kind, sim.port, offset_m=offset_m, direction=direction) as stage:
        stage.home()
        assert stage.limits_m == pytest.approx((0.3, 3.3), abs=1e-6)
        for position_m in (0.5, 1.75, 3.0, 0.8):
            measured = stage.move_to(position_m)
            assert measured == pytest.approx(position_m, abs=1e-6)
            rail_mm = direction * (position_m - offset_m) * 1000.0
            assert sim.carriage.position_mm(time.monotonic()) == pytest.approx(rail_mm, abs=1e-3)
            assert not sim.carriage.moving()


@pytest.mark.parametrize("kind", ["grbl", "zaber"])
def test_sim_reports_where_the_carriage_rests(kind):
    with make_sim(kind) as sim, make_stage(kind, sim.port) as stage:
        rests_mm: list[float] = []
        sim.on_position(rests_mm.append)
        stage.home()
        stage.move_to(1.0)
        assert rests_mm[0] == pytest.approx(0.0) and rests_mm[-1] == pytest.approx(700.0, abs=1e-3)


def test_grbl_polls_status_until_the_move_ends():
    with make_sim("grbl", speed_mm_s=10000.0) as sim, make_stage("grbl", sim.port) as stage:
        stage.home()
        stage.move_to(0.5)
        first = len(sim.replies)
        t0 = time.monotonic()
        stage.move_to(3.0)
        elapsed = time.monotonic() - t0
        assert elapsed >= 2500.0 / 10000.0 * 0.9  # did not return before the carriage got there
        reports = [r for r in sim.replies[first:] if r.startswith("<")]
        running = [float(re.search(r"MPos:([-\d.]+)", r).group(1)) for r in reports if r.startswith("<Run|")]
        assert len(running) >= 5
        assert running == sorted(running) and 200.0 <= running[0] < running[-1] <= 2700.0
        assert sum(200.0 < x < 2700.0 for x in running) >= 3
        assert reports[-1].startswith("<Idle|MPos:2700.000")
        assert any(c.startswith("G21 G53 G1 X2700.000 F600000") for c in sim.commands)  # the feed capped at $110


def test_zaber_polls_until_idle():
    with make_sim("zaber", speed_mm_s=10000.0) as sim, make_stage("zaber", sim.port) as stage:
        stage.home()
        stage.move_to(0.5)
        first = len(sim.replies)
        stage.move_to(3.0)
        replies = bare(sim.replies[first:])
        assert replies[0].startswith("@01 1 OK BUSY")  # the move abs itself
        busy = [int(r.split()[-1]) for r in replies[1:] if " BUSY " in r]
        assert len(busy) >= 5 and busy == sorted(busy)
        final = round(2700.0 * 1000 / 0.1905)
        assert replies[-1] == f"@01 1 OK IDLE -- {final}"
        assert f"/1 1 move abs {final}" in bare(sim.commands)


@pytest.mark.parametrize("kind", ["grbl", "zaber"])
def test_moving_before_homing_is_refused(kind):
    with make_sim(kind) as sim, make_stage(kind, sim.port) as stage:
        sent = len(sim.commands)
        with raises_for_port(sim, "not homed"):
            stage.move_to(1.0)
        assert len(sim.commands) == sent


def test_soft_limits_refuse_before_sending(homed):
    sim, stage = homed
    sent = len(sim.commands)
    with raises_for_port(sim, "outside the travel limits 0.300-3.300 m"):
        stage.move_to(3.35)
    with raises_for_port(sim, "outside the travel limits"):
        stage.move_to(0.1)
    assert len(sim.commands) == sent
    far_m = stage.limits_m[1]  # the very end of travel is allowed
    assert stage.move_to(far_m) == pytest.approx(far_m, abs=1e-6)


def test_device_strings_build_configured_drivers():
    spec = DeviceSpec.parse("grbl:///dev/ttyUSB0?baud=57600&offset_m=0.25&direction=-1&feed=1200&settle=0.5"
                            "&tolerance_mm=2&travel_mm=2500&rail_min_mm=0")
    stage = factory("stage", "grbl")(spec, {})
    assert isinstance(stage, GrblStage)
    assert (stage.link.baud, stage.feed_mm_min, stage.settle_s, stage.tolerance_m) == (57600, 1200.0, 0.5, 0.002)
    assert stage.limits_m == pytest.approx((0.25 - 2.5, 0.25))
    assert stage.name == "grbl /dev/ttyUSB0"
    zaber = factory("stage", "zaber")(DeviceSpec.parse("zaber:///dev/ttyUSB1?microstep_um=0.047625&offset_m=0.5"), {})
    assert isinstance(zaber, ZaberStage) and zaber.microstep_um == 0.047625
    with pytest.raises(StageError, match="direction must be 1 or -1"):
        factory("stage", "grbl")(DeviceSpec.parse("grbl:///dev/ttyUSB0?direction=2"), {})
    with pytest.raises(StageError, match="names no serial port.*rig stage-sim zaber"):
        factory("stage", "zaber")(DeviceSpec.parse("zaber:"), {})


# --- ports ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["grbl", "zaber"])
def test_missing_port_suggests_the_simulator(kind):
    stage = make_stage(kind, "/dev/ttyUSB-rig-test-missing")
    with pytest.raises(StageError) as info:
        stage.open()
    message = str(info.value)
    assert message.startswith(f"{kind} /dev/ttyUSB-rig-test-missing: no such serial port")
    assert f"rig stage-sim {kind}" in message and "\n" not in message


def test_port_in_use_is_named():
    with make_sim("grbl") as sim, make_stage("grbl", sim.port):
        with raises_for_port(sim, "in use by another program"):
            make_stage("grbl", sim.port).open()


def test_wrong_device_gives_no_banner():
    with make_sim("zaber") as sim:  # a Zaber ignores G-code and Ctrl-X
        with pytest.raises(StageError) as info:
            make_stage("grbl", sim.port).open()
    assert str(info.value).startswith(f"grbl {sim.port}: no GRBL banner within 0.6 s")
    assert "this port is the GRBL controller" in str(info.value) and "baud=115200" in str(info.value)


# --- injected faults ---------------------------------------------------------------------------------


def test_dropped_reply_times_out(homed):
    sim, stage = homed
    if sim.kind == "grbl":  # one unanswered '?' is asked again; only a link that stays silent is an error
        sim.inject("drop_reply")
        assert stage.position_m() == pytest.approx(0.3, abs=1e-6)
        sim.inject("drop_reply", count=3)
        with raises_for_port(sim, "no reply to '?' in 3 tries of 0.3 s", "check the USB cable"):
            stage.position_m()
    else:
        sim.inject("drop_reply")
        with raises_for_port(sim, "no reply to", "within 0.3 s", "check the USB cable"):
            stage.position_m()
    assert stage.position_m() == pytest.approx(0.3, abs=1e-6)  # the next exchange works


def test_dropped_reply_during_a_move(homed):
    sim, stage = homed
    stage.move_to(1.0)
    if sim.kind == "grbl":  # a lost line is sent again (every line the driver sends is idempotent)
        sim.inject("drop_reply")
        assert stage.move_to(1.5) == pytest.approx(1.5, abs=1e-6)
        sim.inject("drop_reply", count=2)  # the move command is lost twice
        with raises_for_port(sim, "no reply to 'G21 G53 G1 X1700.000", "in 2 tries of 0.3 s"):
            stage.move_to(2.0)
        assert sim.carriage.position_mm(time.monotonic()) == pytest.approx(1200.0, abs=1e-3)
        return
    sim.inject("drop_reply")  # the move command itself is lost
    with raises_for_port(sim, "no reply to"):
        stage.move_to(2.0)
    assert sim.carriage.position_mm(time.monotonic()) == pytest.approx(700.0, abs=1e-3)


def test_line_noise_is_reported_as_garbled(homed):
    sim, stage = homed
    if sim.kind == "grbl":  # one garbled report is asked again; a link that stays bad is named as such
        sim.inject("noise")
        assert stage.position_m() == pytest.approx(0.3, abs=1e-6)
        sim.inject("noise", count=3)
        with raises_for_port(sim, "no clean reply to '?' in 3 tries (3 garbled, the last", "baud=115200",
                             "away from the motor wiring"):
            stage.position_m()
    else:
        sim.inject("noise")
        with raises_for_port(sim, "garbled reply", "baud=115200"):
            stage.position_m()
    assert stage.move_to(1.2) == pytest.approx(1.2, abs=1e-6)


def test_unplug_while_idle(homed):
    sim, stage = homed
    sim.inject("unplug")
    with raises_for_port(sim, "port disconnected", "check the USB cable"):
        stage.position_m()
    reopened = make_stage(sim.kind, sim.port)
    with raises_for_port(sim, "no such serial port", f"rig stage-sim {sim.kind}"):
        reopened.open()


def test_unplug_during_a_move(homed):
    sim, stage = homed
    sim.carriage.speed_mm_s = 5000.0
    threading.Timer(0.1, sim.inject, args=("unplug",)).start()
    with raises_for_port(sim, "port disconnected"):
        stage.move_to(3.0)


def test_position_error_fails_the_tolerance_check(homed):
    sim, stage = homed
    stage.move_to(1.0)
    sim.inject("position_error", mm=3.0)
    with raises_for_port(sim, "commanded 2.0000 m but measured 2.0030 m", "tolerance 1.0 mm"):
        stage.move_to(2.0)
    sim.inject("position_error", mm=0.4)  # within tolerance: accepted, and the measurement shows it
    assert stage.move_to(1.5) == pytest.approx(1.5004, abs=1e-6)


# --- alarms and faults the controllers raise themselves -----------------------------------------------


def test_grbl_soft_limit_alarm_and_recovery():
    # the device string claims more rail than the controller's $130 allows
    with make_sim("grbl", travel_mm=2000.0) as sim, make_stage("grbl", sim.port, rail_min_mm=0.0, travel_mm=3000.0) as stage:
        stage.home()
        with raises_for_port(sim, "ALARM:2", "soft limit", "$130"):
            stage.move_to(2.8)  # inside the driver's travel, beyond the controller's
        assert sim.critical
        with raises_for_port(sim, "not homed"):
            stage.move_to(1.0)
        stage.home()  # resets out of the critical alarm, homes again
        assert not sim.critical and sim.state == "Idle"
        assert stage.move_to(1.0) == pytest.approx(1.0, abs=1e-6)


def test_grbl_hard_limit_alarm_when_soft_limits_are_off():
    with make_sim("grbl", travel_mm=2000.0, soft_limits=False, settings={**ORIGIN_AT_SWITCH["settings"], 21: 1}) as sim, \
            make_stage("grbl", sim.port, rail_min_mm=0.0, travel_mm=3000.0) as stage:
        stage.home()
        with raises_for_port(sim, "ALARM:1", "hard limit", "during 'G21 G53 G1 X2500.000"):
            stage.move_to(2.8)
        assert sim.carriage.position_mm(time.monotonic()) == pytest.approx(2000.0)
        stage.home()
        assert stage.move_to(2.0) == pytest.approx(2.0, abs=1e-6)


def test_grbl_limit_switch_tripped_mid_move():
    with make_sim("grbl") as sim, make_stage("grbl", sim.port) as stage:
        stage.home()
        stage.move_to(0.5)
        sim.inject("hard_limit")
        with raises_for_port(sim, "ALARM:1"):
            stage.move_to(2.5)
        assert sim.carriage.position_mm(time.monotonic()) == pytest.approx(1200.0, abs=1e-3)


def test_grbl_homing_failure():
    with make_sim("grbl") as sim, make_stage("grbl", sim.port) as stage:
        sim.inject("homing_fail")
        with raises_for_port(sim, "ALARM:9", "homing failed", "home switch wiring"):
            stage.home()
        stage.home()
        assert sim.homed


def test_grbl_homing_disabled_on_the_controller():
    with make_sim("grbl", homing=False, soft_limits=False) as sim:
        with raises_for_port(sim, "homing is disabled on the controller ($22=0)", "homing=0"):
            make_stage("grbl", sim.port).open()
        with make_stage("grbl", sim.port, homing=False) as stage:
            stage.home()  # $X only: positions count from where the carriage was at power-up
            assert "$X" in sim.commands
            assert stage.move_to(1.0) == pytest.approx(1.0, abs=1e-6)


def test_grbl_unexpected_reset_is_reported():
    with make_sim("grbl") as sim, make_stage("grbl", sim.port) as stage:
        stage.home()
        stage.move_to(1.0)
        sim.power_cycle()
        with raises_for_port(sim, "reset unexpectedly", "position lost"):
            stage.position_m()
        with raises_for_port(sim, "not homed"):
            stage.move_to(1.5)
        stage.home()
        assert stage.move_to(1.5) == pytest.approx(1.5, abs=1e-6)


def test_zaber_home_stops_a_move_left_running():
    with make_sim("zaber", speed_mm_s=5000.0) as sim, make_stage("zaber", sim.port) as stage:
        stage.home()
        stage.move_to(0.5)
        sim.inject("noise")  # the reply to 'move abs' is lost to noise; the stage moves on
        with raises_for_port(sim, "garbled reply"):
            stage.move_to(3.0)
        assert sim.carriage.moving()
        stage.home()  # what a resume does: stop, clear warnings, home
        assert sim.homed and "/1 1 stop" in bare(sim.commands) and "NI" not in sim.flags
        assert stage.move_to(1.0) == pytest.approx(1.0, abs=1e-6)


def test_zaber_stall_fault():
    with make_sim("zaber") as sim, make_stage("zaber", sim.port) as stage:
        stage.home()
        stage.move_to(0.5)
        sim.inject("stall")
        with raises_for_port(sim, "fault FS", "stalled and stopped"):
            stage.move_to(2.5)
        assert "FS" in sim.flags
        stage.home()  # homing clears the fault
        assert stage.move_to(2.5) == pytest.approx(2.5, abs=1e-6)


def test_zaber_rejects_absolute_moves_after_losing_its_reference():
    with make_sim("zaber") as sim, make_stage("zaber", sim.port) as stage:
        stage.home()
        stage.move_to(1.0)
        sim.power_cycle()
        with raises_for_port(sim, "rejected: no reference position (WR)", "home the stage"):
            stage.move_to(1.5)
        stage.home()
        assert stage.move_to(1.5) == pytest.approx(1.5, abs=1e-6)


@pytest.mark.parametrize("kind,chatter", [("grbl", b"[MSG:chatter]\r\n"), ("grbl", b"ok\r\n"), ("zaber", b"#01 1 chatter\r\n")])
def test_a_port_that_streams_without_end_fails_by_its_deadline(kind, chatter):
    """A peer that never stops talking (a wrong device, a looping board) must not hang open()."""
    import os
    import pty
    import tty

    master, slave = pty.openpty()
    tty.setraw(slave)
    stop = threading.Event()

    def talk():
        while not stop.is_set():
            try:
                os.write(master, chatter * 64)  # as fast as the line takes it: never a silent moment
            except OSError:
                return

    threading.Thread(target=talk, daemon=True).start()
    stage = make_stage(kind, os.ttyname(slave), timeout_s=0.3)
    t0 = time.monotonic()
    try:
        with pytest.raises(StageError, match=r"no (GRBL banner|reply)|garbled reply"):  # one line, either way
            stage.open()
    finally:
        stop.set()
        elapsed = time.monotonic() - t0
        stage.close()
        os.close(master)
        os.close(slave)
    assert elapsed < 10 * 0.3 + 2.0, elapsed  # its own deadlines (a few timeouts), not forever
