"""A kind of device is described once, by its entry (drivers.registry.DeviceKind), and everything reads that.

The proof adds one: `orbbec`, a camera kind defined in this file (driver, probe, options, gain unit), is
installed the way any plugin is: a distribution on sys.path whose entry point `rig.cameras` names `ORBBEC`
(a dist-info folder written to tmp_path, as pip would write it; nothing in rig is changed or told). It then
appears in `rig devices` with what its probe found, prints its options, and runs the default plan. Also
here: the run path never loads the simulator; the default settings run on every installed camera kind (gain
in rig's unit); the papercuts of `rig devices` (an SDK's chatter on stdout) and of `rig run -o` (an
unwritable output named by its lock file).
"""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

from drivers.camera import (CameraCalibration, CameraInfo, CameraSettings, DepthCamera, Frame, FrameMetadata, GainScale,
                            Intrinsics)
from drivers.errors import CameraError
from drivers.options import POSITIVE, Option, OptionTable
from drivers.registry import ON_BUILT, DeviceKind, DeviceSpec, Probe, kind, kind_names
from protocols.recording import Recording
from rig.cli import devices_main, main

ROOT = Path(__file__).resolve().parents[1]


# -- the kind a lab would add: one driver, one entry ------------------------------------------------------

ORBBEC_OPTIONS = OptionTable("orbbec", "camera", (
    Option("width", int, 16, POSITIVE, "px", "image width"),
    Option("height", int, 10, POSITIVE, "px", "image height"),
    Option("serial", str, "OB-1", None, "", "which camera"),
), error=CameraError)
#: its own gain scale: "sensitivity" 50 at x1, up to 800
ORBBEC_GAIN = GainScale("sensitivity", 50.0, (50.0, 800.0))


class OrbbecCamera(DepthCamera):
    """A stand-in depth camera that sees the wall where the stage puts it, with noise growing as Z^2."""

    name = "orbbec"

    def __init__(self, width: int, height: int, serial: str):
        self.width, self.height, self.serial = width, height, serial
        self.stage: Any = None  # the stage built with it (its ON_BUILT hook), whose position it sees
        self.native_gain: float | None = None
        self._settings = CameraSettings()
        self._number = 0
        self._rng = np.random.default_rng(3)

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass

    def info(self) -> CameraInfo:
        return CameraInfo("Orbbec stand-in", self.serial, "1.0",
                          Intrinsics(self.width, self.height, 20.0, 20.0, (self.width - 1) / 2, (self.height - 1) / 2),
                          baseline_m=0.05, depth_scale_m=0.001, extra={"fps": 30.0})

    def configure(self, settings: CameraSettings) -> CameraSettings:
        lo, hi = ORBBEC.exposure_us
        if not lo <= settings.exposure_us <= hi:
            raise CameraError(f"{self.name}: exposure {settings.exposure_us:g} us is outside {lo:g}-{hi:g} us")
        self.native_gain = ORBBEC_GAIN.check(settings.gain, self.name)  # its own scale, from rig's unit
        self._settings = settings
        return self.read_settings()

    def read_settings(self) -> CameraSettings:
        s = self._settings
        gain = s.gain if self.native_gain is None else ORBBEC_GAIN.from_native(self.native_gain)
        return CameraSettings(s.projector_on, s.exposure_us, gain, s.auto_exposure)

    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        z = self.stage.position_m() if self.stage is not None else 1.0
        s = self.read_settings()
        for _ in range(n):
            depth = (z + self._rng.normal(0.0, 0.002 * z * z, (self.height, self.width))) / 0.001
            self._number += 1
            yield Frame(np.round(depth).astype(np.uint16), self._number, self._number * 33.3,
                        FrameMetadata(s.exposure_us, s.gain, s.projector_on),
                        ir=np.full((self.height, self.width), 40, np.uint8) if ir else None)


def open_orbbec(spec: DeviceSpec, context: dict[str, Any]) -> DepthCamera:
    o = spec.take(ORBBEC_OPTIONS)
    camera = OrbbecCamera(o["width"], o["height"], o["serial"])

    def see_the_stage(devices: Any) -> None:
        camera.stage = devices.stage
        devices.clock = lambda seconds: None  # a stand-in: waiting takes no time

    context.setdefault(ON_BUILT, []).append(see_the_stage)
    return camera


def list_orbbec() -> list[dict[str, str]]:
    return [{"kind": "orbbec", "model": "Femto Bolt", "serial": "CL8F1234", "firmware": "1.2.3", "usb": "3.2",
             "string": "orbbec:serial=CL8F1234"}]


ORBBEC = DeviceKind("orbbec", "camera", open_orbbec, ORBBEC_OPTIONS, Probe("orbbec", list_orbbec),
                    summary="Orbbec (a test's stand-in)", exposure_us=(100.0, 30000.0), gain=ORBBEC_GAIN)


@pytest.fixture
def orbbec_installed(tmp_path, monkeypatch):
    """Install the kind as a plugin is installed: a distribution whose entry point names ORBBEC."""
    site = tmp_path / "site"
    info = site / "rig_orbbec-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: rig-orbbec\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[rig.cameras]\norbbec = {__name__}:ORBBEC\n")
    monkeypatch.syspath_prepend(str(site))
    assert "orbbec" in kind_names("camera")
    return site


def _quiet_probes(monkeypatch, *names):
    """The probes `names` find nothing (no SDK search); the others run."""
    from drivers import listing

    real = listing.probes

    def probes():
        got = real()
        return listing.ProbeSet({n: ((lambda: []) if n in names else p) for n, p in got.probes.items()}, got.cameras)

    monkeypatch.setattr(listing, "probes", probes)


def test_a_camera_kind_defined_here_is_listed_with_its_probe_result(orbbec_installed, monkeypatch):
    _quiet_probes(monkeypatch, "realsense", "oak", "serial")
    out = io.StringIO()
    assert devices_main([], out=out) == 0
    lines = out.getvalue().splitlines()
    found = [line for line in lines if "Femto Bolt" in line]
    assert len(found) == 1 and found[0].split()[0] == "orbbec", lines
    assert "id CL8F1234" in found[0] and found[0].endswith("-> --camera orbbec:serial=CL8F1234")
    assert lines[lines.index("cameras:") + 1] == found[0] and "none found" not in lines[1]

    out = io.StringIO()
    assert devices_main(["--options", "orbbec"], out=out) == 0
    text = out.getvalue()
    assert text.startswith("orbbec camera: orbbec:KEY=VALUE,...") and "serial" in text
    assert "settings: exposure 100-30000 us; gain 16-256 (16 = x1 = sensitivity 50; sensitivity 50-800)" in text


def test_a_broken_plugin_is_a_note_and_hides_no_other_kind(orbbec_installed, monkeypatch):
    info = orbbec_installed / "rig_broken-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: rig-broken\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[rig.cameras]\nbroken = rig_no_such_module:BROKEN\n")
    _quiet_probes(monkeypatch, "realsense", "oak", "serial")
    out = io.StringIO()
    assert devices_main([], out=out) == 0
    text = out.getvalue()
    assert "Femto Bolt" in text
    assert "note: the camera kind 'broken' cannot be loaded from 'rig_no_such_module:BROKEN'" in text


def test_a_camera_kind_defined_here_runs_the_default_plan(orbbec_installed, tmp_path, capsys):
    out = tmp_path / "run.h5"
    assert main(["run", "--protocol", "perpendicular", "--camera", "orbbec:", "--stage", "fake:", "-o", str(out),
                 "-q"]) == 0, capsys.readouterr().err
    rec = Recording(out)
    stops = list(rec.stops())
    assert [s.label for s in stops] == [f"{z:.3f}m" for z in np.arange(0.5, 3.01, 0.25)]  # the default plan
    for s in stops:
        assert s.n_frames == 300 and s.settings_requested["gain"] == 16.0 and s.settings_read_back["gain"] == 16.0
        centre = np.nanmedian(s.stats.mean_m)
        assert centre == pytest.approx(s.commanded_position_m, abs=0.01)  # it saw the stage's wall
    assert rec.calibration == CameraCalibration(16, 10, 20.0, 20.0, 7.5, 4.5, 0.05, 0.001)
    assert isinstance(rec.calibration, Intrinsics) and rec.calibration.intrinsics == Intrinsics(16, 10, 20.0, 20.0, 7.5, 4.5)


def test_the_default_settings_run_on_every_installed_camera_kind():
    """Gain is in rig's unit (16 = x1) on every camera: each kind's range holds the default plan's settings."""
    default = CameraSettings()
    for name in kind_names("camera"):
        k = kind("camera", name)
        lo, hi = k.gain.range
        assert lo <= default.gain <= hi, (name, k.gain.text())
        assert k.exposure_us[0] <= default.exposure_us <= k.exposure_us[1], name
    assert kind("camera", "oak").gain.to_native(default.gain) == 100.0  # the OAK's ISO 100 is x1
    assert kind("camera", "realsense").gain.to_native(default.gain) == 16.0


def test_an_oak_takes_the_default_plan_as_iso_100():
    pytest.importorskip("depthai", reason="depthai is not installed")
    from drivers.oak import exposure_control, frame_metadata

    ctrl = exposure_control(CameraSettings())  # the default plan: gain 16, 8500 us; refused before as ISO 16
    assert ctrl.getSensitivity() == 100

    class Msg:
        def getExposureTime(self):
            return 8500.0

        def getSensitivity(self):
            return 100

    assert frame_metadata(Msg(), projector_on=True, auto_exposure=False).gain == 16.0


def test_the_run_path_never_loads_the_simulator():
    code = ("import sys\n"
            "import rig.cli.acquire, protocols.runner, protocols.experiment_file\n"
            "from rig.devices import open_devices\n"
            "open_devices('realsense:', 'none:')\n"
            "open_devices('oak:', 'grbl:///dev/null')\n"
            "loaded = sorted(m for m in sys.modules if m.split('.')[0] == 'fakes')\n"
            "assert not loaded, loaded\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr[-2000:]
    files = [p for d in ("drivers", "protocols", "rig/camera_check") for p in (ROOT / d).rglob("*.py")]
    files.append(ROOT / "rig" / "devices.py")
    names_fakes = re.compile(r"^\s*(from|import) fakes\b|[\"']fakes[.:]", re.M)
    named = [str(p.relative_to(ROOT)) for p in files if names_fakes.search(p.read_text())]
    assert not named  # not even as a "module:attr" string


def test_the_simulator_is_a_plugin_like_any_other():
    assert kind("camera", "fake").simulated and kind("stage", "fake").simulated
    from importlib.metadata import entry_points

    assert {ep.value for ep in entry_points(group="rig.cameras") if ep.name == "fake"} == {"fakes.kinds:FAKE_CAMERA"}


# -- papercuts ---------------------------------------------------------------------------------------------

def test_sdk_chatter_during_the_probes_goes_to_stderr(capfd):
    """What an SDK writes to file descriptor 1 while probing (depthai's logger does) goes to stderr."""
    from drivers import listing

    def chatty() -> list[dict[str, str]]:
        os.write(1, b"[depthai] [warning] USB protocol not available\n")
        return []

    results, notes = listing.probe_all(which=listing.ProbeSet({"chatty": chatty}, frozenset({"chatty"})))
    print("listing")
    captured = capfd.readouterr()
    assert results == {"chatty": []} and not notes
    assert captured.out == "listing\n" and "USB protocol not available" in captured.err


@pytest.mark.slow
def test_rig_devices_prints_only_its_listing_on_stdout():
    pytest.importorskip("depthai", reason="depthai is not installed (its logger is what chatters)")
    r = subprocess.run([str(Path(sys.executable).parent / "rig"), "devices"], cwd=ROOT, capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("cameras:\n") and "[depthai]" not in r.stdout and "[warning]" not in r.stdout, r.stdout


@pytest.mark.parametrize("where", ["/proc/x.h5", "/sys/x.h5"])
def test_an_unwritable_output_is_named_not_its_lock_file(where, capsys):
    if not Path("/proc/self").exists():
        pytest.skip("not Linux: no /proc or /sys, whose folders take no new files")
    code = main(["run", "--protocol", "perpendicular", "--stops", "1", "--frames", "2", "-o", where, "-q"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert f"cannot write {where}:" in err and ".lock" not in err and "choose an output in a folder you can write" in err
