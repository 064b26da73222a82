"""`rig sigma-bag`: a bag copied with a 32FC1 sigma image beside each depth frame (rig/reports/sigma_bag.py).

The input bags are written and the outputs read with rosbags (the library, not rig's bag reader); each sigma pixel
is checked against the evaluator written from docs/noise-model.md alone (tests/noise_model_port.py).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_in_process import rig_in_process
from noise_model_port import PortedModel, rounding_bound
from ros_bags import DEPTH, write_bag

from rig.noise_model import NoiseModel

MODEL = "active+incidence+noise_floor+empirical(radius)"  # incidence: the bag's sigma takes a perpendicular wall's


@pytest.fixture(scope="module")
def model_file(small_recording, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sigma-bag") / "cam.json"
    r = rig_in_process("export", small_recording, "--model", MODEL, "-o", out, "-q")
    assert r.returncode == 0, r.stderr
    return out


def _frames(doc: dict) -> np.ndarray:
    """Three depth frames (mm, as REP 118 has 16UC1) of the model's camera's size, each with pixels of no data."""
    k = doc["camera"]["intrinsics"]
    frames = np.random.default_rng(3).integers(400, 2600, (3, k["height"], k["width"])).astype(np.uint16)
    frames[:, 0, :3] = 0
    frames[1, 5:7, 10:20] = 0
    return frames


def _wall_cos(k: dict, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """cos_incidence of a wall perpendicular to the axis, as docs/noise-model.md gives it: 1 / sqrt(1 + rho^2)."""
    return 1 / np.sqrt(1 + ((u - k["cx"]) / k["fx"]) ** 2 + ((v - k["cy"]) / k["fy"]) ** 2)


def _messages(path: Path, topic: str) -> list[tuple[str, int, bytes, object]]:
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as r:
        chosen = [c for c in r.connections if c.topic == topic]
        return [(c.msgtype, t, bytes(raw), r.deserialize(raw, c.msgtype)) for c, t, raw in r.messages(chosen)]


def _types(path: Path) -> dict[str, str]:
    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as r:
        return {c.topic: c.msgtype for c in r.connections}


@pytest.mark.numeric
@pytest.mark.parametrize("fmt", ["db3", "mcap", "ros1"])
def test_each_depth_frame_gets_its_sigma_image_under_the_same_header(model_file, tmp_path, fmt):
    doc = json.loads(model_file.read_text())
    k = doc["camera"]["intrinsics"]
    frames = _frames(doc)
    bag = write_bag(tmp_path / "run", frames, fx=k["fx"], fy=k["fy"], cx=k["cx"], cy=k["cy"], baseline_m=0.05, fmt=fmt)
    out = tmp_path / ("run-sigma.bag" if fmt == "ros1" else "run-sigma")
    r = rig_in_process("sigma-bag", model_file, bag, "-q")  # the default output name
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"sigma bag: {out} (3 frames of {DEPTH} with their sigma on {DEPTH}/sigma")
    assert _types(out) == {**_types(bag), f"{DEPTH}/sigma": "sensor_msgs/msg/Image"}
    depth_in, depth_out, sigma = _messages(bag, DEPTH), _messages(out, DEPTH), _messages(out, f"{DEPTH}/sigma")
    assert [m[:3] for m in depth_out] == [m[:3] for m in depth_in]  # the depth messages, byte for byte, same times
    assert len(sigma) == len(frames) == 3
    port = PortedModel(doc)
    v, u = np.mgrid[0:k["height"], 0:k["width"]].astype(float)
    cos = _wall_cos(k, u, v)
    for (_, t_in, _, d), (msgtype, t, _, s), counts in zip(depth_in, sigma, frames):
        assert msgtype == "sensor_msgs/msg/Image" and t == t_in
        assert (s.header.stamp.sec, s.header.stamp.nanosec, s.header.frame_id) == \
            (d.header.stamp.sec, d.header.stamp.nanosec, d.header.frame_id)
        assert getattr(s.header, "seq", None) == getattr(d.header, "seq", None)
        assert (s.encoding, s.is_bigendian, s.step) == ("32FC1", 0, 4 * k["width"])
        assert (s.width, s.height) == (k["width"], k["height"])
        image = np.frombuffer(bytes(s.data), "<f4").reshape(k["height"], k["width"])
        valid = counts > 0
        assert np.array_equal(np.isnan(image), ~valid)
        z = counts[valid] * 1e-3  # REP 118: millimetres
        exact = np.array([port.sigma_m(zi, ui, vi, cos_incidence=ci)
                          for zi, ui, vi, ci in zip(z, u[valid], v[valid], cos[valid])])
        # two double implementations within `rounding_bound`, then float32's rounding to nearest: 2^-24 relatively
        inputs = {"cos_incidence": cos[valid]}
        bound = rounding_bound(NoiseModel.from_dict(doc), z, u[valid], v[valid], inputs) + 2.0**-24
        assert np.all(np.abs(image[valid] - exact) <= bound * exact)


def _bag_of_two_sizes(path: Path, doc: dict) -> Path:
    """A ROS 2 bag whose third depth frame is smaller than the first two: rosbags' writer, as a recorder would."""
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    t = ts.types
    Image, Header, Time = t["sensor_msgs/msg/Image"], t["std_msgs/msg/Header"], t["builtin_interfaces/msg/Time"]
    k = doc["camera"]["intrinsics"]
    with Writer(path, version=8) as w:
        c = w.add_connection(DEPTH, Image.__msgtype__, typestore=ts)
        for i, (h, wd) in enumerate([(k["height"], k["width"])] * 2 + [(4, 6)]):
            data = np.full((h, wd), 1000, "<u2").view(np.uint8).ravel()
            msg = Image(header=Header(stamp=Time(sec=1, nanosec=i), frame_id="depth"), height=h, width=wd,
                        encoding="16UC1", is_bigendian=0, step=2 * wd, data=data)
            w.write(c, 10 + i, ts.serialize_cdr(msg, Image.__msgtype__))
    return path


def test_a_failure_leaves_no_output_and_says_why_in_one_line(model_file, tmp_path):
    doc = json.loads(model_file.read_text())
    bag = _bag_of_two_sizes(tmp_path / "mixed", doc)
    out = tmp_path / "out"
    r = rig_in_process("sigma-bag", model_file, bag, "-o", out)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "frame 3 of /camera/depth/image_rect_raw is 6x4 16UC1" in r.stderr and "one depth stream" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mixed"]  # no output, and no partial one beside it
    # refused before anything is written: an output that exists, a ROS 1 name for a ROS 2 bag, another camera's size
    out.mkdir()
    r = rig_in_process("sigma-bag", model_file, bag, "-o", out)
    assert r.returncode == 2 and f"{out} exists; remove it or give another -o" in r.stderr
    r = rig_in_process("sigma-bag", model_file, bag, "-o", tmp_path / "x.bag")
    assert r.returncode == 2 and "is a ROS 2 bag, so the copy is a ROS 2 bag folder" in r.stderr
    small = write_bag(tmp_path / "small", np.full((2, 4, 6), 900, np.uint16), fx=5, fy=5, cx=2.5, cy=1.5, baseline_m=0.05)
    r = rig_in_process("sigma-bag", model_file, small)
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert f"is 6x4 px, the model's camera {doc['camera']['intrinsics']['width']}x" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mixed", "out", "small"]


@pytest.mark.numeric
def test_a_bag_librealsense_recorded_keeps_every_topic_and_gains_its_sigma(model_file, tmp_path):
    """The real D435 recording (tests/vendor/real): 70 topics of librealsense's recorder, ROS 1, copied byte for byte,
    and the sigma of 2000 of its pixels a frame against the port. The model is the exported one given this camera's
    depth intrinsics (the bag's camera_info), as a model fitted to this camera would have them."""
    from rosbags.highlevel import AnyReader

    bag = Path(__file__).parent / "vendor" / "real" / "realsense" / "single_depth_color_640x480.bag"
    topic = "/device_0/sensor_0/Depth_0/image/data"
    with AnyReader([bag]) as r:
        info = next(r.deserialize(raw, c.msgtype) for c, _, raw in r.messages(
            [c for c in r.connections if c.topic == "/device_0/sensor_0/Depth_0/info/camera_info"]))
    doc = json.loads(model_file.read_text())
    doc["camera"]["intrinsics"] = {"width": int(info.width), "height": int(info.height), "fx": float(info.K[0]),
                                   "fy": float(info.K[4]), "cx": float(info.K[2]), "cy": float(info.K[5])}
    (tmp_path / "d435.json").write_text(json.dumps(doc))
    out = tmp_path / "d435-sigma.bag"
    r = rig_in_process("sigma-bag", tmp_path / "d435.json", bag, "-o", out, "-q")
    assert r.returncode == 0, r.stderr
    with AnyReader([bag]) as a, AnyReader([out]) as b:
        before = [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in a.messages()]
        after = [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in b.messages()]
        depth = [a.deserialize(m[3], m[1]) for m in before if m[0] == topic]
        sigma = [b.deserialize(m[3], m[1]) for m in after if m[0] == f"{topic}/sigma"]
    assert len({m[0] for m in before}) == 70
    assert [m for m in after if m[0] != f"{topic}/sigma"] == before
    assert len(sigma) == len(depth) == 2
    port, k = PortedModel(doc), doc["camera"]["intrinsics"]
    pick = np.random.default_rng(5).integers(0, k["width"] * k["height"], 2000)
    for d, s in zip(depth, sigma):
        def fields(h):  # the two readers' classes differ: their fields do not
            return h.seq, h.stamp.sec, h.stamp.nanosec, h.frame_id

        assert fields(s.header) == fields(d.header) and s.encoding == "32FC1"
        counts = np.frombuffer(bytes(d.data), "<u2").reshape(k["height"], k["width"]).ravel()[pick]
        image = np.frombuffer(bytes(s.data), "<f4").ravel()[pick]
        v, u = np.divmod(pick, k["width"])
        valid = counts > 0
        assert np.array_equal(np.isnan(image), ~valid) and valid.mean() > 0.5
        z = counts[valid] * 1e-3  # the recorded Depth Units: 0.001 m
        uv = u[valid].astype(float), v[valid].astype(float)
        cos = _wall_cos(k, *uv)
        exact = np.array([port.sigma_m(*row, cos_incidence=c) for *row, c in zip(z, *uv, cos)])
        bound = rounding_bound(NoiseModel.from_dict(doc), z, *uv, {"cos_incidence": cos}) + 2.0**-24
        assert np.all(np.abs(image[valid] - exact) <= bound * exact)


def _compressed_png(frame: np.ndarray) -> tuple[str, bytes]:
    """16UC1 compressedDepth png as image_transport's codec.cpp makes it: a 12-byte ConfigHeader (format 0 and two
    unset floats, compression_common.h) and cv::imencode's 16-bit PNG (OpenCV, the test extra)."""
    import struct

    import cv2

    ok, png = cv2.imencode(".png", np.ascontiguousarray(frame, np.uint16), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    assert ok
    return "16UC1; compressedDepth png", struct.pack("<iff", 0, 0.0, 0.0) + png.tobytes()


@pytest.mark.numeric
@pytest.mark.parametrize("form", ["32FC1", "big-endian", "compressedDepth"])
def test_every_depth_form_the_import_reads_gets_the_raw_frames_sigma(model_file, tmp_path, form):
    """The forms `rig import` reads (issue 48) give the sigma the raw 16UC1 frames give: exactly for big-endian and
    PNG (the same counts); for 32FC1 metres the range is the float32 m value (counts x float32(1e-3), two roundings:
    within 2 x 2^-24 of counts x 1 mm), which moves sigma by at most 3 times that (d ln sigma / d ln Z <= lambda = 3
    for active + noise_floor; incidence and the radius shape do not depend on Z), and float32 rounds both outputs
    (2^-24 between them): 7 x 2^-24 in all (6.4 seen). Bags by rosbags' writer (tests/ros_bags.py), outputs read by
    rosbags."""
    from ros_bags import Camera, write_cameras

    doc = json.loads(model_file.read_text())
    frames = _frames(doc)
    raw = write_cameras(tmp_path / "raw", [Camera(frames)], fmt="mcap")
    cam = {"32FC1": Camera((frames * np.float32(1e-3)).astype(np.float32), encoding="32FC1"),
           "big-endian": Camera(frames, bigendian=True),
           "compressedDepth": Camera(frames, compress=_compressed_png, right_info=None)}[form]
    sent = write_cameras(tmp_path / "sent", [cam], fmt="mcap")
    for bag in (raw, sent):
        r = rig_in_process("sigma-bag", model_file, bag, "-q")
        assert r.returncode == 0, r.stderr
    want = [np.frombuffer(bytes(m[3].data), "<f4") for m in _messages(tmp_path / "raw-sigma", "/camera/depth/image_rect_raw/sigma")]
    got = [np.frombuffer(bytes(m[3].data), "<f4") for m in _messages(tmp_path / "sent-sigma", f"{cam.depth_topic}/sigma")]
    assert len(got) == len(want) == 3
    for g, w in zip(got, want):
        assert np.array_equal(np.isnan(g), np.isnan(w))
        if form == "32FC1":
            ok = ~np.isnan(w)
            assert np.all(np.abs(g[ok] - w[ok]) <= 7 * 2.0**-24 * w[ok])
        else:
            assert np.array_equal(g, w, equal_nan=True)


def test_a_bag_of_another_camera_gets_its_sigma_with_a_note_saying_so(model_file, tmp_path):
    """The model's camera has its own f and b; a bag of a camera with fx 1.5 times and a baseline 1.9 times the
    model's (the two-camera bag of issue 48: 60 px and 50 mm against 90 px and 95 mm) is copied, with a one-line note
    that the sigma is not this camera's (sigma ~ 1 / (f b)); the same camera gets none (an outside review found
    none given)."""
    from ros_bags import Camera, write_cameras

    doc = json.loads(model_file.read_text())
    k, b = doc["camera"]["intrinsics"], doc["camera"]["baseline_m"]
    frames = _frames(doc)
    same = write_cameras(tmp_path / "same", [Camera(frames, fx=k["fx"], baseline_m=b)])
    other = write_cameras(tmp_path / "other", [Camera(frames, fx=1.5 * k["fx"], baseline_m=1.9 * b)])
    r = rig_in_process("sigma-bag", model_file, same)
    assert r.returncode == 0 and "note:" not in r.stderr, r.stderr
    r = rig_in_process("sigma-bag", model_file, other)
    assert r.returncode == 0 and r.stderr.count("\n") == 1, r.stderr
    assert r.stderr.startswith(f"note: {other}'s camera is not the model's (fx {1.5 * k['fx']:.4g} px against the "
                               f"model's {k['fx']:.4g} px; baseline {1.9 * b * 1e3:.4g} mm against the model's "
                               f"{b * 1e3:.4g} mm)")
    assert (tmp_path / "other-sigma").is_dir()
