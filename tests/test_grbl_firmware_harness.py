"""The harness that runs the real GRBL 1.1h firmware (grbl-sim) on a pseudo-terminal: tests/grbl_firmware.py.

Clients open `.port` with pyserial, as they would open /dev/ttyUSB0. Motion tests raise $110/$120: the stock
500 mm/min and 10 mm/s^2 make every move take seconds.
"""

from __future__ import annotations

import os
import re
import shutil
import time

import pytest
import serial

import grbl_firmware
from grbl_firmware import GrblFirmware, require_firmware

pytestmark = pytest.mark.slow


FAST = {110: 6000, 120: 500}  # 100 mm/s, 500 mm/s^2


class Client:
    """A pyserial client that reads lines and keeps the raw bytes."""

    def __init__(self, port: str) -> None:
        self.ser = serial.Serial(port, 115200, timeout=0.05)
        self.raw = b""

    def send(self, data: bytes | str) -> None:
        self.ser.write(data.encode() if isinstance(data, str) else data)

    def line(self, timeout_s: float = 2.0) -> bytes:
        """The next line, line end included (b"" on timeout)."""
        deadline = time.monotonic() + timeout_s
        got = b""
        while time.monotonic() < deadline:
            got += self.ser.readline()
            if got.endswith(b"\n"):
                break
        self.raw += got
        return got

    def until(self, pattern: str, timeout_s: float = 3.0) -> list[str]:
        """Lines (decoded, stripped) up to and including the first that matches `pattern`."""
        deadline = time.monotonic() + timeout_s
        lines: list[str] = []
        while time.monotonic() < deadline:
            line = self.line(deadline - time.monotonic())
            if line:
                lines.append(line.decode("latin-1").strip())
                if re.search(pattern, lines[-1]):
                    return lines
        raise AssertionError(f"no line matching {pattern!r} in {timeout_s} s; got {lines}")

    def command(self, text: str, timeout_s: float = 3.0) -> list[str]:
        self.send(text + "\n")
        return self.until(r"^(ok|error:\d+)$", timeout_s)

    def status(self) -> str:
        self.send(b"?")
        return self.until(r"^<.*>$")[-1]

    def wait_idle(self, timeout_s: float = 10.0) -> str:
        """The status once the queued motion has ended. Not the first `<Idle` seen: GRBL starts a queued
        move only when its main loop next finds the serial buffer empty (grbl/protocol.c:154-157), and a
        `?` that arrives before then is answered Idle with the old position in the same pass
        (protocol.c:250-253: the status before the cycle start). `G4 P0` is the firmware's own sync point: mc_dwell
        waits in protocol_buffer_synchronize until the planner is empty and the cycle over
        (motion_control.c:195-199, protocol.c:169-176) before its `ok`."""
        assert self.command("G4 P0", timeout_s)[-1] == "ok"
        report = self.status()
        assert report.startswith("<Idle"), report
        return report

    def close(self) -> None:
        self.ser.close()


def mpos_x(report: str) -> float:
    return float(re.search(r"MPos:(-?[\d.]+),", report).group(1))


@pytest.fixture(scope="module")
def exe():
    return require_firmware()


@pytest.fixture(scope="module")
def stock(exe, tmp_path_factory):
    """A freshly flashed controller (stock settings), shared by the tests that leave it as they found it."""
    with GrblFirmware(tmp_path_factory.mktemp("stock"), exe=exe) as fw:
        yield fw


@pytest.fixture
def client(stock):
    stock.clear_faults()
    c = Client(stock.port)
    yield c
    c.close()
    stock.clear_faults()


def test_missing_toolchain_is_a_one_line_skip_reason(monkeypatch):
    monkeypatch.setattr(shutil, "which", lambda name: None)
    reason = grbl_firmware.missing_toolchain()
    assert reason and "\n" not in reason and "C compiler" in reason


def test_settings_applied_at_start_are_in_dollar_dollar_and_a_move_ends_idle_at_the_commanded_mpos(exe, tmp_path):
    with GrblFirmware(tmp_path, exe=exe, settings={**FAST, 100: 250, 22: 1, 20: 1}, x0_mm=150.0) as fw:
        # written, then the controller power-cycled: with homing on it meets the client locked in Alarm
        assert fw.starts == 2 and "[MSG:'$H'|'$X' to unlock]" in fw.startup_burst
        c = Client(fw.port)
        try:
            settings = dict(line.split("=") for line in c.command("$$") if line.startswith("$"))
            assert (settings["$110"], settings["$120"], settings["$22"], settings["$20"]) == ("6000.000", "500.000",
                                                                                              "1", "1")
            assert c.status().startswith("<Alarm|")
            assert c.command("$X")[-1] == "ok"  # unlocked, not homed: soft limits allow MPos -200..0
            t0 = time.monotonic()
            assert c.command("G90 G1 X-42.5 F6000")[-1] == "ok"
            report = c.wait_idle()
            took = time.monotonic() - t0
            assert mpos_x(report) == -42.5 and report.startswith("<Idle|MPos:-42.500,0.000,0.000|")
            assert 0.5 < took < 2.0  # 42.5 mm at 100 mm/s with 500 mm/s^2 ramps: 0.6 s
            assert fw.physical_x_mm() == pytest.approx(150.0 - 42.5)
        finally:
            c.close()


def test_a_fresh_folder_powers_up_with_error_7_the_stock_settings_and_the_banner(stock):
    burst = stock.startup_burst
    assert burst[0] == "error:7"  # EEPROM.DAT did not exist: settings restored to the defaults
    assert "$110=500.000" in burst and burst[-1] == "Grbl 1.1h ['$' for help]"
    assert (stock.workdir / "EEPROM.DAT").is_file()


def test_banner_after_ctrl_x(client):
    client.send(b"\x18")
    assert client.until(r"^Grbl 1\.1h")[-1] == "Grbl 1.1h ['$' for help]"


def test_dollar_dollar_lists_the_stock_settings(client):
    lines = client.command("$$")
    settings = dict(line.split("=") for line in lines if line.startswith("$"))
    assert settings["$110"] == "500.000" and settings["$120"] == "10.000" and settings["$130"] == "200.000"
    assert settings["$22"] == "0" and settings["$20"] == "0" and settings["$21"] == "0" and settings["$27"] == "1.000"
    assert lines[-1] == "ok"


def test_homing_finds_the_switch_and_hard_limits_trip_at_the_end_of_the_rail(exe, tmp_path):
    settings = {**FAST, 22: 1, 25: 3000, 24: 600, 26: 20, 27: 1.5}
    with GrblFirmware(tmp_path, exe=exe, rail_mm=120.0, x0_mm=100.0, settings=settings) as fw:
        c = Client(fw.port)
        try:
            assert c.status().startswith("<Alarm|")
            assert c.command("$H", timeout_s=15.0)[-1] == "ok"  # towards +X: the switch at the rail's +X end
            report = c.status()
            assert report.startswith("<Idle|MPos:-1.500,0.000,0.000|") and "Pn:" not in report  # MPos -$27
            assert fw.physical_x_mm() == pytest.approx(120.0 - 1.5)
            # hard limits: running into the end of the rail trips the X switch
            assert c.command("$21=1")[-1] == "ok"
            c.send("G1 X5 F600\n")
            lines = c.until(r"^ALARM:", timeout_s=3.0)
            assert lines[-1] == "ALARM:1"  # hard limit (not 3: the pin-change interrupt ran as one piece)
            assert fw.physical_x_mm() == pytest.approx(120.0)
            # GRBL now locks up until reset; it clears a reset that came during its 0.5 s ALARM pause
            assert c.until(r"^\[MSG:")[-1] == "[MSG:Reset to continue]"
            c.send(b"\x18")
            assert "[MSG:Check Limits]" in c.until(r"to unlock\]$")
            assert "Pn:X" in c.status()
        finally:
            c.close()


def test_no_switch_reads_triggered_in_the_middle_of_the_rail(client, stock):
    report = client.status()
    assert report.startswith("<Idle|MPos:0.000,0.000,0.000|") and "Pn:" not in report
    assert stock.physical_x_mm() == pytest.approx(100.0)


def test_a_status_asked_with_the_move_is_idle_where_it_was_and_g4_p0_waits_for_the_move(client, stock):
    """Why wait_idle syncs with G4 P0: a `?` that reaches GRBL with the line is answered before the
    queued move starts, Idle at the old position; the move then runs."""
    client.send("G90 G1 X1 F500\n?")
    lines = client.until(r"^(ok|error:\d+)$")
    assert lines[-1] == "ok" and lines[0].startswith("<Idle|MPos:0.000,0.000,0.000|"), lines
    assert mpos_x(client.wait_idle()) == 1.0 and stock.physical_x_mm() == pytest.approx(101.0)
    assert client.command("G1 X0")[-1] == "ok" and mpos_x(client.wait_idle()) == 0.0


@pytest.mark.parametrize("kind, expect", [
    ("letter", rb"^<Idle\|MPPs:0\.000,0\.000,0\.000\|FS:0,0.*>\r\n$"),
    ("separator", rb"^<Idle\|MPos::0\.000,0\.000,0\.000\|.*>\r\n$"),
    ("non_ascii", rb"^<Idle\|MPos:\xb0\.000,0\.000,0\.000\|.*>\r\n$"),
])
def test_a_garbled_status_report_arrives_garbled_once(client, stock, kind, expect):
    stock.garble_next_status(kind)
    client.send(b"?")
    assert re.match(expect, client.line()), client.raw
    assert client.status().startswith("<Idle|MPos:0.000,0.000,0.000|")  # one-shot


def test_a_truncated_status_report_has_no_line_end_and_runs_into_the_next_line(client, stock):
    stock.garble_next_status("truncate")
    client.send(b"?")
    time.sleep(0.2)
    client.send(b"$I\n")
    joined = client.line()
    head = joined.removesuffix(b"[VER:1.1h.20190830:]\r\n")
    assert head != joined and head.startswith(b"<Idle|MPos:") and b">" not in head, joined  # half a report
    assert client.until(r"^ok$")[-1] == "ok"


def test_a_link_that_stays_bad_garbles_every_report_until_cleared(client, stock):
    stock.garble_status_reports(None, "separator")
    for _ in range(3):
        client.send(b"?")
        assert b"MPos::" in client.line()
    stock.clear_faults()
    client.send(b"?")
    assert b"MPos:0.000" in client.line()


#: every report GRBL 1.1h sends in Idle and Run with the stock $10=1 (MPos, no buffer state)
REPORT = re.compile(r"^<(Idle|Run)\|MPos:(-?\d+\.\d{3}),-?\d+\.\d{3},-?\d+\.\d{3}\|FS:\d+,\d+"
                    r"(\|WCO:-?\d+\.\d{3},-?\d+\.\d{3},-?\d+\.\d{3})?(\|Ov:\d+,\d+,\d+)?>$")


def test_a_status_report_flood_mid_move_neither_stops_the_steppers_nor_garbles_a_report(exe, tmp_path):
    """grbl-sim runs GRBL's main program and its interrupts in two threads. They shared one SREG: a '?' taken
    by the serial interrupt while the main program was between cli() and its restore (system.c) wrote the
    cleared I bit back for good, and the stepper interrupt never ran again (MPos frozen in Run, a feed hold
    stuck in Hold:1). About one move in 70 froze with a '?' every 20 ms; this flood froze that build within
    seconds (patch sreg-per-thread). Every report must also arrive whole: a ring buffer that published its
    head before its byte sent stale characters (patch ring-buffer-order)."""
    with GrblFirmware(tmp_path, exe=exe, rail_mm=400.0, x0_mm=10.0, settings={110: 1200, 120: 100}) as fw:
        ser = serial.Serial(fw.port, 115200, timeout=0)
        try:
            ser.write(b"G91 G1 X40 F1200\n")  # 2.2 s at 20 mm/s
            buf, reports, state, x = b"", 0, None, None
            t0 = moved = time.monotonic()
            while not (state == "Idle" and x == "40.000"):
                ser.write(b"?" * 20)
                time.sleep(0.001)
                buf += ser.read(1 << 16)
                *lines, buf = buf.split(b"\n")
                now = time.monotonic()
                for line in (raw.decode("latin-1").rstrip("\r") for raw in lines):
                    if line == "ok":
                        continue
                    match = REPORT.match(line)
                    assert match, f"a garbled report from the firmware: {line!r}"
                    reports += 1
                    if match.group(2) != x:
                        moved = now
                    state, x = match.group(1), match.group(2)
                assert now - moved < 2.0, f"the steppers stopped: MPos X {x} for 2 s in {state}, {reports} reports"
                assert now - t0 < 6.0, f"not done after 6 s: {state} at {x}"
            assert reports > 500  # the flood reached GRBL (a report every ~1 ms)
            assert fw.physical_x_mm() == pytest.approx(50.0)
        finally:
            ser.close()


def test_a_killed_controller_vanishes_and_restarts_on_a_new_port_where_the_carriage_was(exe, tmp_path):
    with GrblFirmware(tmp_path, exe=exe, settings=FAST, x0_mm=100.0) as fw:
        c = Client(fw.port)
        try:
            c.command("G1 X-80 F6000")
            time.sleep(0.35)  # mid-move
            assert c.status().startswith("<Run|")
            old_port = fw.port
            fw.kill()
            where = fw.physical_x_mm()
            assert 20.0 < where < 99.0  # the carriage file says where the move was cut off
            assert not os.path.exists(old_port)  # unplugged
            with pytest.raises(serial.SerialException):
                c.send(b"?")
                c.line(timeout_s=0.5)
        finally:
            c.close()
        fw.restart()
        assert fw.port != old_port and fw.alive
        c = Client(fw.port)
        try:
            assert c.status().startswith("<Idle|MPos:0.000,0.000,0.000|")  # MPos restarts at 0 ...
            assert fw.physical_x_mm() == pytest.approx(where)  # ... where the carriage stopped
            settings = dict(line.split("=") for line in c.command("$$") if line.startswith("$"))
            assert settings["$110"] == "6000.000"  # EEPROM.DAT kept what was written before the kill
            c.command("G91 G1 X10 F6000")
            assert mpos_x(c.wait_idle()) == 10.0 and fw.physical_x_mm() == pytest.approx(where + 10.0)
        finally:
            c.close()


def test_a_delayed_reply_is_held_and_lines_after_it_wait_behind_it(client, stock):
    stock.delay_next_reply(0.6)
    t0 = time.monotonic()
    client.send(b"?")
    time.sleep(0.1)
    client.send(b"$I\n")
    assert client.line(timeout_s=0.4) == b""  # nothing yet: the report is held and [VER...] waits behind it
    assert client.line().startswith(b"<Idle|")
    assert time.monotonic() - t0 >= 0.6
    assert client.until(r"^ok$")[0].startswith("[VER:")
    # the firmware answered at once: only the bridge held the reply
    report_t = next(e.t for e in reversed(stock.lines) if e.data.startswith("<Idle"))
    sent_t = next(e.t for e in reversed(stock.sent) if e.data == b"?")
    assert report_t - sent_t < 0.3


def test_a_dropped_byte_never_reaches_the_firmware(client, stock):
    stock.drop_next(b"?")
    client.send(b"?")
    assert client.line(timeout_s=0.4) == b""  # GRBL never saw it
    assert stock.sent[-1].data == b"?"  # the bridge did
    client.send(b"?")
    assert client.line().startswith(b"<Idle|")


def test_a_stalled_link_forwards_nothing_then_delivers_what_it_held(client, stock):
    t0 = time.monotonic()  # before the stall begins: it ends 0.6 s after its own start, which is after t0
    stock.stall(0.6)
    client.send(b"$I\n")
    assert client.line(timeout_s=0.45) == b""
    lines = client.until(r"^ok$")
    assert lines[0].startswith("[VER:1.1h") and time.monotonic() - t0 >= 0.6
    ver_t = next(e.t for e in reversed(stock.lines) if e.data.startswith("[VER:"))
    sent_t = next(e.t for e in reversed(stock.sent) if e.data == b"$I\n")
    assert ver_t - sent_t >= 0.55  # the firmware got the line only when the stall ended


def test_ctrl_f_and_0xff_from_the_client_are_ignored_as_a_real_grbl_would(client, stock):
    client.send(b"\x06\xff")  # grbl-sim would exit on either; the bridge keeps them from it
    time.sleep(0.2)
    assert stock.alive and client.status().startswith("<Idle|")


def test_query_talks_to_the_firmware_outside_the_clients_port(stock):
    lines = stock.query("$I")
    assert lines[0] == "[VER:1.1h.20190830:]" and lines[-1] == "ok"
    assert stock.status().startswith("<Idle|")
    ticks, seconds = stock.sim_clock()
    assert ticks > 16_000_000 and seconds > 1.0
    t0 = time.monotonic()
    time.sleep(0.5)
    _, later = stock.sim_clock()
    # simulated time keeps up with real time (the patched sim sleeps when idle instead of falling behind)
    assert (later - seconds) / (time.monotonic() - t0) == pytest.approx(1.0, abs=0.1)


#: a main program that loses its core for 150 ms after every 60 ms of a move or a homing cycle, as a loaded host's
#: scheduler may do to it: what the segment-underrun patch is for. Timed by the clock, not by counting segment
#: preps (every 400th, before): how often GRBL's loop preps depends on how the simulator sleeps, and once it slept
#: between its batches of ticks a 1 s move sometimes saw no stall that starved it
STALLED_MAIN = grbl_firmware.Patch(
    "test: stalled main program", "stepper.c",
    "void st_prep_buffer()\n{\n",
    "#include <time.h>\n"
    "void platform_sleep(long microsec);\n"
    "void st_prep_buffer()\n{\n"
    "  { static struct timespec last = {0, 0};\n"
    "    struct timespec now;\n"
    "    clock_gettime(CLOCK_MONOTONIC, &now);\n"
    "    long ms = (now.tv_sec - last.tv_sec) * 1000L + (now.tv_nsec - last.tv_nsec) / 1000000L;\n"
    "    if ((sys.state & (STATE_CYCLE | STATE_HOMING)) && ms >= 60) {\n"
    "      platform_sleep(150000);\n"
    "      clock_gettime(CLOCK_MONOTONIC, &last); } }\n",
)


def _stalled_firmware(fixed: bool):
    base = grbl_firmware.PATCHES if fixed else grbl_firmware.patches_without("segment-underrun")
    return grbl_firmware.build_firmware((*base, STALLED_MAIN))


def _first_idle(exe, tmp_path) -> tuple[str, int]:
    """Move 20 mm (1 s at 20 mm/s) under a flood of '?' (20 a millisecond, so that every pass of GRBL's realtime
    loop reports: a cycle ended and restarted at once shows as one Idle report); the first Idle report and how
    many reports came."""
    with GrblFirmware(tmp_path, exe=exe, rail_mm=400.0, x0_mm=10.0, settings={110: 1200, 120: 100}) as fw:
        ser = serial.Serial(fw.port, 115200, timeout=0)
        try:
            ser.write(b"G91 G1 X20 F1200\n")
            buf, reports, deadline = b"", 0, time.monotonic() + 20.0
            time.sleep(0.05)  # the line reaches the planner before the first '?'
            while time.monotonic() < deadline:
                ser.write(b"?" * 20)
                time.sleep(0.001)
                buf += ser.read(1 << 16)
                *lines, buf = buf.split(b"\n")
                for line in (raw.decode("latin-1").rstrip("\r") for raw in lines):
                    match = REPORT.match(line)
                    if match:
                        reports += 1
                        if match.group(1) == "Idle":
                            return line, reports
            raise AssertionError("the move never ended")
        finally:
            ser.close()


@pytest.mark.parametrize("fixed", [True, False], ids=["with the patch", "without it"])
def test_a_main_program_that_loses_its_core_mid_move_never_reports_idle_short_of_the_target(exe, tmp_path, fixed):
    """CI on a loaded 2-core machine saw a move end Idle at MPos 9.868 for 10.000 and a homing pull-off go the
    wrong way: grbl-sim's simulator thread, catching up with real time, ran the step segments faster than the
    descheduled main program could prep them, the buffer ran dry mid-move and GRBL ended the cycle there. Stall
    the main program on purpose (150 ms after every 60 ms of the move): without the segment-underrun patch the first Idle
    report comes short of 20 mm; with it, the simulated time waits for the main program, as the AVR's would."""
    report, reports = _first_idle(_stalled_firmware(fixed), tmp_path)
    if fixed:
        assert mpos_x(report) == 20.0, report
    else:
        assert mpos_x(report) < 20.0, f"the stall did not starve the stepper: {report} (so this test proves nothing)"


@pytest.mark.parametrize("fixed", [True, False], ids=["with the patch", "without it"])
def test_a_main_program_that_loses_its_core_while_homing_still_finds_the_switch(tmp_path, fixed):
    """The same stalls during `$H`: a homing search whose segments ran dry ended as if it had travelled its whole
    search distance without meeting the switch (ALARM:9, as CI saw with the switch 150 mm away on a 300 mm rail);
    with the patch it finds the switch and pulls off."""
    settings = {110: 1200, 120: 100, 22: 1, 25: 1200, 24: 300, 27: 2}
    with GrblFirmware(tmp_path, exe=_stalled_firmware(fixed), rail_mm=300.0, x0_mm=260.0, settings=settings) as fw:
        c = Client(fw.port)
        try:
            reply = c.command("$H", timeout_s=60.0)
        finally:
            c.close()
        if fixed:
            assert reply[-1] == "ok", reply
            assert fw.physical_x_mm() == pytest.approx(300.0 - 2.0)
        else:
            assert "ALARM:9" in reply, f"the stalls did not starve the homing search: {reply} (so this proves nothing)"
