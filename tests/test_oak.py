"""The OAK-D driver's pieces with real depthai (v3) objects, and discovery without a device.

Building and starting the on-device pipeline needs an OAK attached (depthai cannot create
camera or StereoDepth nodes in a host-only pipeline); see docs/hardware.md.
"""

import datetime
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from drivers.camera import CameraSettings
from drivers.errors import CameraError
from protocols.runner import settings_mismatch
from rig.devices import open_devices

dai = pytest.importorskip("depthai", reason="depthai is not installed (pip install 'depthai>=3,<4')")
ROOT = Path(__file__).resolve().parents[1]


def _img(data, seq, *, exposure_us=8500, iso=100, t_s=1.25, kind=None):
    f = dai.ImgFrame()
    h, w = data.shape
    f.setWidth(w)
    f.setHeight(h)
    f.setType(kind or (dai.ImgFrame.Type.RAW16 if data.dtype == np.uint16 else dai.ImgFrame.Type.GRAY8))
    f.setData(np.ascontiguousarray(data).view(np.uint8).ravel())
    f.setSequenceNum(seq)
    f.setTimestampDevice(datetime.timedelta(seconds=t_s))
    cam = f.cam
    cam.exposureTimeUs = exposure_us
    cam.sensitivityIso = iso
    f.cam = cam
    return f


def test_imgframes_become_a_frame_with_the_left_cameras_exposure_and_sensitivity():
    from drivers.oak import frame_from_messages

    rng = np.random.default_rng(0)
    depth = rng.integers(300, 3000, size=(40, 64), dtype=np.uint16)
    left = rng.integers(0, 255, size=(40, 64), dtype=np.uint8)
    frame = frame_from_messages(_img(depth, 17), _img(left, 17, exposure_us=8500, iso=200), projector_on=True,
                                auto_exposure=False, ir=True)
    np.testing.assert_array_equal(frame.depth, depth)
    assert frame.depth.dtype == np.uint16 and frame.depth.flags.writeable
    np.testing.assert_array_equal(frame.ir, left)
    assert frame.frame_number == 17 and frame.timestamp_ms == pytest.approx(1250.0)
    assert (frame.metadata.exposure_us, frame.metadata.gain) == (8500.0, 32.0)  # ISO 200 = x2 = rig's gain 32
    assert frame.metadata.projector_on and not frame.metadata.auto_exposure
    assert frame_from_messages(_img(depth, 17), _img(left, 17), projector_on=True, auto_exposure=False).ir is None


def test_frame_metadata_are_checked_against_the_request():
    from drivers.oak import frame_from_messages

    depth = np.full((8, 8), 1000, np.uint16)
    asked = CameraSettings(projector_on=True, exposure_us=8500, gain=16)  # ISO 100
    good = frame_from_messages(_img(depth, 3), _img(depth.astype(np.uint8), 3, exposure_us=8500, iso=100),
                               projector_on=True, auto_exposure=False)
    assert settings_mismatch(asked, good.metadata) == []
    stale = frame_from_messages(_img(depth, 4), _img(depth.astype(np.uint8), 4, exposure_us=20000, iso=400),
                                projector_on=True, auto_exposure=False)
    assert settings_mismatch(asked, stale.metadata) == ["exposure 20000 us (asked 8500 us)", "gain 64 (asked 16)"]


def test_wrong_messages_are_refused_in_one_line():
    from drivers.oak import frame_from_messages

    depth = np.full((8, 8), 1000, np.uint16)
    with pytest.raises(CameraError, match=r"depth frame 5 was paired with left frame 6; pair frames by sequence number"):
        frame_from_messages(_img(depth, 5), _img(depth.astype(np.uint8), 6), projector_on=True, auto_exposure=False)
    with pytest.raises(CameraError, match=r"not a uint16 image; link StereoDepth.depth"):
        frame_from_messages(_img(depth.astype(np.uint8), 5), None, projector_on=True, auto_exposure=False)


def test_calibration_from_a_handler_gives_metres_and_scaled_intrinsics():
    from drivers.oak import calibration_from_handler

    h = dai.CalibrationHandler()
    k = [[800.0, 0.0, 640.0], [0.0, 801.0, 400.0], [0.0, 0.0, 1.0]]
    for socket in (dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C):
        h.setCameraIntrinsics(socket, k, 1280, 800)
    eye = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    # calibrated 7.42 cm (stored in cm), designed 7.5 cm: the driver must use the calibration
    h.setCameraExtrinsics(dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C, eye, [-7.42, 0.0, 0.0], [-7.5, 0.0, 0.0])
    intr, baseline_m = calibration_from_handler(h, 640, 400)
    assert baseline_m == pytest.approx(0.0742, rel=1e-5)
    assert (intr.width, intr.height) == (640, 400)
    assert (intr.fx, intr.fy, intr.cx, intr.cy) == pytest.approx((400.0, 400.5, 320.0, 200.0))
    with pytest.raises(CameraError, match=r"no stereo calibration|baseline of 0 cm; recalibrate"):
        calibration_from_handler(dai.CalibrationHandler(), 640, 400)


def test_exposure_control_and_stereo_settings_are_what_the_rig_records():
    from drivers.oak import apply_stereo_settings, exposure_control, stereo_settings

    ctrl = exposure_control(CameraSettings(exposure_us=8500.4, gain=32))  # rig's gain 32 = x2 = ISO 200
    assert ctrl.getExposureTime() == datetime.timedelta(microseconds=8500) and ctrl.getSensitivity() == 200
    with pytest.raises(CameraError, match=r"oak: gain 8 is outside 16-256 \(rig's unit: 16 = x1, = ISO 100 on this camera\)"):
        exposure_control(CameraSettings(gain=8))
    with pytest.raises(CameraError, match=r"exposure 50000 us is outside 20-33000 us"):
        exposure_control(CameraSettings(exposure_us=50000, gain=16))
    cfg = dai.StereoDepthConfig()
    apply_stereo_settings(cfg, confidence=180, subpixel=True, lr_check=True)
    s = stereo_settings(cfg, "ROBOTICS")
    assert s["preset"] == "ROBOTICS" and s["subpixel"] and s["lr_check"]
    assert s["confidence_threshold"] == 180 and s["median_filter"] == "MEDIAN_OFF" and s["depth_unit"] == "MILLIMETER"


def test_no_device_gives_a_one_line_error_within_five_seconds():
    devices = open_devices("oak:", "none:")
    t0 = time.monotonic()
    with pytest.raises(CameraError) as e:
        devices.camera.open()
    assert time.monotonic() - t0 < 5.0
    msg = str(e.value)
    assert msg.startswith("oak: no OAK device found") and "--camera fake:" in msg and "\n" not in msg


@pytest.mark.slow
def test_importing_the_driver_needs_no_sdk():
    code = (
        "import sys; sys.modules['depthai'] = None\n"
        "from rig.devices import open_devices\n"
        "from drivers.errors import CameraError\n"
        "import drivers.oak\n"
        "d = open_devices('oak:', 'none:')\n"
        "try:\n    d.camera.open()\nexcept CameraError as e:\n    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().startswith("oak: the Python package depthai is not installed; install it with pip install 'depthai>=3,<4'")
