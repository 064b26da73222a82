"""Every depth stream a lab records comes in right: several cameras in one bag, 32FC1 metres, image_transport's
compressedDepth (PNG and RVL), and depth aligned to a colour camera.

The bags are written with rosbags' own writer and typestore (tests/ros_bags.py `write_cameras`), in the topic layouts
of realsense-ros 2.x and 4.x and depthai-ros (drivers/bag/camera_topics.py cites them). compressedDepth payloads are
made by independent encoders: PNGs by OpenCV's cv2.imencode, which compressed_depth_image_transport itself calls
(codec.cpp lines 323 and 391), and RVL by a test-only encoder written from Wilson's paper (tests/rvl_encoder.py);
rig's RVL decoder is also checked against a stream worked out by hand (tests/test_bag_rvl.py).
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


# --- 32FC1: depth in metres ---------------------------------------------------------------------------------------

def _stops(folder: Path, per_stop: dict[float, np.ndarray], encoding: str) -> Path:
    """A folder of bags, one per stop, named by distance ('1.500m')."""
    folder.mkdir()
    for z, frames in per_stop.items():
        write_cameras(folder / f"{z:.3f}m", [Camera(frames, fx=400.0, baseline_m=0.05, encoding=encoding)], "mcap")
    return folder


STOPS = ("--projector", "on", "--stop-distance-from-name", "(?P<m>[0-9.]+)m")


def _metres(counts_mm: np.ndarray) -> np.ndarray:
    """16UC1 millimetres as depth_image_proc publishes them in 32FC1: count * 0.001f in float32; no depth as NaN,
    and here as 0, +inf and -inf too (REP 118)."""
    z = counts_mm.astype(np.float32) * np.float32(0.001)
    holes = np.flatnonzero(counts_mm == 0)
    z.flat[holes] = np.resize(np.array([np.nan, 0.0, np.inf, -np.inf], np.float32), holes.size)
    return z


def test_32fc1_on_a_millimetre_grid_gives_the_16uc1_statistics_exactly(tmp_path):
    counts = {z: _counts(6, 1e3 * z, 1.5 * z * z, seed=i) for i, z in enumerate((0.75, 1.5, 2.25))}
    mm = _stops(tmp_path / "mm", counts, "16UC1")
    m = _stops(tmp_path / "m", {z: _metres(c) for z, c in counts.items()}, "32FC1")
    with _import(mm, tmp_path / "mm.h5", *STOPS) as a, _import(m, tmp_path / "m.h5", *STOPS) as b:
        assert b.calibration.depth_scale_m == 1e-3  # found on the data's own grid: the counts hold them exactly
        extra = _camera_extra(tmp_path / "m.h5")
        assert extra["metric_depth"]["exact"] and "every value on a grid of 1 mm" in extra["depth_unit_source"]
        _same_stats(a, b)
    fa, fb = fit_recording(tmp_path / "mm.h5").fit, fit_recording(tmp_path / "m.h5").fit
    assert (fb.k, fb.lam) == (fa.k, fa.lam)  # the same implementation on the same statistics


def test_32fc1_of_continuous_depth_fits_as_its_16uc1_within_the_standard_error(tmp_path):
    """A simulator's continuous depth (sigma = k z^lambda, 2.2-20 mm): rig rounds it to the finest 1-2-5 unit that
    holds the farthest depth in 16 bits (0.05 mm here), the 16UC1 copy of the same frames is rounded to 1 mm. Both
    fits give the same k and lambda within the estimator's standard error (the same samples: they differ by the
    rounding only), and the 32FC1 fit finds the truth within 2 standard errors (fixed seed). (With sigma near 1 mm the
    16UC1 copy's rounding, q^2/12 against sigma^2, moves its own fit by more than that; the 32FC1 fit does not move.)"""
    rng = np.random.default_rng(8)
    k_true, lam_true = 4e-3, 2.0
    metres = {z: (z + rng.normal(0, k_true * z**lam_true, (30, *SHAPE))).astype(np.float32) for z in (0.75, 1.5, 2.25)}
    m = _stops(tmp_path / "m", metres, "32FC1")
    mm = _stops(tmp_path / "mm", {z: np.rint(v.astype(np.float64) * 1e3).astype(np.uint16) for z, v in metres.items()}, "16UC1")
    with _import(m, tmp_path / "m.h5", *STOPS) as rec:
        # the farthest sample, ~2.25 m + 4 sigma = 2.33 m: 2.33 / 65535 = 3.6e-5 m, so 5e-5 m of the 1-2-5 series
        assert rec.calibration.depth_scale_m == 5e-5
        assert "rounded to counts of 0.05 mm" in _camera_extra(tmp_path / "m.h5")["depth_unit_source"]
    _import(mm, tmp_path / "mm.h5", *STOPS).close()
    fm, fmm = fit_recording(tmp_path / "m.h5").fit, fit_recording(tmp_path / "mm.h5").fit
    assert abs(fm.lam - fmm.lam) <= fmm.se_lam, (fm.lam, fmm.lam, fmm.se_lam)
    assert abs(fm.k - fmm.k) <= fmm.se_k, (fm.k, fmm.k, fmm.se_k)
    assert abs(fm.lam - lam_true) <= 2 * fm.se_lam and abs(fm.k - k_true) <= 2 * fm.se_k, (fm.k, fm.lam)


@pytest.mark.numeric
def test_32fc1_takes_a_given_depth_unit(tmp_path):
    """--depth-unit-m sets the counts' unit for depth in metres (0.1 mm here, the data being on a 1 mm grid: every
    count 10 times the 16UC1 one), and the recording says so."""
    counts = _counts()
    mm = write_cameras(tmp_path / "mm", [Camera(counts)])
    m = write_cameras(tmp_path / "m", [Camera(_metres(counts), encoding="32FC1")])
    with _import(mm, tmp_path / "mm.h5", *ARGS) as a, _import(m, tmp_path / "m.h5", *ARGS, "--depth-unit-m", "1e-4") as b:
        assert b.calibration.depth_scale_m == 1e-4
        sa, sb = next(a.stops()).stats, next(b.stops()).stats
        assert np.array_equal(sa.count, sb.count)
        # the mean is (shift + S1 / n) * unit: a quotient, a sum and a product, 3 u each way; 10x the counts, same metres
        valid = sa.count > 0
        assert np.allclose(sb.mean_m[valid], sa.mean_m[valid], rtol=6 * np.finfo(float).eps / 2, atol=0)
    assert _camera_extra(tmp_path / "m.h5")["depth_unit_source"] == "32FC1 metres rounded to counts of 0.0001 m (given)"


# --- image_transport's compressedDepth ----------------------------------------------------------------------------

#: compressed_depth_image_transport's ConfigHeader (compression_common.h lines 44-57): compressionFormat INV_DEPTH = 0
#: and depthParam[2], which the encoder leaves unset for 16-bit images (codec.cpp lines 251-252, 356-416)
def _config(a: float = 0.0, b: float = 0.0) -> bytes:
    return struct.pack("<iff", 0, a, b)


def _png(frame: np.ndarray) -> tuple[str, bytes]:
    """16UC1 compressedDepth png as codec.cpp line 391 makes it: cv::imencode(".png", image, {PNG_COMPRESSION, 1})."""
    import cv2  # OpenCV (the test extra), imported where used: 0.1 s a worker
    ok, png = cv2.imencode(".png", np.ascontiguousarray(frame, np.uint16), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    assert ok
    return "16UC1; compressedDepth png", _config() + png.tobytes()


def _rvl(frame: np.ndarray) -> tuple[str, bytes]:
    """16UC1 compressedDepth rvl (codec.cpp lines 403-414): width and height as uint32, then the RVL stream."""
    h, w = frame.shape
    return "16UC1; compressedDepth rvl", _config() + struct.pack("<II", w, h) + encode_rvl(frame)


@pytest.mark.parametrize("how", ["png", "rvl", "big-endian"])
def test_compressed_and_big_endian_depth_give_the_raw_frames_statistics(tmp_path, how):
    frames = _counts(holes=True)
    raw = write_cameras(tmp_path / "raw", [Camera(frames)])
    cam = Camera(frames, bigendian=True) if how == "big-endian" else Camera(frames, compress={"png": _png, "rvl": _rvl}[how])
    sent = write_cameras(tmp_path / "sent", [cam])
    with _import(raw, tmp_path / "raw.h5", *ARGS) as a, _import(sent, tmp_path / "sent.h5", *ARGS) as b:
        _same_stats(a, b)
        assert b.calibration.depth_scale_m == 1e-3 and next(b.stops()).attrs["source_topic"] == cam.depth_topic


@pytest.mark.numeric
def test_compressed_depth_of_32fc1_reads_back_as_the_codec_defines(tmp_path):
    """32FC1 compressedDepth png with the publisher's defaults (depth_max 10 m, depth_quantization 100): the test
    quantises as codec.cpp lines 291-312 do (float arithmetic, truncation to unsigned short; NaN and z >= depth_max
    to 0), OpenCV writes the PNG; rig must read z = A / (v - B) (lines 176-183), 0 as no depth, and record counts of
    the finest 1-2-5 unit holding the farthest depth. Both sides do the same two IEEE single operations (a
    subtraction and a correctly rounded division), so the floats, and the counts rounded from them, are equal."""
    import cv2

    z0, z_max = np.float32(100.0), np.float32(10.0)
    a = z0 * (z0 + np.float32(1.0))
    b = np.float32(1.0) - a / z_max
    metres = (_counts(holes=True) * 1e-3 + np.random.default_rng(4).uniform(0, 1e-3, (6, *SHAPE))).astype(np.float32)
    metres[_counts(holes=True) == 0] = np.nan
    metres[:, 1, 1] = 12.0  # beyond depth_max: sent as 0

    def send(z: np.ndarray) -> tuple[str, bytes]:
        with np.errstate(invalid="ignore"):
            v = np.where(z < z_max, a / z + b, 0).astype(np.uint16)  # float -> unsigned short truncates
        ok, png = cv2.imencode(".png", v, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        return "32FC1; compressedDepth png", _config(float(a), float(b)) + png.tobytes()

    bag = write_cameras(tmp_path / "inv", [Camera(metres, compress=send)])
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.where(metres < z_max, a / metres + b, 0).astype(np.uint16)
        back = np.where(v > 0, a / (v.astype(np.float32) - b), np.nan).astype(np.float32)
    unit_m = min(q for q in (1e-4, 5e-5, 2e-5, 1e-5) if np.nanmax(back) / q <= 65535)
    counts = np.where(np.isfinite(back), np.rint(back.astype(np.float64) / unit_m), 0).astype(np.uint16)
    acc = PixelMomentAccumulator(SHAPE, unit_m)
    for frame in counts:
        acc.add(frame)
    want = acc.result()
    with _import(bag, tmp_path / "inv.h5", *ARGS) as rec:
        assert rec.calibration.depth_scale_m == unit_m
        got = next(rec.stops()).stats
        assert np.array_equal(got.count, want.count) and np.array_equal(got.m2_m2, want.m2_m2)
        assert np.array_equal(got.mean_m, want.mean_m, equal_nan=True)
    extra = _camera_extra(tmp_path / "inv.h5")["compressed_depth"]
    assert (extra["depth_quant_a"], extra["depth_quant_b"]) == (float(a), float(b))


@pytest.mark.parametrize("transport, form", [("compressed", "16UC1; png compressed "), ("zstd", "zstd"),
                                             ("compressedDepth", "16UC1; compressedDepth jpeg")])
def test_a_compressed_format_rig_does_not_read_is_named_in_one_line(tmp_path, transport, form):
    bag = write_cameras(tmp_path / "c", [Camera(_counts(), compress=lambda f: (form, b"\0" * 64), transport=transport)])
    message = _refused(bag, tmp_path / "c.h5", *ARGS)
    assert f"is a CompressedImage in format {form!r}, which rig does not read" in message, message


# --- depth aligned to a colour camera ---------------------------------------------------------------------------

ALIGNED_NOTE = "resampled into another camera's pixels, so its noise is not the sensor's own"


def test_aligned_depth_is_imported_with_a_note_in_the_output_and_the_recording(tmp_path, capsys):
    cam = Camera(_counts(), depth="aligned_depth_to_color/image_raw", info="aligned_depth_to_color/camera_info",
                 frame_id="camera_color_optical_frame")
    bag = write_cameras(tmp_path / "aligned", [cam])
    with _import(bag, tmp_path / "a.h5", *ARGS) as rec:
        said = capsys.readouterr()
        progress = next(x for x in said.err.splitlines() if x.startswith("importing"))
        (done,) = said.out.splitlines()
        for line in (progress, done):  # the progress line and the command's one line of output
            assert "; note: aligned depth (the topic /camera/aligned_depth_to_color/image_raw is aligned depth): " \
                   + ALIGNED_NOTE in line, line
        assert any(n.startswith("imported: aligned depth") and ALIGNED_NOTE in n for n in rec.notes()), rec.notes()
    assert ALIGNED_NOTE in _camera_extra(tmp_path / "a.h5")["aligned_depth"]


@pytest.mark.parametrize("frame_id, aligned", [("oak_rgb_camera_optical_frame", True), ("oak_right_camera_optical_frame", False)])
def test_depth_in_a_colour_camera_s_frame_is_known_for_aligned(tmp_path, frame_id, aligned):
    """depthai-ros aligns its stereo depth to the RGB camera on the device; only the header's frame says so."""
    bag = write_cameras(tmp_path / "oak", [Camera(_counts(), ns="/oak", depth="stereo/image_raw", info="stereo/camera_info",
                                                  right_info="left/camera_info", frame_id=frame_id)], "db3")
    facts = read_facts(bag)
    assert facts.topic == "/oak/stereo/image_raw" and bool(facts.aligned) == aligned, facts.aligned
    assert (f"its frame {frame_id} is a colour camera's" in facts.aligned) == aligned
