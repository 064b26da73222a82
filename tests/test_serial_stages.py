"""The GRBL and Zaber drivers against the simulated controllers, through pyserial on a real pty, in real time.

What is left here needs the pty, the port layer or real time: a move the driver waits out while the simulated
carriage travels, pyserial's errors for a port that is missing, taken or unplugged, deadlines against a peer that
never stops talking, and the simulators' own position callback. What the drivers say to a controller, and do
with its replies (connecting, homing, moves, soft limits, tolerances, lost and garbled replies, alarms, feed
holds, Zaber flags and rejections), is tested against expected exchanges in tests/test_serial_exchanges.py,
instantly; the simulators are held to the firmware by tests/test_grbl_golden.py and tests/test_zaber_protocol.py.
"""

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

#: a controller served in real time over a pty (pyproject.toml's `slow` marker)
real_time = pytest.mark.slow


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


# --- moving: the driver waits while the carriage travels ---------------------------------------------


@real_time
@pytest.mark.parametrize("kind", ["grbl", "zaber"])
def test_sim_reports_where_the_carriage_rests(kind):
    with make_sim(kind) as sim, make_stage(kind, sim.port) as stage:
        rests_mm: list[float] = []
        sim.on_position(rests_mm.append)
        stage.home()
        stage.move_to(1.0)
        assert rests_mm[0] == pytest.approx(0.0) and rests_mm[-1] == pytest.approx(700.0, abs=1e-3)


@real_time
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


@real_time
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


@real_time
def test_port_in_use_is_named():
    with make_sim("grbl") as sim, make_stage("grbl", sim.port):
        with raises_for_port(sim, "in use by another program"):
            make_stage("grbl", sim.port).open()


# --- unplugged: pyserial's errors for a port that vanishes --------------------------------------------


@real_time
def test_unplug_while_idle(homed):
    sim, stage = homed
    sim.inject("unplug")
    with raises_for_port(sim, "port disconnected", "check the USB cable"):
        stage.position_m()
    reopened = make_stage(sim.kind, sim.port)
    with raises_for_port(sim, "no such serial port", f"rig stage-sim {sim.kind}"):
        reopened.open()


@real_time
def test_unplug_during_a_move(homed):
    sim, stage = homed
    sim.carriage.speed_mm_s = 5000.0
    threading.Timer(0.1, sim.inject, args=("unplug",)).start()
    with raises_for_port(sim, "port disconnected"):
        stage.move_to(3.0)


# --- deadlines in real time --------------------------------------------------------------------------


@real_time
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
