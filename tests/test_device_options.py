"""Device strings refuse what they do not know: one option parser (drivers.options) for every kind.

Each kind declares its options once (an OptionTable); `spec.take(table)` refuses an unknown key with the
nearest known one, and a value of the wrong type or out of range, in one line naming the fix. The defaults
must be the values the drivers had before the tables existed (written out here, not read from the tables).
"""

from __future__ import annotations

import inspect
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

from drivers.errors import CameraError, DeviceError, StageError
from drivers.options import Option, OptionTable, POSITIVE
from drivers.registry import DeviceSpec, build, kind_names, option_table
from drivers.serial import GrblStage, ZaberStage
from drivers.serial.line import SerialLine
from drivers.stage import Stage
from fakes.camera import FakeCamera
from rig.cli import main

ROOT = Path(__file__).resolve().parents[1]
RIG = Path(sys.executable).parent / "rig"

#: one string per kind, as little as the kind needs (a port for the serial stages)
BARE = {
    ("stage", "grbl"): "grbl:///dev/null",
    ("stage", "zaber"): "zaber:///dev/null",
    ("stage", "fake"): "fake:",
    ("stage", "none"): "none:",
    ("camera", "fake"): "fake:",
    ("camera", "realsense"): "realsense:",
    ("camera", "oak"): "oak:",
}
#: a typo of a real key of each kind, and the key it should suggest
TYPO = {
    ("stage", "grbl"): ("ofset_m", "offset_m"),
    ("stage", "zaber"): ("ofset_m", "offset_m"),
    ("stage", "fake"): ("mn_m", "min_m"),
    ("camera", "fake"): ("widht", "width"),
    ("camera", "realsense"): ("widht", "width"),
    ("camera", "oak"): ("confidance", "confidence"),
}


def with_option(what: str, kind: str, option: str) -> str:
    base = BARE[(what, kind)]
    if base.startswith(f"{kind}://"):
        return f"{base}?{option}"
    return f"{base}{option}"


def refusal(what: str, text: str, error: type[DeviceError] = DeviceError) -> str:
    with pytest.raises(error) as e:
        build(what, text)
    message = str(e.value)
    assert "\n" not in message, message
    return message


def test_every_built_in_kind_has_a_table():
    assert {(w, k) for w in ("camera", "stage") for k in kind_names(w)} >= set(BARE)
    for what, kind in BARE:
        table = option_table(what, kind)
        assert isinstance(table, OptionTable) and (table.kind, table.what) == (kind, what)
        assert table.error is (CameraError if what == "camera" else StageError)


# --- unknown keys ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("what,kind", sorted(TYPO))
def test_an_unknown_key_is_refused_with_a_suggestion_and_the_list(what, kind):
    typo, meant = TYPO[(what, kind)]
    text = with_option(what, kind, f"{typo}=1")
    table = option_table(what, kind)
    message = refusal(what, text, table.error)
    assert message.startswith(f"unknown option '{typo}' in '{text}'; did you mean {meant}? It takes: "), message
    assert message.endswith(", ".join(sorted(o.name for o in table.options)))


def test_the_issue_example_is_refused_word_for_word():
    message = refusal("stage", "grbl:///dev/ttyUSB0?ofset_m=0.3", StageError)
    assert message.startswith("unknown option 'ofset_m' in 'grbl:///dev/ttyUSB0?ofset_m=0.3'; did you mean offset_m? "
                              "It takes: baud, direction, feed, ")


def test_several_unknown_keys_and_one_with_no_near_miss():
    message = refusal("stage", "fake:mn_m=0.5,mx_m=2", StageError)
    assert "unknown options 'mn_m', 'mx_m'" in message and "did you mean min_m (for mn_m), max_m (for mx_m)?" in message
    message = refusal("stage", "zaber:///dev/null?colour=red", StageError)
    assert "unknown option 'colour'" in message and "did you mean" not in message and "; it takes: axis, baud," in message


def test_none_takes_nothing_and_fake_kinds_take_no_path():
    assert "'none:offset_m=0.3'; it takes no options" in refusal("stage", "none:offset_m=0.3", StageError)
    assert "takes no path" in refusal("stage", "fake:///dev/ttyUSB0", StageError)
    assert "takes no path" in refusal("camera", "fake:///x", CameraError)


def test_a_port_written_without_its_slashes_is_named_as_a_port():
    """issue 51: --stage 'grbl:/dev/pts/0' was "not KEY=VALUE; write e.g. 'fake:width=424'"."""
    assert ("'/dev/pts/0' looks like a port; write it after '//', as 'grbl:///dev/pts/0'"
            in refusal("stage", "grbl:/dev/pts/0"))
    assert "'COM3' looks like a port; write it after '//', as 'zaber://COM3'" in refusal("stage", "zaber:COM3")
    message = refusal("camera", "fake:wide")
    assert "option 'wide' is not KEY=VALUE; write e.g. 'fake:KEY=VALUE'" in message and "port" not in message


def test_a_key_without_a_value_is_not_dropped():
    # parse_qsl used to drop these silently: the run went on with the default offset
    assert "option 'offset_m' is not KEY=VALUE" in refusal("stage", "grbl:///dev/null?offset_m")
    assert "offset_m has no value; give e.g. offset_m=0.3 (m, the default)" in refusal("stage", "grbl:///dev/null?offset_m=")


# --- values ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("text,phrase", [
    ("zaber:///dev/null?travel_mm=-500", "travel_mm must be positive, not -500; give e.g. travel_mm=1000 (mm), "
                                         "or leave it out (read from the device)"),
    ("grbl:///dev/null?travel_mm=0", "travel_mm must be positive, not 0"),
    ("grbl:///dev/null?direction=2", "direction must be 1 or -1, not 2; give e.g. direction=1 (the default)"),
    ("zaber:///dev/null?direction=0", "direction must be 1 or -1, not 0"),
    ("grbl:///dev/null?feed=0", "feed must be positive, not 0; give e.g. feed=3000 (mm/min, the default)"),
    ("grbl:///dev/null?offset_m=-1", "offset_m must be at least 0, not -1; give e.g. offset_m=0.3 (m, the default)"),
    ("zaber:///dev/null?offset_m=-0.1", "offset_m must be at least 0, not -0.1"),
    ("grbl:///dev/null?homing=3", "homing='3' is not 1 or 0; write homing=1 or homing=0"),
    ("grbl:///dev/null?baud=fast", "baud='fast' is not a whole number; give e.g. baud=115200 (the default)"),
    ("grbl:///dev/null?baud=-9600", "baud must be positive, not -9600"),
    ("zaber:///dev/null?baud=115200.5", "baud='115200.5' is not a whole number"),
    ("grbl:///dev/null?settle=-0.1", "settle must be at least 0, not -0.1"),
    ("grbl:///dev/null?timeout_s=0", "timeout_s must be positive, not 0"),
    ("zaber:///dev/null?home_timeout_s=-1", "home_timeout_s must be positive, not -1"),
    ("zaber:///dev/null?move_timeout_s=0", "move_timeout_s must be positive, not 0"),
    ("grbl:///dev/null?poll_s=0", "poll_s must be positive, not 0"),
    ("grbl:///dev/null?stall_s=0", "stall_s must be positive, not 0"),
    ("grbl:///dev/null?tolerance_mm=0", "tolerance_mm must be positive, not 0"),
    ("zaber:///dev/null?microstep_um=0", "microstep_um must be positive, not 0"),
    ("zaber:///dev/null?deviceid=-3", "deviceid must be positive, not -3"),
    ("zaber:///dev/null?device=0", "device must be positive, not 0"),
    ("grbl:///dev/null?offset_m=nan", "offset_m=nan is not a finite number"),
    ("grbl:///dev/null?rail_min_mm=inf&travel_mm=100", "rail_min_mm=inf is not a finite number"),
    ("fake:speed=0", "speed must be positive, not 0"),
    ("fake:min_m=-1", "min_m must be at least 0, not -1"),
    ("fake:min_m=2,max_m=1", "travel min_m=2 to max_m=1 m is empty"),
])
def test_stage_values_out_of_range_are_refused(text, phrase):
    message = refusal("stage", text, StageError)
    assert message.startswith(f"device '{text}': ") or "travel min_m" in message, message
    assert phrase in message, message


@pytest.mark.parametrize("text,phrase", [
    ("fake:width=100000", "width must be 4 to 4096, not 100000"),
    ("fake:light=dusk", "light must be 'day', 'night' or 'auto', not 'dusk'"),
    ("fake:drop=1", "drop must be 0 to below 1, not 1"),
    ("fake:seed=-1", "seed must be at least 0, not -1"),
    ("fake:depth_unit_mm=0", "depth_unit_mm must be above 0 and below 10000, not 0"),
    ("realsense:fps=0", "fps must be positive, not 0"),
    ("realsense:ir=maybe", "ir='maybe' is not 1 or 0"),
    ("realsense:laser_power=-5", "laser_power must be at least 0, not -5"),
    ("realsense:timeout=0", "timeout must be positive, not 0"),
    ("oak:projector=2", "projector must be 0 to 1, not 2"),
    ("oak:confidence=300", "confidence must be 0 to 255, not 300"),
    ("oak:subpixel=2", "subpixel='2' is not 1 or 0"),
    ("oak:fps=-30", "fps must be positive, not -30"),
])
def test_camera_values_out_of_range_are_refused(text, phrase):
    message = refusal("camera", text, CameraError)
    assert message.startswith(f"device '{text}': ") and phrase in message, message


# --- defaults: the values the drivers had before the tables ---------------------------------------------------


def test_grbl_defaults_are_unchanged():
    s = build("stage", "grbl:///dev/ttyUSB0")
    assert isinstance(s, GrblStage) and s.link.path == "/dev/ttyUSB0"
    assert (s.link.baud, s.offset_m, s.direction, s.feed_mm_min, s.settle_s, s.tolerance_m) == (115200, 0.3, 1, 3000.0, 0.2, 0.001)
    assert (s.travel_mm, s.rail_min_mm, s.rail, s.homing) == (None, None, None, True)
    assert (s.timeout_s, s.home_timeout_s, s.poll_s, s.stall_s) == (2.0, 120.0, 0.05, 3.0)
    assert (s.link.timeout_s) == 2.0


def test_zaber_defaults_are_unchanged():
    s = build("stage", "zaber:///dev/ttyUSB0")
    assert isinstance(s, ZaberStage) and s.link.path == "/dev/ttyUSB0"
    assert (s.link.baud, s.device, s.axis, s.datasheet_microstep_um, s.expected_device_id) == (115200, 1, 1, 0.1905, None)
    assert (s.offset_m, s.direction, s.settle_s, s.tolerance_m, s.travel_mm, s.rail) == (0.3, 1, 0.2, 0.001, None, None)
    assert (s.timeout_s, s.home_timeout_s, s.move_timeout_s, s.poll_s) == (2.0, 120.0, 60.0, 0.05)


def test_fake_and_none_stage_defaults_are_unchanged():
    s = build("stage", "fake:")
    assert (s.limits_m, s.speed_m_s, s.settle_s) == ((0.3, 3.5), 0.1, 0.5)
    n = build("stage", "none:", {"distance_m": 1.5})
    assert n.position_m() == 1.5


def test_camera_defaults_are_unchanged():
    f = build("camera", "fake:")
    assert (f.intrinsics.width, f.intrinsics.height, f.depth_scale_m, f.baseline_m, f.seed, f.fps) == (848, 480, 0.001, 0.05, 0, 30.0)
    assert (f.effects, f.fail_at_frame, f.light, f.drop, f.duplicate) == ([], None, "auto", 0.0, 0.0)
    assert build("camera", "fake:width=424").intrinsics.height == 240  # the height follows the width
    r = build("camera", "realsense:")
    assert (r.serial, r.file, r.record, r.width, r.height, r.fps) == (None, None, None, 848, 480, 30)
    assert (r.stream_ir, r.laser_power, r.preset, r.timeout_s) == (True, None, None, 5.0)
    o = build("camera", "oak:")
    assert (o.device_id, o.width, o.height, o.fps, o.preset, o.confidence) == (None, 640, 400, 30.0, "DEFAULT", 200)
    assert (o.subpixel, o.lr_check, o.projector, o.search_s, o.timeout_s) == (True, True, 0.5, 3.0, 5.0)


@pytest.mark.parametrize("cls,table,renamed", [
    (GrblStage, "grbl", {"feed": "feed_mm_min", "settle": "settle_s"}),
    (ZaberStage, "zaber", {"deviceid": "device_id", "settle": "settle_s"}),
])
def test_the_serial_tables_match_the_constructors_defaults(cls, table, renamed):
    """The constructor's keyword defaults (what Python callers get) and the device string's must not drift."""
    parameters = inspect.signature(cls.__init__).parameters
    for option in option_table("stage", table).options:
        assert parameters[renamed.get(option.name, option.name)].default == option.default, option.name


# --- every documented key is accepted --------------------------------------------------------------------------


def documented_keys(doc: str, heading: str) -> set[str]:
    """The option names in the first table after `heading` in a markdown file (`| \\`a\\`, \\`b\\` | ... |`)."""
    text = (ROOT / doc).read_text()
    start = text.index(heading)
    table = re.search(r"\| option \|.*?\n\n", text[start:], re.S).group(0)
    rows = [row for row in table.splitlines()[2:] if row.startswith("|")]
    return {k for row in rows for k in re.findall(r"`([a-z_]+)`", row.split("|")[1])}


@pytest.mark.parametrize("kind,heading", [("grbl", "### GRBL options"), ("zaber", "First run on a real Zaber")])
def test_docs_stages_lists_exactly_the_options_of_the_table(kind, heading):
    assert documented_keys("docs/stages.md", heading) == set(option_table("stage", kind).names())


def test_every_grbl_key_is_taken():
    s = build("stage", "grbl:///dev/ttyUSB0?baud=57600&offset_m=0.25&direction=-1&feed=1200&settle=0.5&tolerance_mm=2"
                       "&travel_mm=2500&rail_min_mm=-10&homing=0&timeout_s=1.5&home_timeout_s=60&poll_s=0.02&stall_s=4")
    assert (s.link.baud, s.offset_m, s.direction, s.feed_mm_min, s.settle_s, s.tolerance_m) == (57600, 0.25, -1, 1200.0, 0.5, 0.002)
    assert (s.travel_mm, s.rail_min_mm, s.homing) == (2500.0, -10.0, False)
    assert (s.timeout_s, s.home_timeout_s, s.poll_s, s.stall_s) == (1.5, 60.0, 0.02, 4.0)
    assert build("stage", "grbl:///dev/null?homing=off").homing is False
    assert build("stage", "grbl:///dev/null?settle=0").settle_s == 0.0


def test_every_zaber_key_is_taken():
    s = build("stage", "zaber:///dev/ttyUSB1?baud=9600&device=2&axis=2&microstep_um=0.047625&deviceid=50081&offset_m=0.5"
                       "&direction=-1&settle=0&tolerance_mm=0.5&travel_mm=500&timeout_s=1&home_timeout_s=30"
                       "&move_timeout_s=20&poll_s=0.1")
    assert (s.link.baud, s.device, s.axis, s.datasheet_microstep_um, s.expected_device_id) == (9600, 2, 2, 0.047625, 50081)
    assert (s.offset_m, s.direction, s.settle_s, s.tolerance_m, s.travel_mm) == (0.5, -1, 0.0, 0.0005, 500.0)
    assert (s.timeout_s, s.home_timeout_s, s.move_timeout_s, s.poll_s) == (1.0, 30.0, 20.0, 0.1)
    # the key=value form reads the same options (a path is still needed)
    with pytest.raises(StageError, match="names no serial port"):
        build("stage", "zaber:offset_m=0.5")


def test_every_camera_key_is_taken():
    f = build("camera", "fake:width=16,height=9,depth_unit_mm=0.1,baseline_mm=40,seed=3,fps=15,effects=noise_floor,"
                        "fail_at_frame=6,light=night,drop=0.1,duplicate=0.05")
    assert (f.intrinsics.width, f.intrinsics.height, f.depth_scale_m, f.baseline_m, f.seed, f.fps) == (16, 9, 1e-4, 0.04, 3, 15.0)
    assert ([e.name for e in f.effects], f.fail_at_frame, f.light, f.drop, f.duplicate) == (["noise_floor"], 6, "night", 0.1, 0.05)
    r = build("camera", "realsense:serial=123,record=rec.db3,width=640,height=360,fps=15,ir=0,laser_power=150,"
                        "preset=High Accuracy,timeout=2")
    assert (r.serial, str(r.record), r.width, r.height, r.fps) == ("123", "rec.db3", 640, 360, 15)
    assert (r.stream_ir, r.laser_power, r.preset, r.timeout_s) == (False, 150.0, "High Accuracy", 2.0)
    assert str(build("camera", "realsense:file=run.db3").file) == "run.db3"
    assert str(build("camera", "realsense:///data/run.db3").file) == "/data/run.db3"
    o = build("camera", "oak:id=14442C108144F1D000,width=1280,height=800,fps=15,preset=ACCURACY,confidence=180,"
                        "subpixel=0,lr_check=off,projector=0.8,search=1,timeout=2")
    assert (o.device_id, o.width, o.height, o.fps, o.preset, o.confidence) == ("14442C108144F1D000", 1280, 800, 15.0, "ACCURACY", 180)
    assert (o.subpixel, o.lr_check, o.projector, o.search_s, o.timeout_s) == (False, False, 0.8, 1.0, 2.0)


def test_fake_camera_from_options_still_takes_a_dict():
    from fakes.world import FakeWorld

    cam = FakeCamera.from_options(FakeWorld.perpendicular(1.0), {"width": "32"})
    assert (cam.intrinsics.width, cam.intrinsics.height) == (32, 18)
    with pytest.raises(CameraError, match="unknown option 'hieght' in 'fake:hieght=3'; did you mean height?"):
        FakeCamera.from_options(FakeWorld.perpendicular(1.0), {"hieght": "3"})


# --- the table itself ------------------------------------------------------------------------------------------


def test_a_table_prints_names_defaults_units_and_ranges(capsys):
    assert main(["devices", "--options", "grbl"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("grbl stage: grbl:///PATH?KEY=VALUE&... (PATH: serial port)")
    rows = {line.split()[0]: line for line in out[1:]}
    assert set(rows) == set(option_table("stage", "grbl").names())
    assert "0.3 m" in rows["offset_m"] and "at least 0" in rows["offset_m"] and "1 or -1" in rows["direction"]
    assert main(["devices", "--options", "fake:"]) == 0  # both the fake camera and the fake stage
    out = capsys.readouterr().out
    assert "fake camera: " in out and "fake stage: " in out
    assert main(["devices", "--options", "nosuch"]) == 2
    assert "no such device kind; known kinds: fake, grbl, none, oak, realsense, zaber" in capsys.readouterr().err


def test_option_parsing_is_the_same_for_both_forms_of_a_string():
    table = OptionTable("demo", "stage", (Option("a_m", float, 1.0, POSITIVE, "m", "a length"),), path="port", error=StageError)
    assert DeviceSpec.parse("demo:///dev/x?a_m=2").take(table) == {"a_m": 2.0}
    assert DeviceSpec.parse("demo:a_m=2").take(table) == {"a_m": 2.0}
    assert DeviceSpec.parse("demo:").take(table) == {"a_m": 1.0}
    assert math.isclose(DeviceSpec.parse("demo:///dev/x?a_m=%32.5").take(table)["a_m"], 2.5)  # percent-decoded


# --- the command line ------------------------------------------------------------------------------------------


def test_rig_run_refuses_a_stage_typo_before_opening_anything(tmp_path, capsys, monkeypatch):
    opened = []
    monkeypatch.setattr(SerialLine, "open", lambda self: opened.append(self.path))
    monkeypatch.setattr(FakeCamera, "open", lambda self: opened.append("camera"))
    out = tmp_path / "x.h5"
    code = main(["run", "--protocol", "perpendicular", "--camera", "fake:width=16", "--stage", "grbl:///dev/null?ofset_m=0.3",
                 "-o", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and err.startswith("rig: error: unknown option 'ofset_m'"), err
    assert "did you mean offset_m?" in err
    assert opened == [] and not out.exists()


@pytest.mark.slow
def test_the_installed_command_exits_2_on_a_stage_typo(tmp_path):
    out = tmp_path / "x.h5"
    r = subprocess.run([str(RIG), "run", "--protocol", "perpendicular", "--stage", "grbl:///dev/null?ofset_m=0.3", "-o", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "'ofset_m'" in lines[0] and "did you mean offset_m?" in lines[0], r.stderr
    assert not out.exists()


def test_rig_run_refuses_an_out_of_range_stage_value(tmp_path, capsys):
    code = main(["run", "--protocol", "perpendicular", "--stage", "zaber:///dev/null?travel_mm=-500", "-o", str(tmp_path / "x.h5")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "travel_mm must be positive, not -500" in err


@pytest.mark.parametrize("text", ["grbl:///dev/ttyUSB0?offset_m=0.3&offset_m=0.5", "fake:width=16,width=32"])
def test_a_key_given_twice_is_refused(text):
    with pytest.raises(DeviceError, match=r"gives (offset_m|width) twice \('(0.3|16)' and '(0.5|32)'\); keep one"):
        DeviceSpec.parse(text)
