"""Our GRBL simulator against transcripts recorded from the real GRBL 1.1h firmware (tests/grbl_transcripts.py).

Every command the driver sends, the real-time bytes (`?`, `!`, `~`, Ctrl-X, jog cancel), errors, alarms, `$SLP`,
resets in each state, homing, startup lines, inches and the report mask were sent to the firmware (grbl-sim, the
firmware's own source compiled for the host) and its replies kept in tests/golden/grbl/. The simulator must give
the same text, timing and mid-move positions aside. A second test runs the firmware again, so a transcript that
no longer says what the firmware says (a change of the scripts or of the build) fails too.
"""

from __future__ import annotations

import pytest

from grbl_firmware import require_firmware
from grbl_transcripts import GOLDEN, SCRIPTS, firmware_transcript, simulator_transcript

pytestmark = pytest.mark.slow


def golden(name: str) -> str:
    path = GOLDEN / f"{name}.txt"
    assert path.is_file(), f"no transcript {path}: record it with `python -m tests.grbl_transcripts {name}`"
    return path.read_text()


@pytest.mark.parametrize("name", list(SCRIPTS))
def test_the_simulator_answers_as_the_firmware_did(name):
    assert simulator_transcript(name) == golden(name)


@pytest.mark.parametrize("name", list(SCRIPTS))
def test_the_firmware_still_answers_as_recorded(name, tmp_path):
    require_firmware()
    assert firmware_transcript(name, tmp_path) == golden(name)


def test_every_script_exercises_the_commands_the_driver_sends():
    sent = b"".join(step.data for steps in SCRIPTS.values() for step in steps if hasattr(step, "data"))
    for command in (b"\r\n\r\n", b"\x18", b"$$\n", b"$I\n", b"$X\n", b"$H\n", b"G90 G21\n", b"G21 G53 G1 X", b"?",
                    b"!", b"~", b"\x85", b"$SLP\n", b"$10=0\n", b"$13=1\n", b"$N0=G20\n"):
        assert command in sent, command
