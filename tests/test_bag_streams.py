"""Every depth stream a lab records comes in right: several cameras in one bag.

The bags are written with rosbags' own writer and typestore (tests/ros_bags.py `write_cameras`), in the topic layouts
of realsense-ros 2.x and 4.x and depthai-ros (drivers/bag/camera_topics.py cites them).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import h5py
import numpy as np
import pytest

from drivers.bag.contents import read_facts
from drivers.errors import FolderImportError
from protocols.recording import Recording
from protocols.stats import PixelMomentAccumulator
from rig.analysis import fit_recording
from rig.cli import import_main
from ros_bags import Camera, write_cameras
from rvl_encoder import encode_rvl

SHAPE = (12, 16)
ARGS = ["--projector", "on", "--distance-m", "1.5"]


def _counts(n: int = 6, z_mm: float = 1500.0, sigma_mm: float = 3.0, seed: int = 0, holes: bool = True) -> np.ndarray:
    """(n, 12, 16) 16UC1 depth of a wall, mm; with `holes`, a few pixels with no depth (0) in every frame."""
    rng = np.random.default_rng(seed)
    frames = np.rint(z_mm + rng.normal(0, sigma_mm, (n, *SHAPE))).astype(np.uint16)
    if holes:
        frames[:, 0, :5] = 0
        frames[rng.random(frames.shape) < 0.05] = 0
    return frames


def _import(src: Path, out: Path, *args: str) -> Recording:
    assert import_main([str(src), "-o", str(out), *args]) == 0
    return Recording(out)


def _refused(src: Path, out: Path, *args: str) -> str:
    with pytest.raises(FolderImportError) as e:
        import_main([str(src), "-o", str(out), *args])
    assert "\n" not in str(e.value) and not out.exists(), str(e.value)
    return str(e.value)


def _camera_extra(path: Path) -> dict:
    """The `extra` of the recording's camera: what the import says about the stream."""
    with h5py.File(path, "r") as f:
        return json.loads(f.attrs["camera"])["extra"]


def _same_stats(a: Recording, b: Recording) -> None:
    for sa, sb in zip(a.stops(), b.stops(), strict=True):
        assert np.array_equal(sa.stats.count, sb.stats.count)
        for name in ("mean_m", "m2_m2", "m3_m3", "m4_m4"):  # one implementation on the same counts: exact
            assert np.array_equal(getattr(sa.stats, name), getattr(sb.stats, name), equal_nan=True), name


# --- several cameras in one bag: each its own intrinsics and baseline --------------------------------------------

#: (format, camera namespaces, depth, its camera_info, the baseline's camera_info (None: extrinsics instead))
LAYOUTS = {
    "realsense-ros 2.x": ("ros1", ("/cam_a", "/cam_b"), "depth/image_rect_raw", "depth/camera_info", "infra2/camera_info"),
    "realsense-ros 4.x": ("mcap", ("/cam_a/camera", "/cam_b/camera"), "depth/image_rect_raw", "depth/camera_info", None),
    "depthai-ros": ("db3", ("/oak_a", "/oak_b"), "stereo/image_raw", "stereo/camera_info", "left/camera_info"),
}


def _two_cameras(path: Path, layout: str, b_right: bool = True) -> tuple[Path, str, str]:
    fmt, (ns_a, ns_b), depth, info, right = LAYOUTS[layout]
    frames = _counts()

    def cam(ns, fx, baseline_m, with_baseline=True):
        ex = (-baseline_m, 0.0, 0.0) if right is None and with_baseline else None  # depth -> infra2: the right imager at +x
        return Camera(frames, ns=ns, depth=depth, info=info, right_info=right if with_baseline else None, fx=fx,
                      baseline_m=baseline_m, extrinsics_m=ex)

    bag = write_cameras(path, [cam(ns_a, 60.0, 0.050), cam(ns_b, 90.0, 0.095, b_right)], fmt)
    return bag, f"{ns_a}/{depth}", f"{ns_b}/{depth}"


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_each_camera_gets_its_own_intrinsics_and_baseline(tmp_path, layout):
    bag, a, b = _two_cameras(tmp_path / "two", layout)
    for topic, fx, baseline_m in ((a, 60.0, 0.050), (b, 90.0, 0.095)):
        f = read_facts(bag, topic)
        assert (f.fx, f.fy) == (fx, fx), topic  # K as written, float64
        # -P[3] / P[0] of P[3] = -fx * b (a product and a quotient, 2 u); the extrinsics' length: one square root, u
        assert f.baseline_m == pytest.approx(baseline_m, rel=2 * np.finfo(float).eps, abs=0), topic
        assert f.extra["baseline_source"].startswith(topic.rsplit("/", 2)[0] + "/"), f.extra["baseline_source"]


def test_the_chosen_camera_s_baseline_is_what_the_recording_holds(tmp_path, capsys):
    """The tester's bag: cam_a fx 60 px, 50 mm; cam_b fx 90 px, 95 mm; cam_b imported."""
    bag, _a, b = _two_cameras(tmp_path / "two", "realsense-ros 4.x")
    with _import(bag, tmp_path / "b.h5", "--topic", b, *ARGS) as rec:
        assert (rec.calibration.fx, rec.calibration.baseline_m) == (90.0, pytest.approx(0.095, rel=1e-15))


@pytest.mark.parametrize("case", ["other_cameras_only", "disagree"])
def test_a_baseline_the_bag_cannot_give_its_camera_is_refused_naming_the_flag(tmp_path, case):
    if case == "other_cameras_only":  # cam_b records no right imager: cam_a's is not cam_b's
        bag, _a, b = _two_cameras(tmp_path / "two", "realsense-ros 2.x", b_right=False)
        want = "/cam_b/ (/cam_b/depth/image_rect_raw's camera) gives the stereo baseline; /cam_a/infra2/camera_info belongs"
    else:  # cam_b's right imager says 95 mm, its extrinsics 100 mm
        b = "/cam_b/depth/image_rect_raw"
        bag = write_cameras(tmp_path / "disagree", [Camera(_counts(), ns="/cam_a", fx=60.0, baseline_m=0.05),
                                                     Camera(_counts(), ns="/cam_b", fx=90.0, baseline_m=0.095,
                                                            extrinsics_m=(-0.1, 0.0, 0.0))], "mcap")
        want = "disagree on the stereo baseline (/cam_b/infra2/camera_info 95 mm, /cam_b/extrinsics/depth_to_infra2 100 mm)"
    message = _refused(bag, tmp_path / "x.h5", "--topic", b, *ARGS)
    assert want in message and message.endswith("pass --baseline-m"), message
    with _import(bag, tmp_path / "given.h5", "--topic", b, *ARGS, "--baseline-m", "0.095") as rec:
        assert rec.calibration.baseline_m == 0.095
