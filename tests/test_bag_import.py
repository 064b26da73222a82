"""`rig import` of bags: a real RealSense D435 recording, and ROS 1/ROS 2 bags written by rosbags.

The real file (tests/vendor/real/realsense/, README there) was written by librealsense's recorder
from a D435: everything rig records about the camera must come from the bag itself, and its frames' statistics
must be what a reading of the same bag with rosbags alone gives. The ROS bags are written here with rosbags
(tests/ros_bags.py: realsense-ros's topics and types) from a live run's raw frames, so an import must give
that run's statistics exactly.
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from drivers.errors import FolderImportError
from protocols.bag_import import import_bags
from protocols.recording import Recording
from protocols.stats import PixelMomentAccumulator
from rig.analysis import fit_recording
from rig.cli import import_main
from moment_bounds import U, accumulator_bounds, numpy_bounds
from ros_bags import DEPTH, write_bag
from simrig import record_perpendicular

pytestmark = pytest.mark.slow


ROOT = Path(__file__).resolve().parents[1]
D435 = ROOT / "tests" / "vendor" / "real" / "realsense" / "single_depth_color_640x480.bag"
STOPS_M = [0.75, 1.5, 2.25]
FRAMES = 8
PATTERN = "(?P<m>[0-9.]+)m"


def _real_bag() -> Path:
    assert D435.is_file(), f"the real D435 recording is missing: {D435} (see tests/vendor/real/README.md)"
    return D435


def _frames_read_by_rosbags(path: Path) -> tuple[np.ndarray, list[int]]:
    """The bag's depth frames and their Frame Counter, read with rosbags alone (no rig code)."""
    from rosbags.highlevel import AnyReader

    frames, numbers = [], []
    with AnyReader([path]) as r:
        image = [c for c in r.connections if c.topic == "/device_0/sensor_0/Depth_0/image/data"]
        meta = [c for c in r.connections if c.topic == "/device_0/sensor_0/Depth_0/image/metadata"]
        for c, _t, raw in r.messages(connections=meta):
            kv = r.deserialize(raw, c.msgtype)
            if kv.key == "Frame Counter":
                numbers.append(int(kv.value))
        for c, _t, raw in r.messages(connections=image):
            m = r.deserialize(raw, c.msgtype)
            frames.append(np.frombuffer(m.data, "<u2").reshape(m.height, m.width))
    return np.stack(frames), numbers


@pytest.mark.numeric
def test_the_real_d435_bag_imports_with_the_bag_s_own_metadata(tmp_path, capsys):
    bag = _real_bag()
    out = tmp_path / "d435.h5"
    assert import_main([str(bag), "-o", str(out), "--distance-m", "1.6"]) == 0
    assert str(out) in capsys.readouterr().out
    with Recording(out) as rec:
        a, c = rec.attrs, rec.calibration
        assert (a["camera_model"], a["camera_serial"]) == ("Intel RealSense D435", "728612070259")
        assert (c.width, c.height) == (640, 480)
        assert (c.fx, c.fy, c.cx, c.cy) == pytest.approx((390.43145752, 390.43145752, 331.38787842, 242.18734741))
        assert c.baseline_m == pytest.approx(0.0501706657)  # the recorded Stereo Baseline option, 50.17 mm
        assert c.depth_scale_m == 0.001  # the recorded Depth Units option
        (stop,) = list(rec.stops())
        assert stop.label == "single_depth_color_640x480" and stop.n_frames == 2
        assert stop.settings_read_back == {"projector_on": True, "exposure_us": 8500.0, "gain": 16.0, "auto_exposure": True}
        s = stop.series
        # each frame's own metadata: Frame Counter, Actual Exposure, Gain Level, the laser on
        assert s.frame_number.tolist() == [169, 170] and s.exposure_us.tolist() == [6452.0, 6452.0]
        assert s.gain.tolist() == [16.0, 16.0] and s.projector_on.tolist() == [True, True]
        assert s.timestamp_ms.tolist() == pytest.approx([360815.089, 360981.765])
        assert stop.attrs["frames_dropped"] == 0
        assert stop.attrs["source_topic"] == "/device_0/sensor_0/Depth_0/image/data"
        notes = rec.notes()
        frames, numbers = _frames_read_by_rosbags(bag)
        acc = PixelMomentAccumulator(frames.shape[1:], 0.001)
        for f in frames:
            acc.add(f)
        want = acc.result()
        assert np.array_equal(stop.stats.count, want.count)
        assert np.array_equal(stop.stats.mean_m, want.mean_m, equal_nan=True)
        assert np.array_equal(stop.stats.m2_m2, want.m2_m2)
        assert numbers == [169, 170]
        # and the per-pixel sample variance is numpy's on the two frames: two implementations, each within its
        # rounding (tests/moment_bounds.py: numpy's deviations carry their samples' rounding, 2 u z / |d|, up to
        # 7e-13 at 1.6 m for samples a millimetre apart), and a quotient each; equal samples give 0 both ways
        valid = np.all(frames > 0, axis=0)
        want = np.var(frames[:, valid] * 1e-3, axis=0, ddof=1)
        bound = (accumulator_bounds(frames, 1e-3)["m2_m2"] + numpy_bounds(frames, 1e-3)["m2_m2"])[valid]
        got = stop.stats.variance_m2[valid]
        assert np.all(np.abs(got - want) <= bound + 2 * U * want), np.max(np.abs(got - want) / (bound + 2 * U * want))
    assert any("auto-exposure on" in n and "exposure per frame 6452-6452 us" in n for n in notes), notes
    from rig.reports.run_info import run_info  # what the diagnosis report's header shows

    rows = {key: value for key, _label, value in run_info(out, "now", "test").rows}
    assert (rows["camera_model"], rows["camera_serial"], rows["camera_firmware"]) == (
        "Intel RealSense D435", "728612070259", "05.09.14.00")
    fit = fit_recording(out)
    assert any(n.startswith("one stop only") for n in fit.notes)
    assert 0 < fit.fit.lam < 6 and np.isfinite(fit.fit.se_lam)  # a number, resting on one scene's spread of ranges


def _live(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("live") / "live.h5"
    record_perpendicular(path, seed=5, width=32, frames=FRAMES, stops_m=STOPS_M, keep_raw=True)
    return path


@pytest.fixture(scope="module")
def live(tmp_path_factory) -> Path:
    """A live run of the fake camera (32x18 px, 0.05 mm depth unit), raw frames kept."""
    return _live(tmp_path_factory)


def _bags(live: Path, folder: Path, fmt: str, **kw) -> Path:
    """One bag per stop, named by its distance ('1.500m'), realsense-ros topics; the calibration the live run had."""
    folder.mkdir()
    with Recording(live) as rec:
        c = rec.calibration
    with h5py.File(live, "r") as f:
        for label in f["stops"]:
            write_bag(folder / label, f["stops"][label]["raw_depth"][()], fx=c.fx, fy=c.fy, cx=c.cx, cy=c.cy,
                      baseline_m=c.baseline_m, fmt=fmt, **kw)
    return folder


@pytest.mark.parametrize("fmt", ["db3", "mcap", "ros1"])
def test_ros_bags_give_the_live_run_s_statistics(live, tmp_path, fmt):
    src = _bags(live, tmp_path / "bags", fmt)
    with pytest.raises(FolderImportError, match=r"the bag does not say projector_on; pass --projector on\|off"):
        import_bags(src, tmp_path / "x.h5", {"stop_distance_from_name": PATTERN})
    with pytest.raises(FolderImportError, match=r"mean range 1[0-9.]* m at the centre, but the stop's distance is 0.75 m; "
                                                r"check the distance, or the depth unit: probably the wrong unit: "
                                                r"depth_unit_m = 5e-05 \(0.05 mm\) would fit"):
        import_bags(src, tmp_path / "x.h5", {"stop_distance_from_name": PATTERN, "projector_on": True})
    out = import_bags(src, tmp_path / "bags.h5", {"stop_distance_from_name": PATTERN, "projector_on": True,
                                                  "depth_unit_m": 5e-5})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bags", "bags.h5"]
    with Recording(live) as a, Recording(out) as b:
        for k in ("fx", "fy", "cx", "cy"):  # written and read as float64: the same numbers
            assert getattr(b.calibration, k) == getattr(a.calibration, k), k
        # the baseline from the right imager's P[3] = -fx * baseline: a product and a quotient, 2 u
        assert b.calibration.baseline_m == pytest.approx(a.calibration.baseline_m, rel=2 * U, abs=0)
        assert b.protocol_params["stops_m"] == STOPS_M
        for sa, sb in zip(a.stops(), b.stops(), strict=True):
            assert np.array_equal(sa.stats.count, sb.stats.count)
            for name in ("mean_m", "m2_m2", "m3_m3", "m4_m4"):
                assert np.array_equal(getattr(sa.stats, name), getattr(sb.stats, name), equal_nan=True), name
            assert sb.attrs["source_topic"] == DEPTH and sb.attrs["frames_dropped"] == 0
    f_live, f_bag = fit_recording(live).fit, fit_recording(out).fit
    assert (f_bag.lam, f_bag.k) == (f_live.lam, f_live.k)  # the same implementation on the same statistics


def test_a_lost_frame_is_counted_as_dropped_from_the_timestamps(live, tmp_path):
    with Recording(live) as rec:
        c = rec.calibration
    with h5py.File(live, "r") as f:
        raw = f["stops"]["1.500m"]["raw_depth"][()]
    bag = write_bag(tmp_path / "gap", raw, fx=c.fx, fy=c.fy, cx=c.cx, cy=c.cy, baseline_m=c.baseline_m, fmt="mcap",
                    skip=frozenset({4}))
    out = import_bags(bag, tmp_path / "gap.h5", {"projector_on": True, "depth_unit_m": 5e-5}, distance_m=1.5)
    with Recording(out) as rec:
        (stop,) = list(rec.stops())
        assert stop.n_frames == FRAMES - 1 and stop.attrs["frames_dropped"] == 1
        assert any("1 dropped" in n for n in rec.notes())


def test_the_raw_depth_topic_is_chosen_over_aligned_depth(live, tmp_path):
    """realsense-ros often records depth aligned to colour too: resampled, so not the sensor's noise; the raw
    topic is taken, and the recording names it."""
    bag = _ros2_bag(live, tmp_path, extra_depth_topic="/camera/aligned_depth_to_color/image_raw")
    out = import_bags(bag, tmp_path / "raw.h5", {"projector_on": True, "depth_unit_m": 5e-5}, distance_m=1.5)
    with Recording(out) as rec:
        assert next(rec.stops()).attrs["source_topic"] == DEPTH


def _one_bag_sweep(live: Path, tmp_path: Path, moving: int = 0) -> Path:
    """The live run's stops in one bag, 5 s apart, 30 fps within a stop; `moving` frames of a camera on the move
    (a ramp of depth) in each pause."""
    with Recording(live) as rec:
        c = rec.calibration
    frames, times = [], []
    with h5py.File(live, "r") as f:
        for i, label in enumerate(sorted(f["stops"], key=lambda k: f["stops"][k].attrs["index"])):
            raw = f["stops"][label]["raw_depth"][()]
            frames += list(raw)
            times += [i * 5 * 10**9 + j * 33_333_333 for j in range(len(raw))]
            for j in range(moving if i < len(STOPS_M) - 1 else 0):
                frames.append(np.full_like(raw[0], 20000 + 3000 * j))
                times.append(i * 5 * 10**9 + 2 * 10**9 + j * 33_333_333)
    return write_bag(tmp_path / "sweep", np.stack(frames), fx=c.fx, fy=c.fy, cx=c.cx, cy=c.cy, baseline_m=c.baseline_m,
                     fmt="mcap", times_ns=times)


@pytest.mark.parametrize("how", ["gaps", "time"])
def test_one_bag_holding_the_sweep_is_split_into_its_stops(live, tmp_path, how):
    bag = _one_bag_sweep(live, tmp_path, moving=3 if how == "time" else 0)
    args = [str(bag), "-o", str(tmp_path / "sweep.h5"), "--projector", "on", "--depth-unit-m", "5e-5"]
    if how == "gaps":
        with pytest.raises(FolderImportError, match=r"3 run\(s\) of frames between pauses of 1 s or more "
                                                    r"\(0.0-0.2 s, 5.0-5.2 s, 10.0-10.2 s\), but 2 distances"):
            import_main([*args, "--stops-at-gaps", "0.75,1.5"])
        assert import_main([*args, "--stops-at-gaps", ",".join(map(str, STOPS_M))]) == 0
    else:  # the moving frames (at 2 s and 7 s) lie outside every span
        assert import_main([*args, "--stops-in-time", "0.75@0-1,1.5@5-6,2.25@10-11"]) == 0
    with Recording(live) as a, Recording(tmp_path / "sweep.h5") as b:
        assert [s.label for s in b.stops()] == ["0.750m", "1.500m", "2.250m"]
        for sa, sb in zip(a.stops(), b.stops(), strict=True):
            assert sb.n_frames == FRAMES and np.array_equal(sa.stats.count, sb.stats.count)
            for name in ("mean_m", "m2_m2", "m3_m3", "m4_m4"):
                assert np.array_equal(getattr(sa.stats, name), getattr(sb.stats, name), equal_nan=True), name


def _ros2_bag(live: Path, tmp_path: Path, **kw) -> Path:
    with Recording(live) as rec:
        c = rec.calibration
    with h5py.File(live, "r") as f:
        raw = f["stops"]["1.500m"]["raw_depth"][()]
    return write_bag(tmp_path / "one", raw, fx=c.fx, fy=c.fy, cx=c.cx, cy=c.cy, baseline_m=c.baseline_m, **kw)


@pytest.mark.parametrize("case", ["8_bit", "two_topics", "damaged", "no_distance", "frames_folder"])
def test_a_bag_rig_cannot_use_is_one_line_and_no_file(live, tmp_path, case):
    args = ["--projector", "on", "--depth-unit-m", "5e-5", "--distance-m", "1.5"]
    if case == "8_bit":  # 8 bits cannot hold depth
        src, want = _ros2_bag(live, tmp_path, encoding="8UC1"), "is 8UC1; rig reads depth as 16UC1, mono16, 32FC1"
    elif case == "two_topics":  # two cameras in one bag: which is meant, only the user knows
        src = _ros2_bag(live, tmp_path, extra_depth_topic="/camera2/depth/image_rect_raw")
        want = "several depth topics ['/camera/depth/image_rect_raw', '/camera2/depth/image_rect_raw']; choose one with --topic"
        assert import_main([str(src), "-o", str(tmp_path / "ok.h5"), *args, "--topic", DEPTH]) == 0
    elif case == "damaged":
        src = tmp_path / "cut.bag"
        src.write_bytes(_real_bag().read_bytes()[:300_000])
        want = "cut.bag: not a readable bag ("
    elif case == "no_distance":
        src, args, want = _ros2_bag(live, tmp_path), args[:4], "no distance for this stop (a bag does not record it); pass --distance-m"
    else:
        src = tmp_path / "frames"
        (src / "1.0m").mkdir(parents=True)
        want = "--distance-m, --topic and --stops-* are for bags"
    out = tmp_path / "out.h5"
    with pytest.raises(FolderImportError) as e:
        import_main([str(src), "-o", str(out), *args])
    assert want in str(e.value) and "\n" not in str(e.value), str(e.value)
    assert not out.exists() and not list(tmp_path.glob(".out.h5*"))
