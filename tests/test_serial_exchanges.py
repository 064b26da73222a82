"""The GRBL and Zaber drivers against the exchanges they should have with their controllers, instantly.

Each test gives the driver a scripted port (tests/exchanges.py): the (write, reply) pairs, in order, that the
controller would have with it, and fails at the first write that is not the next one expected. The port keeps
virtual time, so timeouts, polling and settling take none. What the controllers say is what the recorded
firmware said (tests/golden/grbl/, tests/test_grbl_golden.py) and what the simulators, held to it (and the Zaber
one to zaber-motion: tests/test_zaber_protocol.py), said to the driver over a real pty in the tests these
replace (once in tests/test_serial_stages.py): where they differ from what one might expect of GRBL or Zaber,
they win. The tests against the GRBL firmware itself (tests/test_grbl_firmware*.py) and the pty tests left stay
as the proof that the exchanges here are the real ones.
"""

from __future__ import annotations

import pytest

from drivers.errors import StageError
from drivers.serial import GrblStage, ZaberStage
from exchanges import UNPLUG, Later, expected_exchanges

PORT = "/dev/ttyFAKE0"


def raises_stage_error(port: str, *phrases: str):
    """Expect a one-line StageError that names the port and contains each phrase (in the order given)."""
    kind = "grbl" if port == PORT else "zaber"

    class Check:
        message = ""

        def __enter__(self):
            return self

        def __exit__(self, typ, exc, tb):
            assert typ is not None and issubclass(typ, StageError), f"no StageError, got {typ} {exc}"
            message = str(exc)
            assert message.startswith(f"{kind} {port}: ") and "\n" not in message, message
            at = 0
            for phrase in phrases:
                found = message.find(phrase, at)
                assert found >= 0, f"{phrase!r} not in {message[at:]!r} (the whole message: {message!r})"
                at = found + len(phrase)
            self.message = message
            return True

    return Check()


# === GRBL ===============================================================================================
#
# The controller of most tests: GRBL 1.1h built with HOMING_FORCE_SET_ORIGIN (`Z` in $I's OPT), homing
# towards -X ($23=1) with no pull-off ($27=0), so machine X is the distance from the home switch; soft limits
# on ($20=1), $110 = 3000 mm/min, $120 = 100 mm/s^2, $130 = 3000 mm. The driver at its defaults (timeout 2 s,
# poll 0.05 s, settle 0.2 s, feed 3000) with offset_m = 0.3: rail zero is 0.3 m from the wall, 1.0 m is X700.

BANNER = b"\r\nGrbl 1.1h ['$' for help]\r\n"  # report.c prints a blank line first
UNLOCK = b"[MSG:'$H'|'$X' to unlock]\r\n"  # after a reset in Alarm (homing enabled)
OK = b"ok\r\n"
WCO = "|WCO:0.000,0.000,0.000"

#: `$$` of a freshly flashed 1.1h (tests/golden/grbl/queries.txt)
STOCK = {0: "10", 1: "25", 2: "0", 3: "0", 4: "0", 5: "0", 6: "0", 10: "1", 11: "0.010", 12: "0.002", 13: "0",
         20: "0", 21: "0", 22: "0", 23: "0", 24: "25.000", 25: "500.000", 26: "250", 27: "1.000", 30: "1000",
         31: "0", 32: "0", 100: "250.000", 101: "250.000", 102: "250.000", 110: "500.000", 111: "500.000",
         112: "500.000", 120: "10.000", 121: "10.000", 122: "10.000", 130: "200.000", 131: "200.000",
         132: "200.000"}
RIG = {20: "1", 22: "1", 23: "1", 27: "0.000", 110: "3000.000", 120: "100.000", 130: "3000.000"}


def dollars(changes: dict[int, str] = RIG) -> bytes:
    """The reply to `$$`: every setting, one a line, then ok."""
    return b"".join(f"${n}={v}\r\n".encode() for n, v in {**STOCK, **changes}.items()) + OK


def build_info(opt: str = "VZ,15,128") -> bytes:
    return f"[VER:1.1h.20190830:]\r\n[OPT:{opt}]\r\nok\r\n".encode()


def report(state: str, x_mm: float, feed: float = 0.0, extra: str = "") -> bytes:
    """A status report with MPos ($10=1), as 1.1h prints it."""
    return f"<{state}|MPos:{x_mm:.3f},0.000,0.000|FS:{feed:.0f},0{extra}>\r\n".encode()


def soft_reset(*after_banner: bytes) -> list:
    """The driver's soft reset: wake-up (each line end answered 'ok'; the input is then discarded), Ctrl-X, and
    the banner (a few ms later: the oks come first, as they do over a real port)."""
    return [(b"\r\n\r\n", Later(0.002, OK * 4)), (b"\x18", Later(0.05, BANNER + b"".join(after_banner)))]


def connect(first: bytes = report("Alarm", 0.0, extra=WCO), settings: dict[int, str] = RIG,
            opt: str = "VZ,15,128", after_banner: tuple[bytes, ...] = (UNLOCK,)) -> list:
    """open(): one '?' (is the carriage moving?), a soft reset, `$$`, `$I`, and a '?' that reads the position."""
    state = first[1:].split(b"|")[0].decode()
    return [(b"?", first), *soft_reset(*after_banner), (b"$$\n", dollars(settings)), (b"$I\n", build_info(opt)),
            (b"?", report(state if state in ("Idle", "Alarm") else "Idle", 0.0))]


def home(x_mm: float = 0.0) -> list:
    """home() of a controller in Alarm (as after power-up with homing on): '?', a soft reset, '?', $H, G90 G21."""
    return [(b"?", report("Alarm", x_mm)), *soft_reset(UNLOCK), (b"?", report("Alarm", x_mm, extra=WCO)),
            (b"$H\n", OK), (b"G90 G21\n", OK)]


def move(x_mm: float, *reports: bytes, feed: str = "3000") -> list:
    """A move to machine X: the line, its ok, and one '?' for each report given."""
    return [(f"G21 G53 G1 X{x_mm:.3f} F{feed}\n", OK), *[(b"?", r) for r in reports]]


def grbl(**options) -> GrblStage:
    return GrblStage(PORT, **options)


def test_grbl_connects_with_a_soft_reset_and_reads_the_controller():
    stage = grbl()
    with expected_exchanges(stage, connect()):
        stage.open()
    assert stage.firmware == "1.1h" and stage.options == "VZ,15,128"
    assert stage.settings[130] == 3000.0 and stage.settings[22] == 1.0
    assert stage.limits_m == pytest.approx((0.3, 3.3))
    assert (stage.home_mm, stage.away, stage.feed_mm_min) == (0.0, 1, 3000.0)
    assert stage.setup_problems() == []


def test_grbl_homes_after_a_reset_out_of_the_power_up_alarm_and_reads_the_rail_zero():
    stage = grbl()
    with expected_exchanges(stage, [*connect(), *home(), (b"?", report("Idle", 0.0))]):
        stage.open()
        stage.home()
        assert stage.position_m() == pytest.approx(0.3)  # rail zero is offset_m


def test_grbl_homing_from_idle_does_not_reset():
    stage = grbl()
    with expected_exchanges(stage, [*connect(), (b"?", report("Idle", 250.0)), (b"$H\n", OK), (b"G90 G21\n", OK)]):
        stage.open()
        stage.home()


def test_grbl_move_polls_until_idle_then_settles_and_reads_the_position():
    stage = grbl()
    script = [*connect(), *home(),
              *move(700.0, report("Run", 0.5, 3000), report("Run", 350.0, 3000), report("Idle", 700.0)),
              (b"?", report("Idle", 700.0))]
    with expected_exchanges(stage, script) as port:
        stage.open()
        stage.home()
        port.clock.sleeps.clear()
        assert stage.move_to(1.0) == pytest.approx(1.0)
    assert port.clock.sleeps == [0.05, 0.05, 0.2]  # two polls, then the settling before the position is read


def test_grbl_caps_the_feed_at_the_controllers_maximum_rate():
    stage = grbl(feed_mm_min=1e7, settle_s=0.0)
    script = [*connect(), *home(), *move(700.0, report("Run", 1.0, 3000), report("Idle", 700.0), feed="3000"),
              (b"?", report("Idle", 700.0))]
    with expected_exchanges(stage, script):
        stage.open()
        assert stage.feed_mm_min == 3000.0 and stage.requested_feed_mm_min == 1e7
        stage.home()
        stage.move_to(1.0)


def test_grbl_counts_idle_twice_in_a_row_as_a_move_that_is_over_before_it_was_seen():
    stage = grbl(settle_s=0.0)
    script = [*connect(), *home(), *move(0.0, report("Idle", 0.0), report("Idle", 0.0)),
              (b"?", report("Idle", 0.0))]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        assert stage.move_to(0.3) == pytest.approx(0.3)


@pytest.mark.parametrize("offset_m,direction,targets", [
    (0.3, 1, [(0.5, 200.0), (1.75, 1450.0), (3.0, 2700.0), (0.8, 500.0)]),
    (3.3, -1, [(0.5, 2800.0), (1.75, 1550.0), (3.0, 300.0), (0.8, 2500.0)]),
])
def test_grbl_moves_land_where_commanded(offset_m, direction, targets):
    stage = grbl(offset_m=offset_m, direction=direction, settle_s=0.0)
    script = [*connect(), *home()]
    for _, x in targets:
        script += [*move(x, report("Run", x / 2, 3000), report("Idle", x)), (b"?", report("Idle", x))]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        assert stage.limits_m == pytest.approx((0.3, 3.3))
        for position_m, _ in targets:
            assert stage.move_to(position_m) == pytest.approx(position_m, abs=1e-9)


def test_grbl_stock_machine_space_homes_towards_plus_x_and_moves_in_minus_x():
    # stock $23=0 and $27=1 without HOMING_FORCE_SET_ORIGIN: homing leaves MPos at -$27 and the rail runs
    # towards -X, -$130..0 (tests/golden/grbl/homing.txt: MPos -2.000 after $H with $27=2)
    settings = {20: "1", 22: "1", 110: "3000.000", 120: "100.000"}
    stage = grbl(settle_s=0.0)
    script = [*connect(settings=settings, opt="V,15,128"), *home(x_mm=-1.0),
              *move(-51.0, report("Run", -20.0, 3000), report("Idle", -51.0)), (b"?", report("Idle", -51.0))]
    with expected_exchanges(stage, script):
        stage.open()
        assert (stage.home_mm, stage.away) == (-1.0, -1)
        assert stage.limits_m == pytest.approx((0.3, 0.3 + 0.199))
        stage.home()
        assert stage.move_to(0.35) == pytest.approx(0.35)


def test_grbl_refuses_moves_before_homing_and_beyond_the_travel_without_sending_anything():
    stage = grbl()
    with expected_exchanges(stage, connect()):  # any write after open() fails the test
        stage.open()
        with raises_stage_error(PORT, "not homed", "home the stage"):
            stage.move_to(1.0)
    stage = grbl()
    with expected_exchanges(stage, [*connect(), *home()]):
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "outside the travel limits 0.300-3.300 m"):
            stage.move_to(3.35)
        with raises_stage_error(PORT, "outside the travel limits"):
            stage.move_to(0.1)


def test_grbl_the_very_end_of_the_travel_is_allowed():
    stage = grbl(settle_s=0.0)
    script = [*connect(), *home(), *move(3000.0, report("Run", 10.0, 3000), report("Idle", 3000.0)),
              (b"?", report("Idle", 3000.0))]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        assert stage.move_to(stage.limits_m[1]) == pytest.approx(3.3)


def test_grbl_position_outside_the_tolerance_fails_the_move_and_inside_it_is_measured():
    stage = grbl(settle_s=0.0)
    script = [*connect(), *home(),
              *move(1700.0, report("Run", 900.0, 3000), report("Idle", 1703.0)), (b"?", report("Idle", 1703.0)),
              *move(1200.0, report("Run", 1500.0, 3000), report("Idle", 1200.4)), (b"?", report("Idle", 1200.4))]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "commanded 2.0000 m but measured 2.0030 m", "tolerance 1.0 mm"):
            stage.move_to(2.0)
        assert stage.move_to(1.5) == pytest.approx(1.5004, abs=1e-9)


# --- GRBL: connecting to what is not a ready GRBL --------------------------------------------------------


def test_grbl_wrong_device_gives_no_banner():
    stage = grbl()
    silent = [(b"?", None), (b"\r\n\r\n", None), (b"\x18", None), (b"\x18", None)]  # Ctrl-X is tried twice
    with expected_exchanges(stage, silent) as port:
        with raises_stage_error(PORT, "no GRBL banner within 4.0 s of a soft reset (got nothing)",
                                "this port is the GRBL controller", "baud=115200"):
            stage.open()
    assert not port.is_open  # closed again


def test_grbl_a_board_that_resets_when_the_port_opens_gets_a_second_ctrl_x():
    stage = grbl()
    script = [(b"?", None), (b"\r\n\r\n", None), (b"\x18", None), (b"\x18", BANNER), (b"$$\n", dollars()),
              (b"$I\n", build_info()), (b"?", report("Idle", 0.0))]
    with expected_exchanges(stage, script):
        stage.open()


def test_grbl_homing_disabled_on_the_controller_is_refused_unless_the_device_string_says_homing_0():
    no_homing = {22: "0", 20: "0", 110: "3000.000", 120: "100.000", 130: "3000.000"}
    stage = grbl()
    with expected_exchanges(stage, connect(report("Idle", 0.0), no_homing, after_banner=())[:-1]) as port:
        with raises_stage_error(PORT, "homing is disabled on the controller ($22=0)", "homing=0"):
            stage.open()
    assert not port.is_open
    stage = grbl(homing=False)
    script = [*connect(report("Idle", 0.0), no_homing, after_banner=()), (b"?", report("Idle", 0.0)),
              (b"$X\n", OK), (b"G90 G21\n", OK)]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()  # $X only: positions count from where the carriage was at power-up


def test_grbl_homing_0_against_a_controller_in_alarm_from_before_is_refused():
    # homing off on both sides and the controller in alarm (a reset while moving, a limit, sleep): rail zero is lost
    no_homing = {22: "0", 20: "0", 110: "3000.000", 120: "100.000", 130: "3000.000"}
    stage = grbl(homing=False)
    script = [*connect(report("Idle", 0.0), no_homing, after_banner=()), (b"?", report("Alarm", 40.0)),
              *soft_reset(UNLOCK), (b"?", report("Alarm", 40.0, extra=WCO))]
    with expected_exchanges(stage, script):
        stage.open()
        with raises_stage_error(PORT, "the controller is in alarm from before", "rail zero cannot be found again"):
            stage.home()


def test_grbl_startup_line_echo_and_inch_reports_are_understood():
    # $N0=G20 echoes '>G20:ok' after the banner; $13=1 reports in inches (tests/golden/grbl/startup_inches_jog.txt)
    inches = {13: "1", 110: "3000.000", 120: "100.000", 130: "3000.000"}
    stage = grbl(homing=False, settle_s=0.0)
    inch = lambda state, x_in: f"<{state}|MPos:{x_in:.4f},0.0000,0.0000|FS:0.0,0>\r\n".encode()  # noqa: E731
    script = [(b"?", inch("Idle", 0.0)), *soft_reset(b">G20:ok\r\n"), (b"$$\n", dollars(inches)),
              (b"$I\n", build_info("V,15,128")), (b"?", inch("Idle", 0.0)),
              (b"?", inch("Idle", 0.0)), (b"$X\n", OK), (b"G90 G21\n", OK),
              *move(700.0, inch("Run", 10.0), inch("Idle", 27.5591)), (b"?", inch("Idle", 27.5591))]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        assert stage.move_to(1.0) == pytest.approx(1.0, abs=1e-4)  # 4 decimals of an inch: 2.5 um


def test_grbl_work_positions_are_machine_positions_plus_the_last_work_offset():
    # $10=0: reports give WPos, and WCO only in the first after a reset, then every 10th idle
    # (tests/golden/grbl/report_mask.txt); before any WCO the driver asks again after a poll interval
    wpos = {10: "0", 22: "0", 110: "3000.000", 120: "100.000", 130: "3000.000"}
    stage = grbl(homing=False)
    w = lambda x, extra="": f"<Idle|WPos:{x:.3f},0.000,0.000|FS:0,0{extra}>\r\n".encode()  # noqa: E731
    offset = "|WCO:50.000,0.000,0.000"
    script = [(b"?", w(-10.0)), (b"?", w(-10.0)), (b"?", w(-10.0, offset)),  # open(): is it moving? (WCO awaited)
              *soft_reset(), (b"$$\n", dollars(wpos)), (b"$I\n", build_info("V,15,128")),
              (b"?", w(-10.0, offset)), (b"?", w(-10.0))]
    with expected_exchanges(stage, script) as port:
        stage.open()
        assert stage.link.last_x_mm == 40.0
        assert stage.position_m() == pytest.approx(0.34)  # WPos -10 + WCO 50: machine X 40
    assert port.clock.sleeps == [0.05, 0.05]


# --- GRBL: a link that is not clean ---------------------------------------------------------------------


def test_grbl_an_unanswered_status_request_is_asked_again_and_three_are_an_error():
    stage = grbl()
    script = [*connect(), *home(), (b"?", None), (b"?", report("Idle", 0.0)),
              (b"?", None), (b"?", None), (b"?", None), (b"?", report("Idle", 0.0))]
    with expected_exchanges(stage, script) as port:
        stage.open()
        stage.home()
        assert stage.position_m() == pytest.approx(0.3)
        before = port.clock.now
        with raises_stage_error(PORT, "no reply to '?' in 3 tries of 2.0 s", "check the USB cable"):
            stage.position_m()
        assert port.clock.now - before == pytest.approx(6.0)  # three timeouts, in virtual time
        assert stage.position_m() == pytest.approx(0.3)  # the next exchange works


def test_grbl_a_move_line_whose_ok_is_lost_is_sent_again():
    stage = grbl(settle_s=0.0)
    script = [*connect(), *home(), ("G21 G53 G1 X700.000 F3000\n", None),
              *move(700.0, report("Run", 100.0, 3000), report("Idle", 700.0)), (b"?", report("Idle", 700.0))]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        assert stage.move_to(1.0) == pytest.approx(1.0)


def test_grbl_a_move_line_lost_twice_is_an_error_and_the_carriage_is_held_and_reset():
    # every line is idempotent, so it is sent twice; then, as the move may have started, a feed hold; the hold
    # is complete at once (Hold:0 from Idle: tests/golden/grbl/hold.txt), so a reset keeps the position
    stage = grbl()
    line = "G21 G53 G1 X1700.000 F3000\n"
    script = [*connect(), *home(), (line, None), (line, None), (b"!", None), (b"?", report("Hold:0", 0.0)),
              *soft_reset()]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "no reply to 'G21 G53 G1 X1700.000 F3000' in 2 tries of 2.0 s",
                                "the carriage was stopped (a feed hold, then a reset once the hold was complete"):
            stage.move_to(2.0)


def test_grbl_a_garbled_report_is_asked_again_and_three_are_named_as_a_bad_link():
    stage = grbl()
    noisy = b"<Idle|MPPs:0.000,0.000,0.000|FS:0,0>\r\n"  # a flipped letter: GRBL has no checksum
    script = [*connect(), *home(), (b"?", noisy), (b"?", report("Idle", 0.0)),
              (b"?", noisy), (b"?", b"<Idle|MPos::0.000\xfe\r\n"), (b"?", noisy)]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        assert stage.position_m() == pytest.approx(0.3)
        with raises_stage_error(PORT, "no clean reply to '?' in 3 tries (3 garbled, the last",
                                "baud=115200", "away from the motor wiring"):
            stage.position_m()


def test_grbl_a_late_line_end_is_joined_to_the_start_that_came_in_time():
    stage = grbl()
    first, rest = report("Idle", 250.0)[:12], report("Idle", 250.0)[12:]
    script = [*connect(), *home(), (b"?", [first, Later(3.0, rest)]), (b"?", report("Idle", 250.0))]
    with expected_exchanges(stage, script) as port:
        stage.open()
        stage.home()
        assert stage.position_m() == pytest.approx(0.55)  # the start, then the end (late), make one report
    assert port.input == report("Idle", 250.0)  # the second report is stale: the next request drops it


def test_grbl_unplugged_port_is_named():
    stage = grbl()
    with expected_exchanges(stage, [*connect(), *home(), (b"?", UNPLUG)]):
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "port disconnected while waiting for the reply to '?'", "check the USB cable"):
            stage.position_m()
        assert not stage.link.is_open


# --- GRBL: errors and alarms the controller raises -------------------------------------------------------


def test_grbl_an_error_reply_is_named_with_its_meaning_and_nothing_is_stopped():
    stage = grbl()
    script = [*connect(), *home(), ("G21 G53 G1 X700.000 F3000\n", b"error:9\r\n")]
    with expected_exchanges(stage, script):  # a refused line moved nothing: no hold, no reset
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "controller answered error:9 (G-code locked out during alarm or jog) to "
                                      "'G21 G53 G1 X700.000 F3000'", "re-home the stage"):
            stage.move_to(1.0)


def test_grbl_homing_with_homing_disabled_is_error_5():
    # tests/golden/grbl/homing.txt: '$H' with $22=0 is answered error:5
    stage = grbl()
    with expected_exchanges(stage, [*connect(), (b"?", report("Idle", 0.0)), (b"$H\n", b"error:5\r\n")]):
        stage.open()
        with raises_stage_error(PORT, "error:5 (homing is not enabled ($22=0)) to '$H'", "enable homing"):
            stage.home()


def test_grbl_soft_limit_alarm_silence_and_recovery():
    # tests/golden/grbl/soft_limits.txt: a target beyond the soft limits is ALARM:2 and [MSG:Reset to continue];
    # then GRBL is silent, even to '?', until a reset, which brings the late 'ok' of the line, the banner, and
    # [MSG:'$H'|'$X' to unlock]
    stage = grbl(rail_min_mm=0.0, travel_mm=3000.0, settle_s=0.0)
    settings = {**RIG, 130: "2000.000"}
    script = [*connect(settings=settings), *home(),
              ("G21 G53 G1 X2500.000 F3000\n", b"ALARM:2\r\n[MSG:Reset to continue]\r\n"),
              (b"?", None), (b"?", None), (b"?", None),  # silent
              (b"?", None), (b"?", None), (b"?", None),  # home(): is anyone there? (silent: reset)
              (b"\r\n\r\n", None), (b"\x18", Later(0.05, OK + BANNER + UNLOCK)),
              (b"?", report("Alarm", 0.0, extra=WCO)), (b"$H\n", OK), (b"G90 G21\n", OK),
              *move(700.0, report("Run", 50.0, 3000), report("Idle", 700.0)), (b"?", report("Idle", 700.0))]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "ALARM:2 during 'G21 G53 G1 X2500.000 F3000' (soft limit",
                                "the controller allows machine X only within 0..2000 mm ($130=2000, homing towards "
                                "-X with HOMING_FORCE_SET_ORIGIN)", "make rail_min_mm and travel_mm lie within them"):
            stage.move_to(2.8)  # inside the driver's travel, beyond the controller's
        with raises_stage_error(PORT, "controller silent after ALARM:2", "until a reset", "homing sends the reset"):
            stage.position_m()
        with raises_stage_error(PORT, "not homed"):
            stage.move_to(1.0)
        stage.home()
        assert stage.move_to(1.0) == pytest.approx(1.0)


def test_grbl_soft_limits_the_rail_cannot_respect_are_named_before_anything_moves():
    stage = grbl(rail_min_mm=0.0, travel_mm=3000.0)
    with expected_exchanges(stage, connect(settings={**RIG, 130: "2000.000"})):
        stage.open()
    [problem] = stage.setup_problems()
    assert "soft limits are on ($20=1) and allow machine X only within 0..2000 mm" in problem
    assert "runs over machine X 0..3000 mm" in problem


def test_grbl_hard_limit_mid_move_is_alarm_1_then_silence_until_homing_resets():
    stage = grbl()
    script = [*connect(), *home(), *move(2200.0, report("Run", 800.0, 3000), report("Run", 1200.0, 3000),
                                         b"ALARM:1\r\n[MSG:Reset to continue]\r\n")]
    recover = [(b"?", None)] * 3 + [*soft_reset(UNLOCK), (b"?", report("Alarm", 1200.0, extra=WCO)),
                                    (b"$H\n", OK), (b"G90 G21\n", OK)]  # silent after ALARM:1 until a reset
    script += [*recover, *move(1700.0, report("Run", 1000.0, 3000), report("Idle", 1700.0)),
               (b"?", report("Idle", 1700.0))]
    with expected_exchanges(stage, script):  # the alarm stopped the motors itself: no hold, no reset
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "ALARM:1 during 'G21 G53 G1 X2200.000 F3000' (hard limit triggered",
                                "free the carriage from the limit switch"):
            stage.move_to(2.5)
        assert stage.link.position_lost and stage.link.alarm == "ALARM:1"
        with raises_stage_error(PORT, "not homed"):
            stage.move_to(2.0)
        stage.home()
        assert stage.move_to(2.0) == pytest.approx(2.0)


def test_grbl_an_alarm_pushed_between_requests_is_raised_by_the_next_one():
    # the limit switch trips while nobody asks: the ALARM line waits in the input, read before the next '?'
    stage = grbl()
    with expected_exchanges(stage, [*connect(), *home()]) as port:
        stage.open()
        stage.home()
        port.push(b"ALARM:1\r\n[MSG:Reset to continue]\r\n")
        with raises_stage_error(PORT, "ALARM:1 during '?' (hard limit triggered"):
            stage.position_m()


def test_grbl_homing_failure_then_its_reset_banner_is_not_an_unexpected_reset():
    # a failed homing is ALARM:9; report.c then pauses 500 ms, '$H' gets its 'ok' (system_execute_line returns
    # STATUS_OK even so), and the controller resets itself: banner and unlock message. So answers the firmware
    # (grbl-sim, tests/grbl_firmware.py: $130=50 with the switch 200 mm away), though tests/golden/grbl/ has no
    # transcript of it and the simulator sends no 'ok'; the driver must pass over both the 'ok' and the banner
    stage = grbl()
    script = [*connect(), (b"?", report("Alarm", 0.0)), *soft_reset(UNLOCK), (b"?", report("Alarm", 0.0, extra=WCO)),
              (b"$H\n", [b"ALARM:9\r\n", Later(0.5, OK + BANNER + UNLOCK)]),
              (b"?", report("Alarm", -600.0, extra=WCO)),
              *home(x_mm=-600.0), (b"?", report("Idle", 0.0))]
    with expected_exchanges(stage, script):
        stage.open()
        with raises_stage_error(PORT, "ALARM:9 during homing ($H) (homing failed: limit switch not found",
                                "check the home switch wiring"):
            stage.home()
        assert stage.position_m() == pytest.approx(-0.3)  # the banner on the way is passed over, not an error
        stage.home()
        assert stage.position_m() == pytest.approx(0.3)


def test_grbl_unexpected_reset_is_reported_and_the_stage_must_home_again():
    # a power cycle: the banner arrives unasked, the controller is in Alarm and MPos starts again
    stage = grbl(settle_s=0.0)
    script = [*connect(), *home(), *move(700.0, report("Run", 300.0, 3000), report("Idle", 700.0)),
              (b"?", report("Idle", 700.0)), *home(),
              *move(1200.0, report("Run", 300.0, 3000), report("Idle", 1200.0)), (b"?", report("Idle", 1200.0))]
    with expected_exchanges(stage, script) as port:
        stage.open()
        stage.home()
        stage.move_to(1.0)
        port.push(BANNER + UNLOCK)
        with raises_stage_error(PORT, "controller reset unexpectedly during '?'", "position lost",
                                "check its power supply"):
            stage.position_m()  # the banner is read before the '?' is sent: nothing is written
        with raises_stage_error(PORT, "not homed"):
            stage.move_to(1.5)
        stage.home()
        assert stage.move_to(1.5) == pytest.approx(1.5)


@pytest.mark.parametrize("state,phrases", [
    ("Alarm", ("controller in Alarm during", "check the rail and limit switches")),
    ("Door:1", ("safety door open during", "close it")),
    ("Sleep", ("controller in Sleep mode during", "a reset wakes it")),
    ("Check", ("controller in Check mode during", "$C toggles check mode")),
])
def test_grbl_a_state_in_which_nothing_moves_ends_the_wait(state, phrases):
    stage = grbl()
    script = [*connect(), *home(), *move(700.0, report("Run", 100.0, 3000), report(state, 150.0)),
              (b"!", None), (b"?", report(state, 150.0)), *soft_reset()]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(PORT, *phrases, "the carriage was stopped"):
            stage.move_to(1.0)


# --- GRBL: feed holds (1.1h: Hold:1 while decelerating, Hold:0 once still; a reset only in Hold:0) ----------


def test_grbl_a_feed_hold_pressed_on_the_controller_fails_the_move_once_it_has_lasted_stall_s():
    # someone pressed hold: Hold:1 while it brakes, then Hold:0; the driver does not resume it ('~'), it waits
    # stall_s (0.175 s here: 4 polls of 0.05 s) without motion, then stops the run; as the hold is complete,
    # the reset keeps the position
    stage = grbl(stall_s=0.175)
    held = [report("Hold:0", 430.0)] * 4
    script = [*connect(), *home(),
              *move(700.0, report("Run", 100.0, 3000), report("Hold:1", 400.0, 1500), report("Hold:1", 430.0, 200),
                    *held),
              (b"!", None), (b"?", report("Hold:0", 430.0)), *soft_reset()]
    with expected_exchanges(stage, script) as port:
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "feed hold during 'G21 G53 G1 X700.000 F3000' (X 430.000 mm)",
                                "the carriage was stopped (a feed hold, then a reset once the hold was complete"):
            stage.move_to(1.0)
    assert b"~" not in port.written


def test_grbl_a_stuck_carriage_is_held_and_reset_only_once_the_hold_is_complete():
    # Run with X unchanged for stall_s: stuck. The hold brakes (Hold:1, asked again after a poll interval,
    # '!' sent again each time) until Hold:0; only then the reset (a reset in Hold:1 would be ALARM:3)
    stage = grbl(stall_s=0.175)  # X unchanged over 4 polls of 0.05 s after the first report at 250
    stuck = [report("Run", 250.0, 3000)] * 5
    script = [*connect(), *home(), *move(700.0, report("Run", 100.0, 3000), *stuck),
              (b"!", None), (b"?", report("Hold:1", 250.4, 900)), (b"!", None), (b"?", report("Hold:1", 250.5, 100)),
              (b"!", None), (b"?", report("Hold:0", 250.5)), *soft_reset()]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "stuck during 'G21 G53 G1 X700.000 F3000': X has stayed at 250.000 mm for",
                                "in state Run", "the carriage was stopped (a feed hold, then a reset once the hold "
                                "was complete: position kept)"):
            stage.move_to(1.0)


def test_grbl_a_hold_that_never_completes_is_not_reset():
    # the deadline for the hold: three times the braking from 3000 mm/min at 100 mm/s^2 (1.5 s), plus two reply
    # times (4 s) and a second: 6.5 s, polled every 0.4 s: 18 tries (the last at 6.8 s); Hold:1 all along, so no
    # Ctrl-X is ever sent
    stage = grbl(stall_s=0.6, poll_s=0.4)
    stuck = [report("Run", 250.0, 3000)] * 3
    braking = [(b"!", None), (b"?", report("Hold:1", 250.1, 3000))] * 18
    script = [*connect(), *home(), *move(700.0, report("Run", 100.0, 3000), *stuck), *braking]
    with expected_exchanges(stage, script) as port:
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "stuck during", "a feed hold was sent but it still reported Hold:1 at "
                                "X 250.100 mm, so the controller was not reset", "resuming stops it safely first"):
            stage.move_to(1.0)
    assert port.written.count(b"\x18") == 2  # the two of open() and home(), none since


@pytest.mark.parametrize("first", ["Run", "Jog", "Hold:1"])
def test_grbl_connecting_to_a_moving_carriage_holds_it_and_resets_only_in_hold_0(first):
    # a run was interrupted with the carriage moving (or braking in a hold): open() must not reset it in Run,
    # Jog or Hold:1 (ALARM:3, the position lost: tests/golden/grbl/hold.txt), so it holds it and waits for Hold:0
    stage = grbl()
    script = [(b"?", report(first, 900.0, 3000)),
              (b"!", None), (b"?", report("Hold:1", 910.0, 2000)), (b"!", None), (b"?", report("Hold:0", 915.0)),
              *soft_reset(), (b"$$\n", dollars()), (b"$I\n", build_info()), (b"?", report("Idle", 915.0))]
    with expected_exchanges(stage, script) as port:
        stage.open()
    assert port.clock.sleeps == [0.05]  # one poll between the two holds


def test_grbl_connecting_to_a_complete_hold_resets_at_once():
    # Hold:0: the carriage is still, and a reset then keeps the position (tests/golden/grbl/hold.txt)
    stage = grbl()
    script = [(b"?", report("Hold:0", 900.0)), *soft_reset(), (b"$$\n", dollars()), (b"$I\n", build_info()),
              (b"?", report("Idle", 900.0))]
    with expected_exchanges(stage, script):
        stage.open()


def test_grbl_a_move_that_takes_far_longer_than_its_settings_allow_is_stopped():
    # 700 mm at 3000 mm/min and 100 mm/s^2 should take 14.5 s; after 2 x 14.5 + 10 = 39 s of creeping (X keeps
    # changing, so it is not stuck) the driver gives up, polling every 4 s here
    stage = grbl(poll_s=4.0)
    creeping = [report("Run", 10.0 * i, 3000) for i in range(1, 12)]
    script = [*connect(), *home(), *move(700.0, *creeping), (b"!", None), (b"?", report("Hold:0", 110.0)),
              *soft_reset()]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(PORT, "still moving 40.0 s after 'G21 G53 G1 X700.000 F3000' (state Run, "
                                "X 110.000 mm), though 14.5 s should do at F3000 ($110=3000, $120=100)",
                                "the carriage was stopped"):
            stage.move_to(1.0)


# === Zaber ==============================================================================================
#
# A Zaber device 1, axis 1, as the simulator and the firmware answer: every command carries a message id
# (01-99, then 00) and a checksum; replies echo the id, and carry a checksum only with comm.checksum 1. The
# driver at its defaults with offset_m = 0.3 (1.0 m is 700 mm from home: 3674541 microsteps of 0.1905 um).

ZPORT = "/dev/ttyFAKE1"


def zaber_checksum(body: str) -> str:
    """Zaber ASCII protocol manual, "Checksums": the byte sum of the message and its checksum is 0 mod 256."""
    return f"{(256 - sum(body.encode('ascii')) % 256) % 256:02X}"


def z(message_id: int, command: str, axis: int = 1) -> bytes:
    """What the driver sends: '/1 1 07 get pos:24'."""
    body = f"1 {axis} {message_id:02d} {command}"
    return f"/{body}:{zaber_checksum(body)}\n".encode()


def zr(message_id: int, data: str, status: str = "IDLE", flag: str = "--", axis: int = 1, reply: str = "OK",
       checksum: bool = False) -> bytes:
    """A reply: '@01 1 07 OK IDLE -- 0'."""
    body = f"01 {axis} {message_id:02d} {reply} {status} {flag} {data}"
    return f"@{body}{':' + zaber_checksum(body) if checksum else ''}\r\n".encode()


def steps_of(position_m: float, offset_m: float = 0.3, direction: int = 1) -> int:
    return round(direction * (position_m - offset_m) * 1e6 / 0.1905)


def zconnect(limit_max: int = 15748031, resolution: int = 64, device_id: str = "50081", flag: str = "WR") -> list:
    """open(): who the device is (axis 0), its resolution, its travel."""
    return [(z(1, "get deviceid", 0), zr(1, device_id, flag=flag, axis=0)),
            (z(2, "get system.serial", 0), zr(2, "1234567", flag=flag, axis=0)),
            (z(3, "get version", 0), zr(3, "7.38", flag=flag, axis=0)),
            (z(4, "get resolution"), zr(4, str(resolution), flag=flag)),
            (z(5, "get limit.min"), zr(5, "0", flag=flag)),
            (z(6, "get limit.max"), zr(6, str(limit_max), flag=flag))]


def zhome(first: int = 7, pos: int = 0, flag: str = "WR") -> list:
    """home(): stop, wait for IDLE, clear the warnings, home, poll until IDLE."""
    return [(z(first, "stop"), zr(first, str(pos), flag=flag)),
            (z(first + 1, "get pos"), zr(first + 1, str(pos), flag=flag)),
            (z(first + 2, "warnings clear"), zr(first + 2, f"01 {flag}" if flag != "--" else "00", flag=flag)),
            (z(first + 3, "home"), zr(first + 3, str(pos), "BUSY", flag)),
            (z(first + 4, "get pos"), zr(first + 4, str(pos // 2), "BUSY", flag)),
            (z(first + 5, "get pos"), zr(first + 5, "0"))]


def zmove(first: int, steps: int, *busy_at: int) -> list:
    """move_to(): move abs, 'get pos' BUSY at each of busy_at then IDLE, then the reading after settling."""
    out = [(z(first, f"move abs {steps}"), zr(first, str(busy_at[0] if busy_at else 0), "BUSY"))]
    n = first + 1
    for at in busy_at:
        out.append((z(n, "get pos"), zr(n, str(at), "BUSY")))
        n += 1
    return [*out, (z(n, "get pos"), zr(n, str(steps))), (z(n + 1, "get pos"), zr(n + 1, str(steps)))]


def zaber(**options) -> ZaberStage:
    return ZaberStage(ZPORT, **options)


def test_zaber_commands_carry_the_checksum_the_manual_defines():
    assert z(1, "get deviceid", 0) == b"/1 0 01 get deviceid:41\n"  # as recorded over a pty from the simulator
    assert z(7, "stop") == b"/1 1 07 stop:11\n"
    assert zaber_checksum("0 0 00") == "00"  # zaber-motion's first message is '/0 0 00:00'


def test_zaber_connect_reads_identity_resolution_and_travel():
    stage = zaber(offset_m=0.4)
    with expected_exchanges(stage, zconnect(limit_max=10498687)):
        stage.open()
    assert stage.limits_m == pytest.approx((0.4, 0.4 + 10498687 * 0.1905e-6))
    assert stage.identity == {"deviceid": "50081", "system.serial": "1234567", "version": "7.38", "resolution": "64"}


def test_zaber_a_changed_resolution_scales_the_microstep():
    stage = zaber()
    with expected_exchanges(stage, zconnect(resolution=128)):
        stage.open()
    assert stage.microstep_um == pytest.approx(0.1905 / 2)
    assert stage.describe()["device_resolution"] == "128"


def test_zaber_the_device_id_the_device_string_pins_is_checked():
    stage = zaber(device_id=50419)
    with expected_exchanges(stage, zconnect()[:4]) as port:
        with raises_stage_error(ZPORT, "device 1 is deviceid 50081 (serial 1234567), not deviceid 50419"):
            stage.open()
    assert not port.is_open


def test_zaber_homes_and_waits_for_idle():
    stage = zaber()
    with expected_exchanges(stage, [*zconnect(), *zhome()]) as port:
        stage.open()
        stage.home()
    assert port.clock.sleeps == [0.05]  # one poll while BUSY


def test_zaber_still_unreferenced_after_homing_is_an_error():
    stage = zaber()
    script = [*zconnect(), *zhome()[:-1], (z(12, "get pos"), zr(12, "0", flag="WR"))]
    with expected_exchanges(stage, script):
        stage.open()
        with raises_stage_error(ZPORT, "still no reference position after homing (WR)", "check the home sensor"):
            stage.home()


@pytest.mark.parametrize("offset_m,direction", [(0.3, 1), (3.3, -1)])
def test_zaber_moves_land_where_commanded(offset_m, direction):
    stage = zaber(offset_m=offset_m, direction=direction, settle_s=0.0, travel_mm=3000.0)
    script = [*zconnect(), *zhome()]
    n = 13
    for position_m in (0.5, 1.75, 3.0, 0.8):
        steps = steps_of(position_m, offset_m, direction)
        script += zmove(n, steps, steps // 2)
        n += 4
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        assert stage.limits_m == pytest.approx((0.3, 3.3))
        for position_m in (0.5, 1.75, 3.0, 0.8):
            assert stage.move_to(position_m) == pytest.approx(position_m, abs=1e-6)


def test_zaber_move_polls_until_idle_then_settles():
    stage = zaber()
    steps = steps_of(1.0)
    assert steps == 3674541
    with expected_exchanges(stage, [*zconnect(), *zhome(), *zmove(13, steps, 100000, 2000000)]) as port:
        stage.open()
        stage.home()
        port.clock.sleeps.clear()
        assert stage.move_to(1.0) == pytest.approx(1.0, abs=1e-6)
    assert port.clock.sleeps == [0.05, 0.05, 0.2]


def test_zaber_refuses_moves_before_homing_and_beyond_the_travel_without_sending_anything():
    stage = zaber()
    with expected_exchanges(stage, [*zconnect(limit_max=steps_of(3.3)), *zhome()]):
        stage.open()
        with raises_stage_error(ZPORT, "not homed"):
            stage.move_to(1.0)
        stage.home()
        with raises_stage_error(ZPORT, "outside the travel limits 0.300-3.300 m"):
            stage.move_to(3.35)
        with raises_stage_error(ZPORT, "outside the travel limits"):
            stage.move_to(0.1)


def test_zaber_the_very_end_of_the_travel_is_allowed():
    stage = zaber(settle_s=0.0)
    end = steps_of(3.3)
    with expected_exchanges(stage, [*zconnect(limit_max=end), *zhome(), *zmove(13, end, end // 2)]):
        stage.open()
        stage.home()
        assert stage.move_to(stage.limits_m[1]) == pytest.approx(3.3, abs=1e-6)


def test_zaber_position_outside_the_tolerance_fails_the_move_and_inside_it_is_measured():
    stage = zaber(settle_s=0.0)
    steps, back = steps_of(2.0), steps_of(1.5)
    script = [*zconnect(), *zhome(), (z(13, f"move abs {steps}"), zr(13, "0", "BUSY")),
              (z(14, "get pos"), zr(14, str(steps))), (z(15, "get pos"), zr(15, str(steps + 15748))),  # 3 mm
              (z(16, f"move abs {back}"), zr(16, "0", "BUSY")),
              (z(17, "get pos"), zr(17, str(back))), (z(18, "get pos"), zr(18, str(back + 2100)))]  # 0.4 mm
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(ZPORT, "commanded 2.0000 m but measured 2.0030 m", "tolerance 1.0 mm"):
            stage.move_to(2.0)
        assert stage.move_to(1.5) == pytest.approx(1.5004, abs=1e-6)


def test_zaber_reply_checksums_are_checked_when_the_device_sends_them():
    stage = zaber()
    good = zconnect()[:-1] + [(z(6, "get limit.max"), zr(6, "15748031", flag="WR", checksum=True))]
    with expected_exchanges(stage, good):
        stage.open()
    stage = zaber()
    bad = zr(6, "15748031", flag="WR", checksum=True).replace(b"15748031", b"15748032")
    with expected_exchanges(stage, [*zconnect()[:-1], (z(6, "get limit.max"), bad)]):
        with raises_stage_error(ZPORT, "garbled reply '@01 1 06 OK IDLE WR 15748032:", "baud=115200"):
            stage.open()


def test_zaber_a_late_reply_to_an_earlier_command_is_passed_over_and_info_and_alerts_too():
    stage = zaber()
    script = [*zconnect(), *zhome(),
              (z(13, "get pos"), [zr(12, "5"), b"#01 1 13 some info\r\n", b"!01 1 IDLE --\r\n", zr(13, "0")])]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        assert stage.position_m() == pytest.approx(0.3)


def test_zaber_message_ids_run_from_01_to_99_then_00():
    stage = zaber()
    script = [*zconnect(), *[(z(i % 100, "get pos"), zr(i % 100, "0")) for i in range(7, 102)]]
    with expected_exchanges(stage, script):
        stage.open()
        for _ in range(7, 102):
            stage.position_m()


def test_zaber_an_unanswered_command_is_an_error_and_the_next_works():
    stage = zaber()
    script = [*zconnect(), *zhome(), (z(13, "get pos"), None), (z(14, "get pos"), zr(14, "0"))]
    with expected_exchanges(stage, script) as port:
        stage.open()
        stage.home()
        before = port.clock.now
        with raises_stage_error(ZPORT, "no reply to '/1 1 get pos' within 2.0 s", "check the USB cable",
                                "is device 1"):
            stage.position_m()
        assert port.clock.now - before == pytest.approx(2.0)
        assert stage.position_m() == pytest.approx(0.3)


def test_zaber_an_unanswered_move_is_an_error_and_nothing_more_is_sent():
    stage = zaber()
    steps = steps_of(2.0)
    with expected_exchanges(stage, [*zconnect(), *zhome(), (z(13, f"move abs {steps}"), None)]):
        stage.open()
        stage.home()
        with raises_stage_error(ZPORT, f"no reply to '/1 1 move abs {steps}' within 2.0 s"):
            stage.move_to(2.0)


def test_zaber_noise_is_reported_as_a_garbled_reply():
    stage = zaber()
    script = [*zconnect(), *zhome(), (z(13, "get pos"), b"@01 1 13 OK ID\xceE -- 0\r\n")]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(ZPORT, "garbled reply", "to '/1 1 get pos'", "baud=115200"):
            stage.position_m()


def test_zaber_unplugged_port_is_named():
    stage = zaber()
    with expected_exchanges(stage, [*zconnect(), *zhome(), (z(13, "get pos"), UNPLUG)]):
        stage.open()
        stage.home()
        with raises_stage_error(ZPORT, "port disconnected while waiting for the reply to '/1 1 get pos'"):
            stage.position_m()


def test_zaber_rejects_absolute_moves_after_losing_its_reference():
    # a power cycle: 'move abs' is rejected with the WR flag (BADDATA); the driver says to home, and homes
    stage = zaber(settle_s=0.0)
    steps = steps_of(1.5)
    script = [*zconnect(), *zhome(),
              (z(13, f"move abs {steps}"), zr(13, "BADDATA", flag="WR", reply="RJ")),
              *zhome(14), *zmove(20, steps, 1000)]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(ZPORT, f"'/1 1 move abs {steps}' rejected: no reference position (WR)",
                                "home the stage"):
            stage.move_to(1.5)
        with raises_stage_error(ZPORT, "not homed"):
            stage.move_to(1.5)
        stage.home()
        assert stage.move_to(1.5) == pytest.approx(1.5, abs=1e-6)


def test_zaber_other_rejections_are_named_with_their_reason():
    stage = zaber()
    steps = steps_of(1.0)
    script = [*zconnect(), *zhome(), (z(13, f"move abs {steps}"), zr(13, "BADDATA", reply="RJ"))]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(ZPORT, "rejected: BADDATA (value out of range or invalid", "check microstep_um"):
            stage.move_to(1.0)


def test_zaber_stall_fault_during_a_move_is_read_from_the_warnings_and_homing_clears_it():
    stage = zaber(settle_s=0.0)
    steps = steps_of(2.5)
    script = [*zconnect(), *zhome(),
              (z(13, f"move abs {steps}"), zr(13, "0", "BUSY")),
              (z(14, "get pos"), zr(14, "1000000", "IDLE", "FS")), (z(15, "warnings"), zr(15, "01 FS", flag="FS")),
              (z(16, "stop"), zr(16, "1000000", flag="FS")), (z(17, "get pos"), zr(17, "1000000", flag="FS")),
              (z(18, "warnings clear"), zr(18, "01 FS", flag="FS")), (z(19, "home"), zr(19, "1000000", "BUSY")),
              (z(20, "get pos"), zr(20, "0")), *zmove(21, steps, 5000)]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(ZPORT, f"stage fault FS (stalled and stopped) during 'move abs {steps}'",
                                "homing clears the fault"):
            stage.move_to(2.5)
        stage.home()  # stop (no flags checked), clear, home
        assert stage.move_to(2.5) == pytest.approx(2.5, abs=1e-6)


def test_zaber_a_flag_hidden_behind_a_more_urgent_one_is_read_from_the_warnings():
    # WT (temperature) outranks NI (interrupted): replies show WT; the driver reads `warnings` and stops on NI
    stage = zaber()
    steps = steps_of(2.0)
    script = [*zconnect(), *zhome(), (z(13, f"move abs {steps}"), zr(13, "0", "BUSY")),
              (z(14, "get pos"), zr(14, "500000", "BUSY", "WT")), (z(15, "warnings"), zr(15, "02 WT NI", flag="WT"))]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(ZPORT, f"movement interrupted (NI) during 'move abs {steps}'", "Zaber Launcher"):
            stage.move_to(2.0)


def test_zaber_home_stops_a_move_left_running():
    # the reply to 'move abs' was lost to noise and the stage moves on; homing (what a resume does) stops it,
    # waits until it is IDLE, clears the warnings (NI from the stop), and homes
    stage = zaber()
    steps = steps_of(3.0)
    script = [*zconnect(), *zhome(),
              (z(13, f"move abs {steps}"), b"@01 1 13 OK BU\x00Y -- 0\r\n"),
              (z(14, "stop"), zr(14, "4000000", "BUSY")), (z(15, "get pos"), zr(15, "4100000", "BUSY", "NI")),
              (z(16, "get pos"), zr(16, "4120000", "IDLE", "NI")),
              (z(17, "warnings clear"), zr(17, "01 NI", flag="NI")), (z(18, "home"), zr(18, "4120000", "BUSY")),
              (z(19, "get pos"), zr(19, "0"))]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(ZPORT, "garbled reply"):
            stage.move_to(3.0)
        stage.home()


def test_zaber_a_move_that_never_ends_is_an_error():
    stage = zaber(move_timeout_s=1.0, poll_s=0.3)
    steps = steps_of(1.0)
    busy = [(z(14 + i, "get pos"), zr(14 + i, str(1000 * i), "BUSY")) for i in range(5)]
    script = [*zconnect(), *zhome(), (z(13, f"move abs {steps}"), zr(13, "0", "BUSY")), *busy]
    with expected_exchanges(stage, script):
        stage.open()
        stage.home()
        with raises_stage_error(ZPORT, "still moving 1.0 s after 'move abs 3674541'", "check the rail"):
            stage.move_to(1.0)


# === the scripted port itself ==========================================================================


def test_an_unexpected_write_fails_at_once_naming_both():
    stage = grbl()
    with pytest.raises(AssertionError, match=r"exchange 1 of 1: the driver wrote b'\?', but b'\$\$\\n' was expected"):
        with expected_exchanges(stage, [(b"$$\n", OK)]):
            stage.open()


def test_a_missing_exchange_fails_when_the_block_ends():
    stage = grbl()
    with pytest.raises(AssertionError, match=r"had 6 of the 7 exchanges expected; the next would have been \[b'\?'\]"):
        with expected_exchanges(stage, [*connect(), (b"?", report("Idle", 0.0))]):
            stage.open()
