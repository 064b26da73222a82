"""A stop that contradicts itself or the rest of its recording is left out of the fit, with a note naming the stop
and the field; never fitted silently (issue 28: one stop's m2_m2 zeroed moved lambda by 1,030 standard errors, one
stop's mean_m x10 gave lambda 0.8, both without a word).

Each damage is made with h5py on a real recording; the fit must then equal the fit of the same file with that stop
deleted, to the last bit: the left-out stop's rows never enter it, so the same implementation fits the same rows.
"""

from __future__ import annotations

import shutil

import h5py
import numpy as np
import pytest

from rig.analysis import fit_recording
from simrig import record_perpendicular

STOPS_M = [0.75, 1.25, 1.75, 2.25, 2.75]


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "run.h5"
    record_perpendicular(path, seed=11, width=32, frames=30, stops_m=STOPS_M)
    return path


def _damaged(rec, tmp_path, label, how):
    path = tmp_path / "damaged.h5"
    shutil.copy(rec, path)
    with h5py.File(path, "a") as f:
        g = f["stops"][label]
        if how == "zero_variance":
            g["m2_m2"][...] = 0.0
        elif how == "range_x10":
            g["mean_m"][...] = g["mean_m"][()] * 10
        elif how == "count":
            g["frames"]["valid_fraction"][...] = g["frames"]["valid_fraction"][()] * 0.5
    return path


def _without(rec, tmp_path, label):
    path = tmp_path / "without.h5"
    shutil.copy(rec, path)
    with h5py.File(path, "a") as f:
        del f["stops"][label]
    return path


@pytest.mark.parametrize("how, field", [("zero_variance", "m2_m2 is 0 at 100 % of its pixels"),
                                        ("range_x10", "mean_m is 17.5 m at the image centre, but the stop was at 1.750 m"),
                                        ("count", "count sums to")])
def test_a_stop_that_contradicts_the_rest_is_left_out_with_a_note(rec, tmp_path, how, field):
    label = "1.750m"
    fit = fit_recording(_damaged(rec, tmp_path, label, how))
    (note,) = [n for n in fit.notes if n.startswith(f"skipped stop '{label}' (left out of the fit)")]
    assert field in note, note
    assert label not in fit.labels
    want = fit_recording(_without(rec, tmp_path, label)).fit
    assert (fit.fit.lam, fit.fit.k, fit.fit.se_lam, fit.fit.se_k) == (want.lam, want.k, want.se_lam, want.se_k)
    whole = fit_recording(rec).fit
    assert abs(fit.fit.lam - whole.lam) < 5 * np.hypot(whole.se_lam, fit.fit.se_lam)  # the rest still tell lambda


def test_a_sound_recording_loses_no_stop(rec):
    fit = fit_recording(rec)
    assert fit.labels == [f"{z:.3f}m" for z in STOPS_M] and not any("left out" in n for n in fit.notes)


def test_a_stop_damaged_alike_everywhere_is_one_line(rec, tmp_path):
    path = tmp_path / "all.h5"
    shutil.copy(rec, path)
    with h5py.File(path, "a") as f:
        for label in f["stops"]:
            f["stops"][label]["mean_m"][...] = f["stops"][label]["mean_m"][()] * 10
    with pytest.raises(ValueError, match=r"no stop can be fitted; stop '0.750m': mean_m is 7.5 m at the image centre"):
        fit_recording(path)


def test_a_stop_that_cannot_be_read_is_left_out_and_the_others_fitted(rec, tmp_path):
    """One flipped byte in a stop's compressed data fails its checksum (HDF5's Fletcher-32 filter): that stop is
    named and left out, the others fitted, as docs/reliability.md promises."""
    path = tmp_path / "flipped.h5"
    shutil.copy(rec, path)
    with h5py.File(path, "r") as f:
        ds = f["stops"]["1.250m"]["m2_m2"]
        assert ds.fletcher32, "the writer checksums each dataset"
        offset = ds.id.get_offset() if ds.chunks is None else ds.id.get_chunk_info(0).byte_offset
    data = bytearray(path.read_bytes())
    data[offset + 20] ^= 0xFF
    path.write_bytes(bytes(data))
    fit = fit_recording(path)
    (note,) = [n for n in fit.notes if "left out of the fit" in n]
    assert note.startswith("skipped stop '1.250m' (left out of the fit): stop '1.250m' cannot be read ("), note
    assert "1.250m" not in fit.labels and len(fit.labels) == len(STOPS_M) - 1
    want = fit_recording(_without(rec, tmp_path, "1.250m")).fit
    assert (fit.fit.lam, fit.fit.k) == (want.lam, want.k)


def test_resume_records_a_damaged_stop_again(tmp_path):
    """The note's advice works: --resume records the damaged stop anew and the file is whole again."""
    from simrig import record_perpendicular

    path = tmp_path / "run.h5"
    record_perpendicular(path, seed=12, width=24, frames=20, stops_m=STOPS_M[:3])
    _flip_a_byte_in(path, "1.250m")
    assert any("left out of the fit" in n for n in fit_recording(path).notes)
    record_perpendicular(path, seed=12, width=24, frames=20, stops_m=STOPS_M[:3], resume=True)
    fit = fit_recording(path)
    assert fit.labels == ["0.750m", "1.250m", "1.750m"] and not any("left out" in n for n in fit.notes), fit.notes


def _flip_a_byte_in(path, label):
    with h5py.File(path, "r") as f:
        ds = f["stops"][label]["m2_m2"]
        offset = ds.id.get_offset() if ds.chunks is None else ds.id.get_chunk_info(0).byte_offset
    data = bytearray(path.read_bytes())
    data[offset + 20] ^= 0xFF
    path.write_bytes(bytes(data))
