"""Fuzzing what users and devices hand us (hypothesis): experiment files and serial replies give a
correct result or a one-line error naming the problem; never another exception."""

from __future__ import annotations

import os
import threading
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.errors import StageError
from drivers.serial import GrblStage, ZaberStage
from protocols.experiment_file import ExperimentFileError, load_experiment, toml_value

FUZZ = settings(max_examples=int(os.environ.get("RIG_FUZZ_EXAMPLES", "60")), deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

scalars = st.one_of(st.booleans(), st.integers(-10**7, 10**7), st.floats(allow_nan=True, allow_infinity=True),
                    st.text(max_size=12))
values = st.one_of(scalars, st.lists(scalars, max_size=5))
KEYS = ["stops_m", "frames_per_stop", "frames", "tilt_deg", "distance_m", "projector_on", "exposure_us", "gain",
        "settle_s", "ir", "ambient_frames", "keep_raw", "typo"]


@FUZZ
@given(protocol=st.sampled_from(["perpendicular", "tilted", "other"]),
       params=st.dictionaries(st.sampled_from(KEYS), values, max_size=6))
@pytest.mark.slow
def test_experiment_files(tmp_path, protocol, params):
    body = "\n".join(f"{k} = {toml_value(v)}" for k, v in params.items())
    path = tmp_path / "e.toml"
    path.write_text(f'[experiment]\nprotocol = "{protocol}"\n[parameters]\n{body}\n')
    try:
        exp = load_experiment(path)
    except ExperimentFileError as e:
        assert "\n" not in str(e) and str(e)
        return
    # accepted: every value the plan holds is a sane one
    p = exp.plan.params
    frames = p.get("frames_per_stop", p.get("frames"))
    assert isinstance(frames, int) and frames >= 2
    assert all(0.05 <= z <= 100 for z in p.get("stops_m", [1.0]))
    assert 1 <= p["exposure_us"] <= 200_000 and p["gain"] >= 0 and p["settle_s"] >= 0


class _Quiet:
    """A pty peer that answers every line with one fuzzed reply."""

    def __init__(self, reply: bytes):
        import pty
        import tty

        self.master, self.slave = pty.openpty()
        tty.setraw(self.slave)
        self.reply = reply
        self.stop = threading.Event()
        threading.Thread(target=self.serve, daemon=True).start()

    @property
    def port(self) -> str:
        return os.ttyname(self.slave)

    def serve(self) -> None:
        while not self.stop.is_set():
            try:
                data = os.read(self.master, 1024)
                if data:
                    os.write(self.master, self.reply)
            except OSError:  # close() ran meanwhile: the descriptor is gone (EBADF) or the terminal hung up (EIO)
                return

    def close(self) -> None:
        self.stop.set()
        os.close(self.master)
        os.close(self.slave)


replies = st.one_of(
    st.binary(max_size=40),
    st.sampled_from([b"ok", b"error:", b"error:99", b"ALARM:", b"ALARM:x", b"<Idle|MPos:a,b,c>", b"<Idle>",
                     b"Grbl 1.1h ['$' for help]", b"@01 1 OK IDLE -- ", b"@01 1 OK IDLE WR 0", b"@1 1 RJ IDLE -- X",
                     b"@01 1 07 OK IDLE -- 0", b"#01 1 hi", b"!01 1 IDLE --"]).map(lambda b: b + b"\r\n"),
)


@pytest.mark.slow
@FUZZ
@given(kind=st.sampled_from(["grbl", "zaber"]), reply=replies)
def test_serial_replies(kind, reply):
    peer = _Quiet(reply)
    cls = GrblStage if kind == "grbl" else ZaberStage
    stage = cls(peer.port, timeout_s=0.05, settle_s=0.0, poll_s=0.005)
    t0 = time.monotonic()
    try:
        try:
            stage.open()
            stage.move_to(0.5)
        except StageError as e:
            assert "\n" not in str(e) and str(e).startswith(("grbl", "zaber")), str(e)
    finally:
        stage.close()
        peer.close()
    assert time.monotonic() - t0 < 30, "a reply made the driver wait past its deadlines"


@pytest.mark.parametrize("text", ["<Idle|MPos:1e999,0,0|FS:0,0>", "<Idle|MPos:nan,0,0|FS:0,0>",
                                  "<Idle|MPos:2000000.000,0.000,0.000|FS:0,0>"])
def test_a_status_with_an_impossible_position_is_garbled(text):
    # garbled: None, so the driver asks again (GRBL prints plain decimals; no rail is a kilometre long)
    stage = GrblStage("/dev/null", timeout_s=0.05)
    assert stage.link.parse_status(text) is None
    assert stage.link.parse_status("<Idle|MPos:12.500,0.000,0.000|FS:0,0>").x_mm == 12.5


MANIFEST_KEYS = ["fx", "fy", "cx", "cy", "baseline_m", "depth_unit_m", "projector_on", "exposure_us", "gain",
                 "stop_distance_from_name", "camera_model", "camera_serial", "typo"]
GOOD_MANIFEST = dict(fx=400.0, fy=400.0, cx=50.0, cy=30.0, baseline_m=0.05, depth_unit_m=0.001, projector_on=True)


@FUZZ
@given(changes=st.dictionaries(st.sampled_from(MANIFEST_KEYS), values, max_size=4),
       table=st.one_of(st.none(), st.dictionaries(st.text(max_size=6), values, max_size=3)))
@pytest.mark.slow
def test_import_manifests(tmp_path, changes, table):
    from drivers.errors import FolderImportError
    from drivers.folder import MANIFEST_NAME, load_settings

    manifest = {**GOOD_MANIFEST, **changes}
    lines = [f"{k} = {toml_value(v)}" for k, v in manifest.items()]
    if table is not None:
        lines += ["[stop_distance_m]"] + [f"{toml_value(k)} = {toml_value(v)}" for k, v in table.items()]
    folder = tmp_path / "src"
    folder.mkdir(exist_ok=True)
    (folder / MANIFEST_NAME).write_text("\n".join(lines) + "\n")
    try:
        settings_, _ = load_settings(folder)
    except FolderImportError as e:
        assert "\n" not in str(e) and str(e)
        return
    import math

    for key in ("fx", "fy", "baseline_m", "depth_unit_m"):
        v = getattr(settings_, key, None)
        assert v is None or (math.isfinite(v) and v > 0), (key, v)
    assert math.isfinite(settings_.cx) and math.isfinite(settings_.cy)
    assert all(math.isfinite(z) and z > 0 for z in settings_.stop_distance_m.values()), settings_.stop_distance_m
