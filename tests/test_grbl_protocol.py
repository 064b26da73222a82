"""The GRBL simulator against a G-code sender from the package index, and the GRBL driver against controllers
as they are shipped: stock settings ($110=500, $120=10, $130=200), stock machine space, startup lines, inches.

`grbl-streamer` (a test dependency) is the independent client: it resets the controller, reads `$$`, `$#` and
`$G`, polls `?`, and streams a job with GRBL's character-counting flow control against the 128-byte buffer.
"""

from __future__ import annotations

import threading
import time

import pytest
from grbl_streamer import GrblStreamer

from drivers.errors import StageError
from drivers.serial import GrblStage
from fakes.grbl_sim import GrblSim
from protocols import Runner, perpendicular
from protocols.recording import Recording
from rig.devices import open_devices

pytestmark = pytest.mark.slow


def wait_until(condition, what: str, timeout_s: float = 20.0) -> None:
    """Poll `condition()` until it holds; fail (not hang) if it never does."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.02)


JOB = ["G21 G90", "G1 X10 F6000", "G1 X25.5", "G4 P0.1", "G91", "G1 X-5", "G90", "G0 X40"]


class Events:
    """What grbl-streamer reports through its callback."""

    def __init__(self) -> None:
        self.log: list[tuple[str, tuple]] = []
        self.changed = threading.Condition()

    def __call__(self, event: str, *data) -> None:
        with self.changed:
            self.log.append((event, data))
            self.changed.notify_all()

    def read(self) -> list[str]:
        return [str(d[0]) for e, d in self.log if e == "on_read" and d]

    def wait(self, test, timeout_s: float = 30.0, describe=None) -> None:  # a deadline, not a sleep: generous under load
        """Until test(self) holds, checked on every event and every 50 ms: a test may read the simulator's
        state, which changes with no event (grbl-streamer stays silent once the job's last `ok` is in). On time-out
        the message has the last events and, from `describe`, what the test was waiting on (the simulator's state)."""
        deadline = time.monotonic() + timeout_s
        with self.changed:
            while not test(self):
                left = deadline - time.monotonic()
                assert left > 0, ([e for e, _ in self.log][-20:], describe() if describe else None)
                self.changed.wait(min(left, 0.05))


def test_grbl_streamer_connects_reads_settings_and_streams_a_job():
    with GrblSim(homing=False, soft_limits=False, speed_mm_s=500.0) as sim:
        events = Events()
        sender = GrblStreamer(events)
        sender.cnect(sim.port, 115200)
        try:
            events.wait(lambda ev: any(e == "on_boot" for e, _ in ev.log))
            sender.poll_start()
            sender.request_settings()
            events.wait(lambda ev: any(t.startswith("$132=") for t in ev.read()))  # the last line of $$
            events.wait(lambda ev: any(e == "on_hash_stateupdate" for e, _ in ev.log))  # $# ends with [PRB:...]
            events.wait(lambda ev: any(t.startswith("[GC:") for t in ev.read()))  # $G
            assert "$110=30000.000" in events.read() and "$130=3000.000" in events.read()
            hashes = next(d[0] for e, d in events.log if e == "on_hash_stateupdate")
            assert hashes["G54"] == (0.0, 0.0, 0.0) and "PRB" in hashes
            sender.write("\n".join(JOB))
            sender.job_run()
            # it counts characters against the 128-byte buffer and sees each line acknowledged
            events.wait(lambda ev: any(e == "on_processed_command" and d[1] == "G00X40" for e, d in ev.log), 30.0)
            events.wait(lambda ev: sim.state == "Idle" and sim.machine_mm(time.monotonic()) == 40.0,
                    describe=lambda: (sim.state, repr(sim.machine_mm(time.monotonic())), sim.commands[-5:], sim.replies[-5:]))
            assert not [d for e, d in events.log if e in ("on_error", "on_alarm")]
            assert sim.machine_mm(time.monotonic()) == pytest.approx(40.0, abs=1e-6)
            # it parsed our status reports while the job ran, and after it (its own polling lags the job's end)
            events.wait(lambda ev: any(e == "on_stateupdate" and d[0] == "Idle" for e, d in ev.log))
            states = {d[0] for e, d in events.log if e == "on_stateupdate"}
            assert "Run" in states and "Idle" in states
        finally:
            sender.poll_stop()
            sender.disconnect()


def fast_driver(sim: GrblSim, **options) -> GrblStage:
    return GrblStage(sim.port, **{"settle_s": 0.0, "timeout_s": 0.5, "poll_s": 0.01, **options})


def test_stock_controller_caps_the_feed_and_times_the_move_from_its_settings():
    # a freshly flashed controller: $110=500 mm/min, $120=10 mm/s^2, $130=200; homing and soft limits off.
    # A 150 mm move takes 18 s at 500 mm/min; the old driver allowed 2 x 150 / (3000/60) + 10 = 16 s and failed.
    with GrblSim.stock(start_mm=20.0) as sim, fast_driver(sim, homing=False, offset_m=0.3) as stage:
        stage.home()
        assert stage.feed_mm_min == 500.0 and stage.limits_m == pytest.approx((0.3, 0.5))
        assert stage.move_to(0.45) == pytest.approx(0.45, abs=1e-6)
        assert any(c.startswith("G21 G53 G1 X150.000 F500") for c in sim.commands)
        assert stage.describe()["settings"]["$110"] == 500.0


def test_stock_homing_geometry_with_soft_limits_and_default_device_string():
    # $22=1, $20=1 and stock machine space: homing towards +X leaves MPos at -$27; travel is -$130..0
    with GrblSim.stock(settings={20: 1, 22: 1, 110: 60000.0, 120: 5000.0, 24: 60000.0, 25: 60000.0}) as sim, \
            fast_driver(sim, offset_m=0.3) as stage:
        stage.home()
        assert sim.machine_mm(time.monotonic()) == pytest.approx(-1.0)  # -$27, the pull-off
        assert stage.limits_m == pytest.approx((0.3, 0.3 + 0.199))
        for target in (0.35, 0.45, 0.499):
            assert stage.move_to(target) == pytest.approx(target, abs=1e-6)
            assert sim.from_home_mm(time.monotonic()) == pytest.approx((target - 0.3) * 1000.0, abs=1e-3)
        assert not sim.critical


def test_a_sweep_runs_against_stock_settings_without_a_timeout(tmp_path):
    # stock settings, the default feed (3000, capped to 500) and only homing=0 in the device string
    with GrblSim.stock(start_mm=0.0) as sim:
        devices = open_devices("fake:width=16,height=9,depth_unit_mm=0.1",
                               f"grbl://{sim.port}?offset_m=0.5&homing=0&settle=0&poll_s=0.02")
        Runner(devices.camera, devices.stage).run(perpendicular([0.5, 0.55, 0.6, 0.65], frames_per_stop=2,
                                                                settle_s=0.0), tmp_path / "s.h5")
    with Recording(tmp_path / "s.h5") as rec:
        stops = list(rec.stops())
        assert '"$110": 500.0' in rec.attrs["stage"]
    assert [s.commanded_position_m for s in stops] == [0.5, 0.55, 0.6, 0.65]
    assert all(abs(s.measured_position_m - s.commanded_position_m) < 1e-6 for s in stops)


def test_startup_line_echo_and_inch_reports_are_understood():
    # $N0=G20 makes the controller print '>G20:ok' after its banner, and $13=1 reports positions in inches
    with GrblSim(homing=False, soft_limits=False, speed_mm_s=2000.0, startup_lines=("G20", ""),
                 settings={13: 1}) as sim, fast_driver(sim, homing=False, offset_m=0.3) as stage:
        assert any(r.startswith(">G20:ok") for r in sim.replies)
        stage.home()
        assert stage.move_to(1.0) == pytest.approx(1.0, abs=1e-4)  # inches: 4 decimals, 2.5 um
        assert sim.machine_mm(time.monotonic()) == pytest.approx(700.0, abs=1e-3)  # G21 sent with the move


def test_a_stuck_carriage_is_stopped_with_a_feed_hold_and_a_reset():
    with GrblSim(homing=False, soft_limits=False, speed_mm_s=100.0) as sim, \
            fast_driver(sim, homing=False, offset_m=0.3, stall_s=0.5) as stage:
        stage.home()

        def jam() -> None:  # the carriage stops dead but the controller still says Run
            time.sleep(0.3)
            with sim._lock:
                now = time.monotonic()
                sim.carriage.stop(now)
                sim.carriage.start(sim.carriage.position_mm(now) + 500.0, now, speed_mm_s=1e-6)  # crawls: ~never ends
        threading.Thread(target=jam, daemon=True).start()
        with pytest.raises(StageError, match=r"stuck during .* for \d+\.\d s in state Run.*carriage was stopped"):
            stage.move_to(1.0)
        assert "!" in sim.commands and sim.commands.index("!") < len(sim.commands) - 1
        assert sim.commands[-1] == "^X" or "^X" in sim.commands[sim.commands.index("!"):]
        assert sim.state == "Idle"  # reset after a complete hold: no alarm, position kept


def test_silence_after_a_soft_limit_alarm_is_named_and_homing_recovers():
    with GrblSim(speed_mm_s=20000.0, travel_mm=500.0) as sim, \
            fast_driver(sim, offset_m=0.3, rail_min_mm=-500.0, travel_mm=1000.0) as stage:
        stage.home()
        with pytest.raises(StageError, match=r"ALARM:2 .*within -500\.\.0 mm \(\$130=500, homing towards \+X without"):
            stage.move_to(0.4)  # machine X +100: beyond 0
        with pytest.raises(StageError, match=r"silent after ALARM:2.*until a reset"):
            stage.position_m()
        stage.home()
        assert not sim.critical and stage.move_to(0.3 - 0.2) == pytest.approx(0.1, abs=1e-6)


def test_a_failed_homing_is_named_and_its_reset_banner_is_not_a_power_fault():
    with GrblSim(speed_mm_s=20000.0) as sim, fast_driver(sim, offset_m=0.3) as stage:
        sim.inject("homing_fail")
        with pytest.raises(StageError, match=r"ALARM:9 during homing .*limit switch not found"):
            stage.home()
        stage.home()  # the banner that followed the alarm is not reported as an unexpected reset
        assert sim.homed and stage.position_m() == pytest.approx(0.3)


def test_overlong_line_gets_error_11_and_the_receive_buffer_holds_128_bytes():
    import serial

    with GrblSim(homing=False, soft_limits=False, speed_mm_s=1.0, settings={10: 3}) as sim:
        port = serial.Serial(sim.port, 115200, timeout=0.5)
        port.write(b"G1 X1 F60 (" + b"x" * 90 + b")\n")
        assert port.readline().strip() == b"error:11"
        # 20 ten-second moves: one runs, 15 fill the planner, the last 4 (40 bytes) wait unread in the buffer
        port.write(b"G91\n" + b"G1 X9 F60\n" * 20)
        got = b""
        deadline = time.monotonic() + 10.0
        while got.count(b"ok") < 17 and time.monotonic() < deadline:
            got += port.read(4096)
        # G91 and 16 moves: the 16th is read once the first one runs
        assert got.count(b"ok") == 17, f"{got.count(b'ok')} of 17 'ok' within 10 s (or more): {got!r}"
        port.write(b"?")
        report = port.readline().decode()
        assert "|Bf:0,88|" in report, report
        port.write(b"\x18")
        port.close()


class Terminal:
    """A raw pyserial session with the simulator: send bytes, read the lines that came back."""

    def __init__(self, port: str):
        import serial

        self.port = serial.Serial(port, 115200, timeout=0.3)

    def send(self, data: bytes, wait_s: float = 0.15) -> list[str]:
        self.port.write(data)
        time.sleep(wait_s)
        return self.port.read(8192).decode("ascii", "replace").split()

    def status(self) -> str:
        return next(t for t in self.send(b"?") if t.startswith("<"))


def test_simulator_real_time_commands_check_mode_jogging_and_report_fields():
    with GrblSim(homing=True, soft_limits=True, speed_mm_s=50.0, travel_mm=300.0, settings={10: 0, 25: 6000.0}) as sim:
        term = Terminal(sim.port)
        assert term.status().startswith("<Alarm|WPos:")  # $10=0: work positions; homing on: Alarm at power-up
        term.send(b"$H\n", wait_s=0.05)
        assert term.send(b"?", wait_s=0.1) == []  # homing blocks the protocol loop: '?' goes unanswered
        wait_until(lambda: sim.state != "Home", "homing to end")
        term.send(b"", wait_s=0.1)
        first = term.status()
        assert first.startswith("<Idle|WPos:-1.000,")  # stock pull-off: homing leaves MPos at -$27
        # feed hold and resume
        term.send(b"G53 G1 X-100 F3000\n", wait_s=0.3)
        term.send(b"!", wait_s=0.1)
        held = term.status()
        assert held.startswith("<Hold:0|")  # braked at $120 and still: the hold is complete (report.c)
        x_held = float(held.split("WPos:")[1].split(",")[0])
        time.sleep(0.3)
        assert float(term.status().split("WPos:")[1].split(",")[0]) == x_held  # stopped
        term.send(b"~", wait_s=0.1)
        assert term.status().startswith("<Run|")
        wait_until(lambda: sim.state == "Idle", "the move to end")
        assert sim.machine_mm(time.monotonic()) == pytest.approx(-100.0)
        # feed override: 0x91 x 5 = 150 % (capped at $110 = 3000 mm/min)
        term.send(bytes([0x92] * 5), wait_s=0.05)  # 50 %
        term.send(b"G53 G1 X-90 F3000\n", wait_s=0.2)
        assert "|FS:" in term.status()
        wait_until(lambda: sim.state == "Idle", "the move to end")
        assert any(f"Ov:50,100,100" in r for r in sim.replies) or sim.feed_override == 50
        # jog with soft limits: error:15, not an alarm; jog cancel stops it
        assert term.send(b"$J=G53 X50 F3000\n") == ["error:15"]
        term.send(b"$J=G91 X-50 F600\n", wait_s=0.2)
        assert term.status().startswith("<Jog|")
        term.send(bytes([0x85]), wait_s=0.1)
        assert term.status().startswith("<Idle|") and sim.machine_mm(time.monotonic()) > -140.0
        # check mode: parsed, not moved; leaving it resets
        x = sim.machine_mm(time.monotonic())
        assert term.send(b"$C\n")[:2] == ["[MSG:Enabled]", "ok"]
        assert term.send(b"G53 G1 X-10 F3000\n") == ["ok"]
        assert sim.machine_mm(time.monotonic()) == x
        assert "Grbl" in term.send(b"$C\n", wait_s=0.3)  # [MSG:Disabled], ok, then the reset banner
        # settings writes
        assert term.send(b"$110=1200\n") == ["ok"] and sim.settings[110] == 1200.0
        assert term.send(b"$999=1\n") == ["error:3"] and term.send(b"$110=-1\n") == ["error:4"]
        term.port.close()
