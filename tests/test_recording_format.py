"""docs/data-format.md is enough to write a valid recording with h5py alone."""

import re
from pathlib import Path

import h5py
import numpy as np
import pytest

from rig.analysis import fit_recording
from protocols.recording import Recording, RecordingError

DOC = Path(__file__).resolve().parents[1] / "docs" / "data-format.md"


def write_by_hand(path: Path, k=0.002, lam=3.0, seed=0):
    """Follow the doc's recipe: frames in mm -> count, mean_m, m2_m2 per stop, calibration attrs."""
    rng = np.random.default_rng(seed)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "rig.recording"
        f.attrs["format_version"] = 1
        cam = f.create_group("camera")
        cam.attrs.update(fx=425.0, fy=425.0, cx=15.5, cy=8.5, baseline_m=0.05, depth_scale_m=0.001)
        stops = f.create_group("stops")
        for i, z_true in enumerate([1.0, 1.5, 2.0, 2.5, 3.0]):
            frames = np.rint(rng.normal(z_true * 1000, 1000 * k * z_true**lam, (60, 18, 32))).astype(np.uint16)
            frames[rng.random(frames.shape) < 0.05] = 0
            z = np.where(frames > 0, frames * 0.001, np.nan)
            count = np.sum(frames > 0, axis=0)
            mean = np.nanmean(z, axis=0)
            g = stops.create_group(f"{z_true:.3f}m")
            g.attrs["index"] = i
            g["count"] = count.astype(np.uint32)
            g["mean_m"] = mean
            g["m2_m2"] = np.nansum((z - mean) ** 2, axis=0)


def test_the_documented_example_names_the_required_fields():
    text = DOC.read_text()
    for name in ("count", "mean_m", "m2_m2", "fx", "fy", "cx", "cy", "baseline_m", "depth_scale_m"):
        assert re.search(rf"`{name}`[^\n]*\| yes \|", text), f"{name} is not marked required in the doc"


def test_hand_written_file_loads_and_fits(tmp_path):
    path = tmp_path / "mine.h5"
    write_by_hand(path)
    r = fit_recording(path)
    assert r.fit.n_samples > 0.9 * 5 * 60 * 18 * 32
    assert abs(r.fit.lam - 3.0) < 3 * r.fit.se_lam
    assert abs(r.fit.k - 0.002) < 3 * r.fit.se_k
    assert len(r.measured.z_m) == 5


@pytest.mark.parametrize("damage,message", [
    (lambda f: f["camera"].attrs.__delitem__("baseline_m"), r"/camera lacks attribute\(s\) \['baseline_m'\]"),
    (lambda f: f.attrs.__setitem__("format", "something-else"), r"is not a rig recording"),
    (lambda f: f.attrs.__setitem__("format_version", 9), r"newer than this rig reads"),
])
def test_invalid_files_give_one_line_errors(tmp_path, damage, message):
    path = tmp_path / "bad.h5"
    write_by_hand(path)
    with h5py.File(path, "a") as f:
        damage(f)
    with pytest.raises(RecordingError, match=message):
        fit_recording(path)


def test_a_stop_lacking_a_dataset_is_named_and_left_out_the_others_fitted(tmp_path):
    path = tmp_path / "bad.h5"
    write_by_hand(path)
    with h5py.File(path, "a") as f:
        del f["stops"]["1.000m"]["m2_m2"]
    r = fit_recording(path)
    assert any(re.search(r"stop '1.000m' \(left out of the fit\): stop '1.000m' lacks dataset\(s\) \['m2_m2'\]", n)
               for n in r.notes), r.notes
    assert r.labels == ["1.500m", "2.000m", "2.500m", "3.000m"] and abs(r.fit.lam - 3.0) < 4 * r.fit.se_lam


def test_not_hdf5_and_missing_file(tmp_path):
    (tmp_path / "x.h5").write_text("hello")
    with pytest.raises(RecordingError, match="is not an HDF5 file"):
        Recording(tmp_path / "x.h5")
    with pytest.raises(RecordingError, match="does not exist"):
        Recording(tmp_path / "nope.h5")


@pytest.mark.parametrize("scale,where,error", [
    (1000.0, slice(None), r"stop '1.500m' mean_m has a median of 1[45]\d\d\.?\d*, not a range in metres"),
    (1e-3, slice(None), r"stop '1.500m' mean_m has a median of 0\.001[45]\d*, not a range in metres"),
    (1000.0, (slice(0, 2), slice(0, 3)), None),  # six pixels out of the plausible range: the median is still a range
    (1e-3, (slice(0, 2), slice(0, 3)), None),
])
def test_a_stop_whose_median_range_is_not_in_metres_is_refused(tmp_path, scale, where, error):
    path = tmp_path / "mine.h5"
    write_by_hand(path)
    with h5py.File(path, "a") as f:
        mean = f["stops"]["1.500m"]["mean_m"]
        values = mean[()]
        values[where] *= scale
        mean[...] = values
    with Recording(path) as rec:
        if error is None:
            assert rec.stop("1.500m").stats.mean_m[0, 0] > 100 or rec.stop("1.500m").stats.mean_m[0, 0] < 0.01
        else:
            with pytest.raises(RecordingError, match=error):
                rec.stop("1.500m")


def _replace(g, name, change):
    values = change(g[name][()])
    del g[name]
    g[name] = values


@pytest.mark.parametrize("name,change,message", [
    ("count", lambda a: a.astype(float) + 0.5, r"count holds values that are not whole numbers of samples"),
    ("count", lambda a: a.astype(np.int32) * np.where(np.arange(a.size).reshape(a.shape) == 7, -1, 1),
     r"count holds values that are not whole numbers"),
    ("mean_m", lambda a: np.where(np.arange(a.size).reshape(a.shape) % 97 == 3, np.nan, a), r"mean_m is not finite at 6 pixels"),
    ("mean_m", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 5, np.inf, a), r"mean_m is not finite at 1 pixels"),
    ("m2_m2", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 9, -1e-9, a), r"m2_m2 is negative or not finite at 1 pixels"),
    ("m2_m2", lambda a: np.where(np.arange(a.size).reshape(a.shape) < 2, np.nan, a), r"m2_m2 is negative or not finite at 2 pixels"),
    ("m4_m4", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 4, np.inf, a), r"m4_m4 is negative or not finite at 1 pixels"),
])
def test_a_stops_impossible_values_are_named_with_how_many(tmp_path, name, change, message):
    """check_stop's refusals of a field's values (docs/reliability.md), each with the field and how many pixels."""
    path = tmp_path / "bad.h5"
    write_by_hand(path)
    with h5py.File(path, "a") as f:
        g = f["stops"]["1.500m"]
        if "m4_m4" not in g:
            g["m4_m4"] = 3 * g["m2_m2"][()] ** 2 / np.maximum(g["count"][()], 1)
        _replace(g, name, change)
    with Recording(path) as rec:
        with pytest.raises(RecordingError, match=message):
            rec.stop("1.500m")
        rec.stop("2.000m")  # the others read


def test_a_stop_without_fourth_moments_reads(tmp_path):
    path = tmp_path / "old.h5"
    write_by_hand(path)
    with h5py.File(path, "a") as f:
        f["stops"]["1.500m"]["m4_m4"] = np.full(f["stops"]["1.500m"]["count"].shape, np.nan)  # written, but empty
    with Recording(path) as rec:
        assert np.isnan(rec.stop("1.500m").stats.m4_m4).all()
