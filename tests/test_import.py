"""rig import: folders of 16-bit PNG or .npy depth frames become recordings identical to live ones."""

from __future__ import annotations

import json
import shutil
import tracemalloc
from pathlib import Path

import h5py
import numpy as np
import pytest
from PIL import Image

from rig.analysis import fit_recording
from rig.cli import main as rig_main
from drivers.errors import FolderImportError
from drivers.folder import MANIFEST_NAME
from protocols.folder_import import import_folder
from protocols.recording import Recording
from rig.cli import import_main
from simrig import record_perpendicular

STOPS_M = [0.5, 1.0, 1.5, 2.0, 2.5]
FRAMES = 12
PATTERN = "(?P<m>[0-9.]+)m"


@pytest.fixture(scope="module")
def live(tmp_path_factory) -> Path:
    """A live run of the fake camera through the runner, raw frames kept (32x18 px, 0.05 mm depth unit)."""
    path = tmp_path_factory.mktemp("live") / "live.h5"
    record_perpendicular(path, seed=3, width=32, frames=FRAMES, stops_m=STOPS_M, keep_raw=True)
    return path


def manifest_for(live: Path, **extra) -> dict:
    with Recording(live) as rec:
        c = rec.calibration
    return {**dict(fx=c.fx, fy=c.fy, cx=c.cx, cy=c.cy, baseline_m=c.baseline_m, depth_unit_m=c.depth_scale_m,
                   projector_on=True, exposure_us=8500.0, gain=16.0), **extra}


def write_manifest(folder: Path, manifest: dict) -> None:
    lines, tables = [], []
    for k, v in manifest.items():
        if isinstance(v, dict):
            tables += [f"[{k}]"] + [f"{json.dumps(name)} = {d!r}" for name, d in v.items()]
        else:
            lines.append(f"{k} = {json.dumps(v) if isinstance(v, (str, bool)) else repr(v)}")
    (folder / MANIFEST_NAME).write_text("\n".join(lines + tables) + "\n")


def write_png(path: Path, image: np.ndarray) -> None:
    Image.fromarray(image).save(path)


def dump(live: Path, folder: Path, *, fmt: str = "png", by_name: bool = False, frames: int | None = None) -> Path:
    """Write the live run's raw frames as a folder to import: one sub-folder per stop."""
    folder.mkdir(parents=True, exist_ok=True)
    table = {}
    with h5py.File(live, "r") as f:
        for i, label in enumerate(sorted(f["stops"], key=lambda k: f["stops"][k].attrs["index"])):
            raw = f["stops"][label]["raw_depth"][: frames or None]
            name = label if by_name else f"stop_{chr(ord('a') + i)}"
            table[name] = float(f["stops"][label].attrs["commanded_position_m"])
            stop = folder / name
            stop.mkdir()
            if fmt == "npy":
                np.save(stop / "depth.npy", raw)
            else:
                for j, frame in enumerate(raw):
                    write_png(stop / f"frame_{j}.png", frame)
    extra = dict(stop_distance_from_name=PATTERN) if by_name else dict(stop_distance_m=table)
    write_manifest(folder, manifest_for(live, **extra))
    return folder


def stop_stats(path: Path):
    with Recording(path) as rec:
        return [(s.stats, s.series) for s in rec.stops()]


@pytest.mark.slow
@pytest.mark.parametrize("fmt,by_name", [("png", False), ("npy", False), ("png", True)])
def test_import_gives_the_live_run_statistics_and_fit(live, tmp_path, fmt, by_name):
    src = dump(live, tmp_path / "frames", fmt=fmt, by_name=by_name)
    events = []
    out = import_folder(src, tmp_path / "imported.h5", progress=events.append)
    assert out == tmp_path / "imported.h5" and sorted(p.name for p in tmp_path.iterdir()) == ["frames", "imported.h5"]

    for (a, sa), (b, sb) in zip(stop_stats(live), stop_stats(out), strict=True):
        assert np.array_equal(a.count, b.count)
        for name in ("mean_m", "m2_m2", "m3_m3", "m4_m4"):
            assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
        assert np.array_equal(sa.center_mean_m, sb.center_mean_m, equal_nan=True)
        assert np.array_equal(sa.valid_fraction, sb.valid_fraction)
    f_live, f_imp = fit_recording(live).fit, fit_recording(out).fit
    assert (f_imp.k, f_imp.lam) == (f_live.k, f_live.lam)  # the same implementation on the same statistics
    assert 2.5 < f_imp.lam < 3.5
    assert [e.frame for e in events if e.kind == "frame"][-1] == FRAMES
    assert sum(e.kind == "stop_done" for e in events) == len(STOPS_M)


def test_imported_file_carries_distances_and_provenance(live, tmp_path):
    src = dump(live, tmp_path / "frames", fmt="npy")
    out = import_folder(src, tmp_path / "imported.h5")
    with Recording(out) as rec:
        assert rec.protocol == "import"
        assert rec.protocol_params["stops_m"] == STOPS_M
        assert rec.attrs["import_source_folder"] == str(src.resolve())
        assert json.loads(rec.attrs["import_manifest"]) == json.loads(json.dumps(manifest_for(live, stop_distance_m={
            f"stop_{c}": z for c, z in zip("abcde", STOPS_M)})))
        stops = list(rec.stops())
        assert [s.label for s in stops] == ["stop_a", "stop_b", "stop_c", "stop_d", "stop_e"]
        assert [s.measured_position_m for s in stops] == STOPS_M
        assert all(json.loads(s.attrs["source_files"]) == ["depth.npy"] and s.n_frames == FRAMES for s in stops)
        assert stops[0].projector_on and stops[0].settings_read_back["exposure_us"] == 8500.0
        assert rec.calibration.depth_scale_m == manifest_for(live)["depth_unit_m"]


@pytest.mark.slow
def test_fit_compare_and_diagnose_work_on_an_import(live, tmp_path, capsys):
    out = import_folder(dump(live, tmp_path / "frames", fmt="npy"), tmp_path / "imported.h5")
    assert rig_main(["fit", str(out)]) == 0
    assert "import, projector on" in capsys.readouterr().out
    assert rig_main(["compare", str(out), "--models", "active,active+noise_floor", "--no-held-out"]) == 0
    assert "Lowest BIC" in capsys.readouterr().out
    assert rig_main(["diagnose", str(out), "--out", str(tmp_path / "diag")]) == 0
    assert (tmp_path / "diag").is_dir()


@pytest.mark.parametrize("kind", ["png", "npy"])
def test_ir_images_are_averaged_not_taken_for_depth(live, tmp_path, kind):
    """8-bit IR keeps its full scale, 255: the samples there are counted as clipped (data-format.md,
    `ir_saturated`). Before, the folder's frames were widened to uint16 first, and 255 was never clipped."""
    src = dump(live, tmp_path / "frames", frames=4)
    rng = np.random.default_rng(5)
    irs = {}
    for stop in sorted(p for p in src.iterdir() if p.is_dir()):
        irs[stop.name] = rng.integers(0, 256, (4, 18, 32), dtype=np.uint8)
        if kind == "npy":
            np.save(stop / "ir_stack.npy", irs[stop.name])
        for j, image in enumerate(irs[stop.name] if kind == "png" else []):
            write_png(stop / f"ir_{j}.png", image)  # 8-bit: fine for IR, refused for depth
    out = import_folder(src, tmp_path / "imported.h5")
    with Recording(out) as rec:
        for s in rec.stops():
            assert s.n_frames == 4
            # the mean of whole numbers, rounded once in float64 and then to float32 as the file keeps it
            assert np.allclose(s.ir_mean, irs[s.label].mean(axis=0), rtol=2.0**-24 + 2.0**-52, atol=0)
            assert len(json.loads(s.attrs["source_ir_files"])) == (4 if kind == "png" else 1)
            assert s.ir_full_scale_dn == 255
            assert np.array_equal(s.ir_saturated, (irs[s.label] == 255).sum(axis=0)) and s.ir_saturated.any()


def test_frames_stream_from_disk(live, tmp_path):
    """Memory does not grow with the number of frames: a 800-frame stack is never loaded whole."""
    src = tmp_path / "frames"
    (src / "1.0m").mkdir(parents=True)
    rng = np.random.default_rng(1)
    stack = (20000 + rng.integers(-40, 40, (800, 30, 40))).astype(np.uint16)  # 1 m at 0.05 mm
    np.save(src / "1.0m" / "stack.npy", stack)
    write_manifest(src, manifest_for(live, stop_distance_from_name=PATTERN, cx=19.5, cy=14.5))
    tracemalloc.start()
    try:
        out = import_folder(src, tmp_path / "imported.h5")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < stack.nbytes / 4, f"peak {peak} bytes for a {stack.nbytes}-byte stack"
    with Recording(out) as rec:
        assert rec.stop("1.0m").n_frames == 800


def test_overrides_replace_and_complete_the_manifest(live, tmp_path):
    src = dump(live, tmp_path / "frames", frames=3, by_name=True)
    m = manifest_for(live, stop_distance_from_name=PATTERN)
    depth_unit_m, fx = m.pop("depth_unit_m"), m.pop("fx")
    write_manifest(src, {**m, "projector_on": False})
    with pytest.raises(FolderImportError, match=r"lacks fx, depth_unit_m; .* --fx, --depth-unit-m"):
        import_folder(src, tmp_path / "a.h5")
    out = import_folder(src, tmp_path / "a.h5", {"fx": fx, "depth_unit_m": depth_unit_m, "projector_on": True, "gain": None})
    with Recording(out) as rec:
        assert rec.calibration.fx == fx and next(rec.stops()).projector_on
        assert json.loads(rec.attrs["import_overrides"]) == {"fx": fx, "depth_unit_m": depth_unit_m, "projector_on": True}


def test_import_main_prints_where_the_file_is(live, tmp_path, capsys):
    src = dump(live, tmp_path / "frames", frames=3, by_name=True)
    (src / MANIFEST_NAME).write_text((src / MANIFEST_NAME).read_text().replace("projector_on = true", "projector_on = false"))
    out = tmp_path / "sub" / "x.h5"
    assert import_main([str(src), "-o", str(out), "--projector", "on", "--gain", "32"]) == 0
    assert str(out) in capsys.readouterr().out
    with Recording(out) as rec:
        s = next(rec.stops())
        assert s.projector_on and s.settings_requested["gain"] == 32.0
    with pytest.raises(FolderImportError, match="already exists"):
        import_main([str(src), "-o", str(out)])



def test_a_bad_value_given_as_a_flag_is_named_as_typed(live, tmp_path):
    """issue 51: `rig import ... --baseline-m 50` was refused as "rig-import.toml: baseline_m = 50 m ...", a file the
    operator may never have written; a value from the command line is named as typed."""
    src = dump(live, tmp_path / "frames", frames=3, by_name=True)
    out = tmp_path / "x.h5"
    with pytest.raises(FolderImportError, match=r"^--baseline-m 50: 50 m is more than a stereo camera's 1 m; give it "
                                                r"in metres \(a D435's is 0.050: 0.05 if that was mm\)$"):
        import_main([str(src), "-o", str(out), "--baseline-m", "50"])
    with pytest.raises(FolderImportError, match=r"^--fx -5.0; it must be a positive number$"):
        import_main([str(src), "-o", str(out), "--fx", "-5"])
    assert not out.exists()

# -- bad input: one line naming the file, and no output file ----------------------------------

def _resize(src):
    write_png(src / "stop_b" / "frame_1.png", np.full((9, 16), 20000, np.uint16))
    return "stop_b/frame_1.png: 16x9 px, but"


def _eight_bit(src):
    write_png(src / "stop_c" / "frame_2.png", np.full((18, 32), 200, np.uint8))
    return "stop_c/frame_2.png: 8-bit grayscale PNG"


def _colour(src):
    write_png(src / "stop_a" / "frame_0.png", np.zeros((18, 32, 3), np.uint8))
    return "stop_a/frame_0.png: colour (RGB) PNG"


def _one_frame(src):
    for p in (src / "stop_d").glob("frame_*.png"):
        if p.name != "frame_0.png":
            p.unlink()
    return "stop_d: 1 depth frame(s) (frame_0.png alone); a stop needs at least 2 frames"


def _no_distance(src):
    shutil.copytree(src / "stop_e", src / "far")
    return "far: no distance for this stop; add it to [stop_distance_m]"


def _table_names_a_missing_folder(src):
    (src / "stop_e").rename(src / "far")
    return f"{MANIFEST_NAME}: stop_distance_m names 'stop_e', but"


def _distance_not_in_name(src):
    text = (src / MANIFEST_NAME).read_text().split("[stop_distance_m]")[0]
    (src / MANIFEST_NAME).write_text(f'stop_distance_from_name = "{PATTERN}"\n' + text)
    return "stop_a: the name does not give a distance"


def _wrong_unit(src):
    text = (src / MANIFEST_NAME).read_text()
    (src / MANIFEST_NAME).write_text("\n".join("depth_unit_m = 0.001" if line.startswith("depth_unit_m") else line
                                               for line in text.splitlines()))
    return ["stop_a/frame_0.png: mean range 10", " m with depth_unit_m = 0.001, but the stop is at 0.5 m; "
            "probably the wrong unit: depth_unit_m = 5e-05 (0.05 mm) would fit"]


def _baseline_in_mm(src):
    text = (src / MANIFEST_NAME).read_text()
    (src / MANIFEST_NAME).write_text("\n".join("baseline_m = 50" if line.startswith("baseline_m") else line
                                               for line in text.splitlines()))
    return "baseline_m = 50 m is more than a stereo camera's 1 m; give it in metres (a D435's is 0.050: 0.05 if"


def _negative_focal_length(src):
    text = (src / MANIFEST_NAME).read_text()
    (src / MANIFEST_NAME).write_text("\n".join("fx = -5" if line.startswith("fx") else line for line in text.splitlines()))
    return "fx = -5; it must be a positive number"


def _principal_point_outside(src):
    text = (src / MANIFEST_NAME).read_text()
    (src / MANIFEST_NAME).write_text("\n".join("cx = 423.5" if line.startswith("cx") else line for line in text.splitlines()))
    return "cx = 423.5 px lies outside the 32x18 px frames (stop_a/frame_0.png)"


def _bad_toml(src):
    (src / MANIFEST_NAME).write_text("fx = 425\nfy 425\n")
    return f"{MANIFEST_NAME}: not valid TOML (Expected '=' after a key"


def _garbage(src):
    (src / "stop_b" / "frame_2.png").write_bytes(b"not a png at all" * 10)
    return "stop_b/frame_2.png: not a readable PNG file"


def _truncated_last(src):
    """Damaged after the header: found only while streaming, after four stops were written."""
    p = src / "stop_e" / "frame_2.png"
    p.write_bytes(p.read_bytes()[:60])
    return "stop_e/frame_2.png: unreadable PNG"


def _bad_npy(src):
    (src / "stop_a" / "extra.npy").write_bytes(b"\x93NUMPY garbage")
    return "stop_a/extra.npy: unreadable .npy file"


def _float_npy(src):
    np.save(src / "stop_a" / "extra.npy", np.ones((18, 32)))
    return "stop_a/extra.npy: float64 values; .npy depth frames must hold 16-bit integer depth counts"


def _npy_out_of_range(src):
    np.save(src / "stop_e" / "z.npy", np.full((2, 18, 32), 70000, np.int32))
    return "stop_e/z.npy (frame 0): values outside 0-65535"


def _long_folder_name(src):
    """Issue 52: a 245-character stop folder name gave an OSError ENAMETOOLONG from the stop's journal file."""
    text = (src / MANIFEST_NAME).read_text().replace('"stop_c" = ', f'"{"c" * 245}" = ')
    (src / MANIFEST_NAME).write_text(text)
    (src / "stop_c").rename(src / ("c" * 245))
    return "has a name of 245 characters, too long for the file its data are kept in"


@pytest.mark.parametrize("spoil", [_resize, _eight_bit, _colour, _one_frame, _no_distance,
                                   _table_names_a_missing_folder, _distance_not_in_name, _wrong_unit,
                                   _baseline_in_mm, _negative_focal_length,
                                   _principal_point_outside, _bad_toml, _garbage, _truncated_last, _bad_npy, _float_npy, _npy_out_of_range,
                                   _long_folder_name])
def test_bad_input_stops_with_one_line_and_leaves_no_file(live, tmp_path, spoil):
    src = dump(live, tmp_path / "frames", frames=3)
    expected = spoil(src)
    expected = [expected] if isinstance(expected, str) else expected
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    with pytest.raises(FolderImportError) as e:
        import_folder(src, out_dir / "x.h5")
    message = str(e.value)
    assert "\n" not in message
    assert all(part in message.replace(str(src) + "/", "") for part in expected), message
    assert str(src) in message  # the full path to the file
    assert list(out_dir.iterdir()) == []


def test_a_wrong_distance_is_not_blamed_on_the_unit(live, tmp_path):
    src = dump(live, tmp_path / "frames", frames=3, by_name=True)
    (src / "1.000m").rename(src / "3.000m")  # the 1 m frames now claim 3 m: 0.15 mm a count, no common unit
    with pytest.raises(FolderImportError, match="no common unit; check depth_unit_m and the stop's distance"):
        import_folder(src, tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()


def test_damage_found_while_streaming_removes_the_partial_file(live, tmp_path):
    src = dump(live, tmp_path / "frames", frames=3)
    _truncated_last(src)
    events = []
    with pytest.raises(FolderImportError, match="stop_e/frame_2.png: unreadable PNG"):
        import_folder(src, tmp_path / "out" / "x.h5", progress=events.append)
    assert sum(e.kind == "stop_done" for e in events) == 4  # four stops were written before the damage was found
    assert list((tmp_path / "out").iterdir()) == []
