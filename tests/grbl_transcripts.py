"""Golden transcripts: what the real GRBL 1.1h firmware answers, recorded from it, and our simulator held to it.

Each script is a list of steps sent to a controller over pyserial on its pty: bytes to send (a line, or a
real-time byte such as `?`, `!`, `~`, Ctrl-X), or "poll `?` until the state is ...". The replies of each step
are written one a line under it. The same script is run against the real firmware (`tests/grbl_firmware.py`:
GRBL 1.1h compiled for the host with grbl-sim) to record `tests/golden/grbl/<script>.txt`, and against
`fakes.grbl_sim.GrblSim`, which must give the same text.

What is left out of the comparison, and why:
- timing: a step's replies are collected until the line has been quiet for a moment, so how long the firmware
  took does not matter, only what it said and in which order;
- positions and feeds while the carriage moves (in reports whose state is Run, Jog, Home or Hold:1, and in
  the steps marked `timed`, whose position depends on when a byte arrived) are written as `#`;
- the WCO and Ov fields once an `until` step has polled: they come on counters of reports (report.c), and how
  many reports a poll took depends on timing, so from then until the next reset they are left out;
- the start-up burst of a fresh firmware (`error:7` and the settings it restored to a blank EEPROM): the
  harness reads it before a script starts, and the simulator has no EEPROM to lose.

Record again (after a change to the scripts, or to the firmware's build) with

    .venv/bin/python -m tests.grbl_transcripts            # every script
    .venv/bin/python -m tests.grbl_transcripts hold        # one
"""

from __future__ import annotations

import re
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import serial

GOLDEN = Path(__file__).resolve().parent / "golden" / "grbl"
#: the rail both controllers drive: stock $130, the carriage in the middle at power-up
RAIL_MM = 200.0
START_MM = 100.0
#: a step's replies are complete once the line has been quiet this long
QUIET_S = 0.25
#: after a reset that raised an alarm, the firmware's banner follows half a second later
RESET_QUIET_S = 1.2
#: report.c waits 500 ms after printing an ALARM line, then goes on ([MSG:Reset to continue], the banner)
ALARM_PAUSE_S = 1.2


@dataclass(frozen=True)
class Send:
    """Send `data`; `timed`: its replies depend on timing (positions written as #); `until`: a reply that
    ends the step (for a command that is quiet a long time first, such as `$H`)."""

    data: bytes
    timed: bool = False
    until: str | None = None

    def header(self) -> str:
        return f"> {self.data.decode('latin-1')!r}"


@dataclass(frozen=True)
class Until:
    """Poll `?` until a report's state is `state`; only that report (and any other line meanwhile) is kept."""

    state: str
    timed: bool = False
    timeout_s: float = 30.0

    def header(self) -> str:
        return f"= until {self.state}"


@dataclass(frozen=True)
class Pause:
    """Wait, sending nothing (to let a move gather speed)."""

    seconds: float

    def header(self) -> str:
        return f"= pause {self.seconds:g} s"


def line(text: str, timed: bool = False) -> Send:
    return Send(text.encode("ascii") + b"\n", timed)


FAST = [line("$110=3000"), line("$120=100")]

SCRIPTS: dict[str, list[Send | Until | Pause]] = {
    # what the driver reads at open, the reports' WCO and Ov fields while idle, errors, check mode
    "queries": [
        Send(b"\r\n\r\n"), Send(b"\x18"), line("$$"), line("$I"), line("$G"), line("$#"), line("$N"), line("$"),
        *[Send(b"?") for _ in range(12)],
        line("$999=1"), line("$110=-1"), line("$20=1"), line("$X"), line("G1 X1"), line("$J=X1"),
        line("$C"), line("G53 G1 X5 F600"), Send(b"?"), line("$C"), Send(b"?"), line("$G"),
    ],
    # absolute and relative moves, a dwell, and what a reset keeps (the position) and clears (the parser state)
    "moves": [
        *FAST, line("G21 G53 G1 X20.000 F3000"), Until("Idle"), line("$G"), Send(b"?"),
        Send(b"\x18"), line("$G"), Send(b"?"),
        line("G90 G21"), line("G91 G1 X-5 F600"), Until("Idle"), line("G90"), line("G0 X10"), Until("Idle"),
        line("G4 P0.2"), Send(b"?"),
    ],
    # a dwell holds the parser (mc_dwell syncs the buffer, then sleeps in the line's execution): the line after it
    # is read, and answered, only once the dwell's ok is out
    "dwell": [Send(b"G4 P0.5\n$G\n", until="ok"), Send(b"?")],
    # a feed hold: Hold:1 while braking, Hold:0 once still; '~' ignored until then; a reset in each
    # ($120=5 mm/s^2: a hold from 15 mm/s brakes for 3 s, long enough to send '?', '~' and Ctrl-X meanwhile)
    "hold": [
        line("$110=1200"), line("$120=5"),
        line("G21 G53 G1 X90 F1200"), Until("Run"), Pause(3.0), Send(b"!"), Send(b"?", timed=True), Send(b"~"),
        Until("Hold:0", timed=True), Send(b"~"), Until("Run"), Until("Idle"),
        Send(b"!"), Send(b"?"), Send(b"~"), Send(b"?"),
        line("G21 G53 G1 X0 F1200"), Until("Run"), Pause(3.0), Send(b"!"), Until("Hold:0", timed=True),
        Send(b"\x18"), Send(b"?", timed=True), line("$G"),
        line("G21 G53 G1 X90 F1200"), Until("Run"), Pause(3.0), Send(b"!"), Send(b"?", timed=True),
        Send(b"\x18"), Send(b"?", timed=True), line("G1 X1 F100"), line("$X"), Send(b"?", timed=True),
    ],
    # a reset while moving: ALARM:3, the position lost; the alarm locks G-code until $X
    "reset_while_moving": [
        *FAST, line("G21 G53 G1 X50 F3000"), Until("Run"), Send(b"\x18"), Send(b"?", timed=True),
        line("G21 G53 G1 X10 F3000"), line("$X"), line("G21 G53 G1 X10 F3000"), Until("Idle"),
    ],
    # sleep: no lines read, '?' answered, the waking reset leaves Alarm; not allowed while moving
    "sleep": [
        *FAST, line("G21 G53 G1 X30 F600"), Until("Run"), line("$SLP"), Until("Idle"),
        line("$SLP"), Send(b"?"), line("G1 X1 F100"), Send(b"?"), Send(b"\x18"), Send(b"?"), line("$X"), Send(b"?"),
    ],
    # soft limits need homing; a target beyond them is ALARM:2 and a critical event: silence until a reset,
    # then the late 'ok' of the line that raised it; a jog beyond them is only error:15
    "soft_limits": [
        *FAST, line("$22=1"), line("$20=1"), Send(b"\x18"), Send(b"?"), line("$J=G53 X10 F600"),
        line("G21 G53 G1 X10 F600"), Send(b"?"), Send(b"\x18"), Send(b"?"), line("$X"), Send(b"?"),
        line("G21 G53 G1 X-20 F600"), Until("Idle"), line("$22=0"), line("$20=0"), line("$22=0"),
    ],
    # the homing cycle on the rail's +X switch: MPos -$27 after the pull-off
    "homing": [
        *FAST, line("$H"), line("$22=1"), line("$25=3000"), line("$24=300"), line("$27=2"), Send(b"$H\n", until="ok"), Send(b"?"),
        line("G21 G53 G1 X-52 F3000"), Until("Idle"), Send(b"?"),
    ],
    # a startup line ($N0), inches ($13=1), and a jog cancelled
    "startup_inches_jog": [
        *FAST, line("$N0=G20"), line("$N"), line("$13=1"), Send(b"\x18"), line("$G"), Send(b"?"),
        line("G53 G1 X1 F600"), Until("Idle"), Send(b"?"), line("$N0="), line("$13=0"), Send(b"\x18"), Send(b"?"),
        line("$J=G91 X30 F600"), Until("Jog"), Send(b"\x85"), Until("Idle", timed=True), line("$J=G91 G21 X-5 F600"),
        Until("Idle", timed=True),
    ],
    # the status report mask: WPos with $10=0 (and WCO), the buffer field with bit 1
    "report_mask": [
        line("$10=0"), *[Send(b"?") for _ in range(3)], line("$10=2"), Send(b"?"), line("$10=3"), Send(b"?"),
        line("$10=1"), Send(b"?"),
    ],
}

_MOVING = ("Run", "Jog", "Home", "Hold:1")
_POSITION = re.compile(r"\b(MPos|WPos|FS|F):[-\d.,]+")


_COUNTED = re.compile(r"\|(WCO|Ov):[-\d.,]+")


def uncounted(text: str) -> str:
    """A status report without the fields that come on counters of reports."""
    return _COUNTED.sub("", text) if text.startswith("<") else text


def masked(text: str, timed: bool) -> str:
    """A status report with its positions and feed written as # while moving, or in a timed step."""
    if not text.startswith("<"):
        return text
    state = text[1:].split("|", 1)[0]
    if timed or state in _MOVING:
        return _POSITION.sub(lambda m: f"{m.group(1)}:#", text)
    return text


class Terminal:
    """A pyserial session with a controller: send a step, collect the lines it answers."""

    def __init__(self, port: str):
        self.port = serial.Serial(port, 115200, timeout=0.05)
        self._buffer = b""

    def close(self) -> None:
        self.port.close()

    def _lines(self, quiet_s: float, limit_s: float, until: str | None = None) -> list[str]:
        """Whole lines until none has arrived for quiet_s (at most limit_s), or, with `until`, until that one
        has arrived and then none for quiet_s."""
        out: list[str] = []
        end = time.monotonic() + limit_s
        last = time.monotonic()
        while time.monotonic() < end:
            data = self.port.read(4096)
            if data:
                self._buffer += data
                last = time.monotonic()
                *whole, self._buffer = self._buffer.split(b"\n")
                out += [w.rstrip(b"\r").decode("latin-1") for w in whole]
            elif time.monotonic() - last > quiet_s and not self._buffer and (until is None or until in out):
                if any(t.startswith("ALARM:") for t in out) and time.monotonic() - last < ALARM_PAUSE_S:
                    continue  # report.c pauses after an alarm before its next line
                break
        return out

    def run(self, step: Send | Until | Pause) -> list[str]:
        if isinstance(step, Send):
            self.port.write(step.data)
            limit = 60.0 if step.until else 5.0
            quiet = RESET_QUIET_S if b"\x18" in step.data else QUIET_S
            return [masked(t, step.timed) for t in self._lines(quiet, limit, step.until) if t != ""]
        if isinstance(step, Pause):
            time.sleep(step.seconds)
            return self._lines(0.0, 0.0)
        kept: list[str] = []
        last_report = None
        end = time.monotonic() + step.timeout_s
        while time.monotonic() < end:
            self.port.write(b"?")
            for text in self._lines(0.05, 1.0):
                if text.startswith("<"):
                    last_report = text
                    if text[1:].split("|", 1)[0] == step.state:
                        return [*kept, masked(text, step.timed)]
                elif text:
                    kept.append(text)
            time.sleep(0.05)
        raise AssertionError(f"no report with state {step.state} within {step.timeout_s} s; last report: "
                             f"{last_report}; other lines: {kept}")


def transcript(port: str, steps: list[Send | Until | Pause]) -> str:
    """The text of a script run against the controller on `port`."""
    term = Terminal(port)
    try:
        term._lines(QUIET_S, 2.0)  # whatever the controller said before the script
        out = []
        counted = True  # report.c's counters are known: no poll of unknown length since the last reset
        for step in steps:
            out.append(step.header())
            replies = term.run(step)
            if isinstance(step, Until):
                counted = False
            elif isinstance(step, Send) and b"\x18" in step.data:
                counted = True
            out += [f"< {t if counted else uncounted(t)}" for t in replies]
        return "\n".join(out) + "\n"
    finally:
        term.close()


def simulator_transcript(name: str) -> str:
    from fakes.grbl_sim import GrblSim

    with GrblSim.stock(start_mm=START_MM) as sim:
        return transcript(sim.port, SCRIPTS[name])


def firmware_transcript(name: str, workdir: Path) -> str:
    try:
        from grbl_firmware import GrblFirmware  # as the tests import it (tests/ on sys.path)
    except ImportError:
        from tests.grbl_firmware import GrblFirmware  # python -m tests.grbl_transcripts

    with GrblFirmware(workdir, rail_mm=RAIL_MM, x0_mm=START_MM) as firmware:
        try:
            return transcript(firmware.port, SCRIPTS[name])
        except AssertionError as e:  # say what the firmware process and the harness's bridge were doing
            session = firmware._session
            proc = session.proc if session is not None else None
            stderr = workdir / "grbl_sim.stderr"
            tail = stderr.read_bytes()[-400:].decode("latin-1") if stderr.is_file() else ""
            raise AssertionError(f"{e}; firmware process: {'exited ' + str(proc.poll()) if proc and proc.poll() is not None else 'running'}"
                                 f"; bridge error: {session.bridge_error if session else None!r}; stderr tail: {tail!r}") from None


def main(argv: list[str]) -> int:
    names = argv or list(SCRIPTS)
    GOLDEN.mkdir(parents=True, exist_ok=True)
    for name in names:
        with tempfile.TemporaryDirectory(prefix=f"grbl-{name}-") as folder:
            text = firmware_transcript(name, Path(folder))
        (GOLDEN / f"{name}.txt").write_text(text)
        print(f"{name}: {text.count(chr(10))} lines -> {GOLDEN / f'{name}.txt'}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
