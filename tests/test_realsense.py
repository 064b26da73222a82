"""The RealSense driver through the real SDK (pyrealsense2), without a camera.

A librealsense `rs.software_device` stands in for a D435: its frames come from the fake
camera's physics (fakes/realsense_software.py), and the driver drives it with the same
calls it makes on a real camera. What needs a real camera is listed in docs/hardware.md.
"""

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from drivers.camera import CameraSettings
from drivers.errors import CameraError, DeviceError
from protocols import Runner, RunError, perpendicular
from rig.analysis import fit_recording
from rig.devices import open_devices
from protocols.recording import Recording
from protocols.stats import PixelMomentAccumulator
from simrig import record_perpendicular

ROOT = Path(__file__).resolve().parents[1]
STOPS = [0.75, 1.25, 1.75, 2.25]
W, H = 64, 36
UNIT_MM = 0.05
PLAN = CameraSettings(projector_on=True, exposure_us=8500.0, gain=16.0, auto_exposure=False)


def _rs():
    return pytest.importorskip("pyrealsense2", reason="pyrealsense2 is not installed (pip install pyrealsense2)")


def _software(world, **kw):
    _rs()
    from fakes.realsense_software import SoftwareRealSense

    kw.setdefault("rate_hz", 250)
    return SoftwareRealSense(world, width=W, height=H, depth_unit_mm=UNIT_MM, **kw)


def _read_with_sdk(bag, read):
    """Play `bag` back with the SDK's own playback device (not rig's reader) and call `read(depth_frame)` for every
    depth frame, none dropped. Not `rs.pipeline`: it starts the playback in real time before `set_real_time(False)`
    can reach it, and on a loaded machine its queue (or its syncer, with a callback) drops frames (CI: frame 0
    missing); with a callback and `set_real_time(False)` it stalls after two frames in pyrealsense2 2.59. The depth
    sensor's own callback, not in real time, gets every frame: the playback waits for it."""
    import threading

    rs = _rs()
    dev = rs.context().load_device(str(bag))
    playback = dev.as_playback()
    playback.set_real_time(False)
    sensor = dev.first_depth_sensor()
    depth = [p for p in sensor.get_stream_profiles() if p.stream_type() == rs.stream.depth]
    errors, seen = [], threading.Event()

    def on_frame(f):
        try:
            read(f.as_depth_frame())
            seen.set()
        except BaseException as e:  # reported after the playback
            errors.append(e)

    sensor.open(depth)
    sensor.start(on_frame)
    try:
        deadline = time.monotonic() + 60
        while not (seen.is_set() and playback.current_status() == rs.playback_status.stopped):
            assert time.monotonic() < deadline, "the SDK's playback of the recording did not end in 60 s"
            time.sleep(0.02)
    finally:
        sensor.stop()
        sensor.close()
    assert not errors, errors


def _stats_from_log(log, frame_numbers, shape, scale):
    acc = PixelMomentAccumulator(shape, scale)
    for n in frame_numbers:
        acc.add(log[int(n)])
    return acc.result()


def _run_software(path, world_seed=0, frames=40, stops=STOPS, **sw_kw):
    from fakes.stage import FakeStage
    from fakes.world import FakeWorld

    world = FakeWorld.perpendicular(1.0)
    sw = _software(world, seed=world_seed, keep_log=True, **sw_kw)
    with sw:
        cam = sw.camera(width=W, height=H)
        plan = perpendicular(stops_m=stops, frames_per_stop=frames)
        Runner(cam, FakeStage(world), sleep=lambda s: None).run(plan, path)
    return sw


# -- a run through the SDK records and fits like the same run on the plain fake camera ------------

@pytest.mark.slow
def test_perpendicular_run_through_the_sdk_records_and_fits_like_the_fake_camera(tmp_path):
    sw = _run_software(tmp_path / "sdk.h5")
    plain, truth, _ = record_perpendicular(tmp_path / "plain.h5", width=W, frames=40, depth_unit_mm=UNIT_MM, stops_m=STOPS)

    with Recording(tmp_path / "sdk.h5") as rec, Recording(plain) as ref:
        c, r = rec.calibration, ref.calibration
        # calibration came through the SDK: intrinsics from the stream profile, baseline from the
        # extrinsics between the IR imagers, depth scale from the depth sensor's option
        assert (c.width, c.height) == (r.width, r.height) == (W, H)
        assert c.fx == pytest.approx(r.fx, rel=1e-6) and c.cx == pytest.approx(r.cx)
        assert c.baseline_m == pytest.approx(0.050, rel=1e-6)
        assert c.depth_scale_m == pytest.approx(UNIT_MM / 1000, rel=1e-6)
        assert rec.attrs["camera_model"].startswith("Intel RealSense D435")
        stops = list(rec.stops())
        assert [s.label for s in stops] == [s.label for s in ref.stops()]
        for s, z in zip(stops, STOPS):
            assert s.settings_read_back == PLAN.to_dict()
            assert set(s.series.exposure_us) == {8500.0} and set(s.series.gain) == {16.0}
            assert s.series.projector_on.all()
            assert np.all(np.diff(s.series.frame_number) > 0)
            assert np.nanmedian(s.stats.mean_m) == pytest.approx(z, rel=0.01)
            # identical frames, identical statistics: the recording holds exactly the frames the
            # software device was fed, with the frame numbers the SDK reported; the same accumulator on
            # the same frames with the depth unit the recording holds: the same numbers, to the last bit
            want = _stats_from_log(sw.log, s.series.frame_number, (H, W), c.depth_scale_m)
            np.testing.assert_array_equal(s.stats.count, want.count)
            np.testing.assert_array_equal(s.stats.mean_m, want.mean_m)
            np.testing.assert_array_equal(s.stats.m2_m2, want.m2_m2)

    a, b = fit_recording(tmp_path / "sdk.h5").fit, fit_recording(plain).fit
    for name in ("k", "lam"):
        diff = abs(getattr(a, name) - getattr(b, name))
        se = np.hypot(getattr(a, "se_" + name), getattr(b, "se_" + name))
        assert diff < 4 * se, f"{name}: {getattr(a, name)} vs {getattr(b, name)} (se {se})"
    assert a.lam == pytest.approx(truth[1], abs=5 * a.se_lam)


# -- recorded with the SDK's recorder, played back through realsense:file= ----------------------------

@pytest.mark.slow
def test_recording_made_by_the_sdk_plays_back_with_the_same_per_pixel_statistics(tmp_path):
    _rs()  # the SDK must be there (its reader below, `_read_with_sdk`, takes it itself)
    from fakes.stage import FakeStage
    from fakes.world import FakeWorld

    bag = tmp_path / "run.db3"
    world = FakeWorld.perpendicular(1.5)  # the recording starts before the run: every frame sees 1.5 m
    sw = _software(world, keep_log=True, initial=PLAN, seed=3)
    with sw:
        cam = sw.camera(width=W, height=H, record=bag)
        plan = perpendicular(stops_m=[1.5], frames_per_stop=30)
        Runner(cam, FakeStage(world), sleep=lambda s: None).run(plan, tmp_path / "live.h5")
    assert bag.exists() and bag.stat().st_size > 0

    devices = open_devices(f"realsense:file={bag}", "none:")
    assert devices.camera.name == "realsense file run.db3"
    Runner(devices.camera, devices.stage, sleep=lambda s: None).run(perpendicular(stops_m=[1.5], frames_per_stop=30),
                                                                     tmp_path / "played.h5")
    with Recording(tmp_path / "played.h5") as played, Recording(tmp_path / "live.h5") as live:
        # intrinsics, baseline and depth scale come from the file (the baseline from the recorded
        # stereo_baseline option: the recorder keeps extrinsics of recorded streams only)
        for k, v in vars(live.calibration).items():
            assert getattr(played.calibration, k) == pytest.approx(v, rel=1e-6), k
        assert played.attrs["camera_serial"] == live.attrs["camera_serial"] == "SW-D435-0001"
        (p,), (l,) = list(played.stops()), list(live.stops())
        want = _stats_from_log(sw.log, p.series.frame_number, (H, W), played.calibration.depth_scale_m)
        # the same accumulator on the same frames and depth unit: exactly
        np.testing.assert_array_equal(p.stats.count, want.count)
        np.testing.assert_array_equal(p.stats.mean_m, want.mean_m)
        np.testing.assert_array_equal(p.stats.m2_m2, want.m2_m2)
        assert np.all(np.diff(p.series.frame_number) == 1)  # every recorded frame, none dropped
        assert p.settings_read_back == PLAN.to_dict()
        # the same wall at the same distance: per-pixel means agree within their noise
        se = np.sqrt(l.stats.variance_m2 / l.stats.count + p.stats.variance_m2 / p.stats.count)
        z = (p.stats.mean_m - l.stats.mean_m) / se
        assert np.nanmean(np.abs(z) < 4) > 0.99
        assert np.nanmedian(p.stats.mean_m) == pytest.approx(1.5, rel=0.01)
    # the file is an ordinary SDK recording: the SDK's own playback reads it too
    depths = {}
    _read_with_sdk(bag, lambda d: depths.__setitem__(d.get_frame_number(), np.asanyarray(d.get_data()).copy()))
    assert len(depths) >= 30 and sorted(depths) == list(range(min(depths), max(depths) + 1))  # none dropped
    for n, depth in depths.items():
        np.testing.assert_array_equal(depth, sw.log[n])


def test_playback_past_the_end_says_the_recording_ended(tmp_path):
    from fakes.world import FakeWorld

    bag = tmp_path / "short.db3"
    sw = _software(FakeWorld.perpendicular(1.0), initial=PLAN)
    with sw:
        with sw.camera(width=W, height=H, record=bag) as cam:
            list(cam.frames(5))
    from drivers.realsense import RealSenseCamera

    with RealSenseCamera(file=bag) as cam:
        with pytest.raises(CameraError, match=r"recording ended after \d+ frames; ask for fewer frames"):
            list(cam.frames(10_000))


@pytest.mark.slow
def test_a_slow_reader_gets_every_frame_of_a_recording(tmp_path):
    """Reading a recording more slowly than the SDK reads the file loses nothing and does not hang."""
    from fakes.world import FakeWorld

    bag = tmp_path / "long.db3"
    sw = _software(FakeWorld.perpendicular(1.0), initial=PLAN, rate_hz=500)
    with sw:
        with sw.camera(width=W, height=H, record=bag) as cam:
            list(cam.frames(150, ir=True))
    code = (
        "import sys, time\n"
        "from drivers.realsense import RealSenseCamera\n"
        "from drivers.errors import CameraError\n"
        "numbers = []\n"
        f"with RealSenseCamera(file={str(bag)!r}) as cam:\n"
        "    try:\n"
        "        for f in cam.frames(10_000, ir=True):\n"
        "            assert f.ir is not None\n"
        "            numbers.append(f.frame_number)\n"
        "            time.sleep(0.002)\n"
        "    except CameraError:\n"
        "        pass\n"
        "print(len(numbers), numbers[0], numbers[-1], all(b == a + 1 for a, b in zip(numbers, numbers[1:])))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    count, first, last, consecutive = out.stdout.split()
    assert int(count) >= 150 and consecutive == "True" and int(last) - int(first) + 1 == int(count)


# -- a camera that does not hold the settings stops the run before anything is recorded ------------------

@pytest.mark.parametrize("report, said", [
    ({"auto_exposure": True}, "auto-exposure on (asked off)"),
    ({"exposure_us": 4000.0}, "exposure 4000 us (asked 8500 us)"),
    ({"projector_on": False}, "projector off (asked on)"),
])
def test_metadata_that_disagree_stop_the_run_before_recording(tmp_path, report, said):
    path = tmp_path / "bad.h5"
    with pytest.raises(RunError) as e:
        _run_software(path, report=report, stops=[1.0], frames=10)
    msg = str(e.value)
    assert said in msg and "nothing was recorded" in msg and "\n" not in msg
    assert not path.exists()


def test_settings_are_read_back_from_the_device_and_long_exposures_warn():
    from fakes.world import FakeWorld

    sw = _software(FakeWorld.perpendicular(1.0))
    with sw:
        with sw.camera(width=W, height=H) as cam:
            assert cam.read_settings().auto_exposure  # a D435 starts with auto-exposure on
            got = cam.configure(CameraSettings(projector_on=False, exposure_us=5000.4, gain=32, auto_exposure=False))
            assert got == CameraSettings(projector_on=False, exposure_us=5000.0, gain=32.0, auto_exposure=False)
            (frame,) = list(cam.frames(1, ir=True))
            assert frame.metadata.exposure_us == 5000 and frame.metadata.gain == 32 and not frame.metadata.projector_on
            assert frame.ir is not None and frame.ir.dtype == np.uint8 and frame.ir.shape == (H, W)
            with pytest.warns(RuntimeWarning, match=r"exposure 40000 us is longer than the frame period 33333 us"):
                cam.configure(CameraSettings(exposure_us=40000))
            with pytest.raises(CameraError, match=r"exposure 200000 us is outside 1-165000 us; choose one inside"):
                cam.configure(CameraSettings(exposure_us=200000))
            info = cam.info()
            assert (info.model, info.serial, info.firmware) == ("Intel RealSense D435 (software device, fake physics)",
                                                                "SW-D435-0001", "5.16.0.1")
            assert info.extra["usb_type"] == "3.2" and info.extra["baseline_source"].startswith("extrinsics")
            assert info.extra["options"]["Gain"] == 16.0  # options as they were at open
            assert info.extra["post_processing"].startswith("none")  # the driver applies no processing block


@pytest.mark.parametrize("clock", ["host", "device"])
def test_frames_queued_before_a_request_are_not_returned(clock):
    """After a stage move the queue holds frames of the old position; frames() skips them, by
    timestamp with host-clock timestamps, by frame number with the camera's own clock."""
    from fakes.world import FakeWorld

    world = FakeWorld.perpendicular(1.0)
    sw = _software(world, initial=PLAN, clock=clock, rate_hz=400)
    with sw:
        with sw.camera(width=W, height=H) as cam:
            cam.configure(PLAN)
            for i, z in enumerate([2.0, 1.0, 1.5, 2.5, 0.8, 1.2] * 3):
                time.sleep(0.02 * (i % 3))  # let some frames of the old position queue up
                world.set_distance(z)
                for f in cam.frames(2):
                    c = f.depth[H // 2 - 2:H // 2 + 2, W // 2 - 2:W // 2 + 2] * UNIT_MM / 1000
                    assert np.median(c[c > 0]) == pytest.approx(z, rel=0.03), (i, f.frame_number)


def test_wrong_mode_and_serial_give_one_line_errors():
    rs = _rs()
    from drivers.realsense import RealSenseCamera
    from fakes.world import FakeWorld

    sw = _software(FakeWorld.perpendicular(1.0))
    with pytest.raises(CameraError, match=r"no depth mode 848x480 at 30 fps; it offers 64x36@30; pass width="):
        sw.camera().open()
    ctx = rs.context()
    with pytest.raises(CameraError, match=r"no RealSense camera is connected .* --camera fake:"):
        RealSenseCamera(context=ctx).open()


# -- no camera, no SDK ----------------------------------------------------------------------------------

def test_no_camera_attached_gives_a_one_line_error_quickly(tmp_path):
    _rs()
    devices = open_devices("realsense:", "none:")
    t0 = time.monotonic()
    with pytest.raises(RunError) as e:
        Runner(devices.camera, devices.stage).run(perpendicular(stops_m=[1.0], frames_per_stop=2), tmp_path / "x.h5")
    elapsed = time.monotonic() - t0
    assert elapsed < 5.0
    msg = str(e.value)
    assert "no RealSense camera is connected" in msg and "--camera fake:" in msg and "\n" not in msg


@pytest.mark.slow
def test_importing_the_driver_needs_no_sdk_and_using_it_says_what_to_install():
    code = (
        "import sys; sys.modules['pyrealsense2'] = None\n"
        "from rig.devices import open_devices\n"
        "from drivers.errors import CameraError\n"
        "import drivers.realsense\n"
        "d = open_devices('realsense:serial=1', 'none:')\n"
        "try:\n    d.camera.open()\nexcept CameraError as e:\n    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    line = out.stdout.strip()
    assert "\n" not in line
    assert "pyrealsense2 is not installed" in line and "pip install pyrealsense2" in line
    assert "apt-get install libusb-1.0-0" in line


def test_missing_libusb_is_named_with_its_apt_package():
    from drivers.realsense import import_problem

    e = ImportError("libusb-1.0.so.0: cannot open shared object file: No such file or directory")
    msg = import_problem(e)
    assert "libusb-1.0 that pyrealsense2 needs is missing" in msg and "apt-get install libusb-1.0-0" in msg
    assert "\n" not in msg


def test_unknown_option_is_refused_in_one_line():
    with pytest.raises(DeviceError, match=r"unknown option 'widht' in 'realsense:widht=640'; did you mean width\? It takes: "):
        open_devices("realsense:widht=640", "none:")


# -- rig devices, and the Depth Quality Tool's figures ------------------------------------------------

def test_depth_quality_figures_of_a_known_tilted_plane():
    from rig.camera_check.depth_quality import depth_quality

    fx = fy = 400.0
    h, w = 120, 200
    cx, cy = (w - 1) / 2, (h - 1) / 2
    b, d, tilt = 0.05, 1.2, np.radians(10.0)
    v, u = np.mgrid[0:h, 0:w].astype(float)
    xn = (u - cx) / fx
    z = d / (1 + np.tan(tilt) * xn)  # the fake world's tilted wall
    rng = np.random.default_rng(1)
    sigma = 0.002
    noisy = z + rng.normal(0, sigma, z.shape)
    noisy[rng.random(z.shape) < 0.25] = np.nan  # a quarter of the pixels without depth
    q = depth_quality(noisy, fx=fx, fy=fy, cx=cx, cy=cy, baseline_m=b, truth_m=1.19)
    assert q.fill_rate == pytest.approx(0.75, abs=0.02)
    assert q.plane_tilt_deg == pytest.approx(10.0, abs=0.1)
    # perpendicular residuals of noise along Z: sigma * cos(tilt)
    assert q.spatial_noise_m == pytest.approx(sigma * np.cos(tilt), rel=0.05)
    assert q.subpixel_rms_px == pytest.approx(fx * b * sigma / d**2, rel=0.1)
    assert q.range_error_m == pytest.approx(q.median_m - 1.19) and q.median_m == pytest.approx(d, abs=0.01)
    flat = depth_quality(np.where(np.isfinite(noisy), z, np.nan), fx=fx, fy=fy, cx=cx, cy=cy, baseline_m=b)
    assert flat.spatial_noise_m < 1e-9 and flat.subpixel_rms_px < 1e-6 and np.isnan(flat.range_error_m)
    empty = depth_quality(np.zeros((h, w)), fx=fx, fy=fy, cx=cx, cy=cy, baseline_m=b)
    assert empty.fill_rate == 0 and "too few pixels" in empty.summary()


def _nothing_from(monkeypatch, *names):
    """Make the probes `names` find nothing (the others run for real)."""
    from drivers import listing

    real = listing.probes

    def probes():
        got = real()
        return listing.ProbeSet({n: ((lambda: []) if n in names else p) for n, p in got.probes.items()}, got.cameras)

    monkeypatch.setattr(listing, "probes", probes)


def test_rig_devices_lists_nothing_attached_in_one_plain_line_quickly(monkeypatch):
    import io

    from rig.cli import devices_main

    _nothing_from(monkeypatch, "realsense", "oak", "serial")
    out = io.StringIO()
    assert devices_main([], out=out) == 0
    last = out.getvalue().strip().splitlines()[-1]
    assert last.startswith("nothing is attached: no camera (") and "RealSense" in last and "OAK" in last
    assert last.endswith("simulate a rig with --camera fake: --stage fake:")


def test_rig_devices_with_the_real_probes_answers_within_five_seconds():
    import io

    from rig.cli import devices_main

    out = io.StringIO()
    t0 = time.monotonic()
    assert devices_main([], out=out) == 0
    assert time.monotonic() - t0 < 5.0
    text = out.getvalue()
    assert text.startswith("cameras:") and "serial ports:" in text


def test_rig_devices_names_serial_ports_and_their_likely_stage_protocol(monkeypatch):
    import io

    from serial.tools import list_ports
    from serial.tools.list_ports_common import ListPortInfo

    from rig.cli import devices_main

    def port(dev, vid, pid, desc, manufacturer=None):
        p = ListPortInfo(dev)
        p.vid, p.pid, p.description, p.manufacturer, p.serial_number = vid, pid, desc, manufacturer, "A1"
        return p

    ports = [port("/dev/ttyACM0", 0x2341, 0x0043, "Arduino Uno"), port("/dev/ttyUSB1", 0x0403, 0x6001, "X-MCB2",
                                                                          "Zaber Technologies Inc."),
             port("/dev/ttyUSB2", 0x1234, 0x5678, "Some adapter"), port("/dev/ttyS0", None, None, "n/a")]
    monkeypatch.setattr(list_ports, "comports", lambda: ports)
    _nothing_from(monkeypatch, "realsense", "oak")
    out = io.StringIO()
    devices_main([], out=out)
    lines = out.getvalue().splitlines()
    acm = next(l for l in lines if "/dev/ttyACM0" in l)
    assert "USB 2341:0043" in acm and "likely grbl" in acm and "--stage grbl:///dev/ttyACM0" in acm
    zaber = next(l for l in lines if "/dev/ttyUSB1" in l)
    assert "likely zaber" in zaber and "--stage zaber:///dev/ttyUSB1" in zaber
    assert "likely unknown" in next(l for l in lines if "/dev/ttyUSB2" in l)
    assert not any("/dev/ttyS0" in l for l in lines) and not any(l.startswith("nothing is attached") for l in lines)


def test_rig_devices_check_on_the_fake_camera_reports_projector_on_and_off():
    import io

    from rig.cli import devices_main

    out = io.StringIO()
    assert devices_main(["--check", "fake:width=64,seed=2", "--seconds", "2"], out=out) == 0
    lines = out.getvalue().splitlines()
    on = next(l for l in lines if l.startswith("projector on "))
    off = next(l for l in lines if l.startswith("projector off"))
    assert "fill rate 100.0 %" in on and "centre range 1.000 m" in on
    assert "exposure 8500 us and gain 16 (read back 8500 us, gain 16, auto-exposure off)" in on
    assert "fill rate   0.0 %" in off and "(dark)" in off  # night: with the projector off nothing lights the wall
    assert any(l.startswith("IR pattern contrast changed when the projector was switched: yes") for l in lines)
    quality = next(l for l in lines if l.startswith("depth quality, projector on"))
    assert "fill rate 100.0 %" in quality and "range error" in quality and "vs 1.000 m" in quality


def test_projector_check_through_the_sdk_sees_the_pattern_come_and_go():
    from fakes.world import FakeWorld
    from rig.camera_check.projector_check import ProjectorCheck, capture_check, contrast_changed

    sw = _software(FakeWorld.perpendicular(1.0), light="night")  # the projector is the only light
    with sw:
        with sw.camera(width=W, height=H) as cam:
            on = capture_check(cam, CameraSettings(projector_on=True), 10)
            off = capture_check(cam, CameraSettings(projector_on=False), 10)
    assert on.fill_rate > 0.99 and on.centre_range_m == pytest.approx(1.0, rel=0.01)
    assert on.read_back.exposure_us == 8500 and not on.read_back.auto_exposure
    assert off.fill_rate == 0.0 and off.ir_mean_dn < 1  # dark: no pattern, no depth
    assert contrast_changed(on, off) and on.ir_contrast > 0.5
    same = ProjectorCheck(False, 1, 1.0, 1.0, 8500, 16, CameraSettings(), on.ir_contrast, 50.0, on.mean_depth_m)
    assert not contrast_changed(on, same)


def test_a_recording_made_with_auto_exposure_plays_back_as_it_was_made_with_a_note(tmp_path):
    """A recording cannot be changed: played back, its settings are taken as recorded (auto-exposure on, the
    exposure of each frame from its metadata) and every output says so; a live camera still refuses them."""
    from fakes.realsense_software import CAMERA_DEFAULTS
    from fakes.world import FakeWorld

    assert CAMERA_DEFAULTS.auto_exposure  # the SDK device starts as a camera out of the box: auto-exposure on
    bag = tmp_path / "auto.db3"
    # the device starts with auto-exposure on, so every recorded frame has it: started with the plan's settings, the
    # frames pushed before configure() below were recorded with them (a loaded machine: 0.1 s between open and
    # configure), and the file then begins exactly as the plan asks (a full-suite run failed on that)
    sw = _software(FakeWorld.perpendicular(1.2))
    with sw:
        with sw.camera(width=W, height=H, record=bag) as cam:
            cam.configure(CAMERA_DEFAULTS)
            list(cam.frames(30))
    devices = open_devices(f"realsense:file={bag}", "none:")
    messages = []
    plan = perpendicular(stops_m=[1.2], frames_per_stop=20)  # asks for auto-exposure off, as every plan does
    assert not plan.params.get("auto_exposure", False)
    Runner(devices.camera, devices.stage, sleep=lambda s: None,
           progress=lambda e: messages.append(e.text)).run(plan, tmp_path / "played.h5")
    assert any("plays back a recording" in m and "auto-exposure on (asked off)" in m for m in messages), messages
    with Recording(tmp_path / "played.h5") as rec:
        (stop,) = list(rec.stops())
        assert stop.settings_read_back["auto_exposure"] is True
        exposure, numbers = stop.series.exposure_us, stop.series.frame_number
        notes = rec.notes()
    # each frame's exposure is its own, as the file's metadata say (read here with the SDK's own playback)
    rs = _rs()
    in_file = {}
    exposure_key = rs.frame_metadata_value.actual_exposure

    def read(d):
        if d.supports_frame_metadata(exposure_key):
            in_file[d.get_frame_number()] = d.get_frame_metadata(exposure_key)

    _read_with_sdk(bag, read)
    assert [in_file[int(n)] for n in numbers] == exposure.tolist()
    assert set(exposure.tolist()) != {PLAN.exposure_us}  # the SDK device's auto-exposure chose its own
    (note,) = [n for n in notes if n.startswith("played back from a recording")]
    assert "auto-exposure on (asked off)" in note, note
    assert f"exposure per frame {exposure.min():g}-{exposure.max():g} us" in note, note
    assert note in fit_recording(tmp_path / "played.h5").notes


def test_a_recordings_settings_are_those_its_frames_report_not_the_playbacks_option_snapshot(tmp_path):
    """Played back, the SDK's options are a snapshot taken near the start of the recording, on the SDK's thread; they
    can differ from what the frames were exposed with (seen: auto-exposure switched on as the recording began read
    back as off while its first frame had it on, 1 of 12 recordings). Here the frames report auto-exposure on and
    their own exposure while the options say off, deterministically: the run takes the frames' word."""
    from fakes.world import FakeWorld

    bag = tmp_path / "told.db3"
    sw = _software(FakeWorld.perpendicular(1.2), initial=PLAN, report={"auto_exposure": True, "exposure_us": 12000.0})
    with sw:
        with sw.camera(width=W, height=H, record=bag) as cam:
            list(cam.frames(30))
    devices = open_devices(f"realsense:file={bag}", "none:")
    messages = []
    Runner(devices.camera, devices.stage, sleep=lambda s: None,
           progress=lambda e: messages.append(e.text)).run(perpendicular(stops_m=[1.2], frames_per_stop=20),
                                                         tmp_path / "played.h5")
    said = [m for m in messages if "plays back a recording" in m]
    assert said and "auto-exposure on (asked off)" in said[0], messages
    with Recording(tmp_path / "played.h5") as rec:
        (stop,) = list(rec.stops())
        assert stop.settings_read_back["auto_exposure"] is True
        assert stop.settings_read_back["exposure_us"] == 12000.0
        assert set(stop.series.exposure_us.tolist()) == {12000.0}


def test_the_real_d435_recording_reads_back_the_exposure_its_first_frame_had():
    """The real D435 bag (tests/vendor/real/realsense, recorded by Intel): auto-exposure on; the playback's options say
    exposure 8500 us (the manual value, unused under auto-exposure), its first depth frame's metadata 6452 us."""
    from drivers.realsense import RealSenseCamera

    _rs()
    bag = Path(__file__).parent / "vendor" / "real" / "realsense" / "single_depth_color_640x480.bag"
    with RealSenseCamera(file=bag) as cam:
        assert cam._option_settings().exposure_us == 8500.0  # what the settings were read from before
        got = cam.read_settings()
        first = next(cam.frames(1)).metadata
    assert got.auto_exposure and first.auto_exposure
    assert (got.exposure_us, got.gain, got.projector_on) == (first.exposure_us, first.gain, first.projector_on) == (6452.0, 16.0, True)
