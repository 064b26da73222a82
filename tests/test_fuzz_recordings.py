"""Fuzzing the recording reader with hypothesis: damaged bytes, wrong attributes and wrong statistics give
a one-line error or a correct result; never a traceback, never a silently wrong fit.

"Correct" is judged against the undamaged file's fit: a run of `rig fit --json` that exits 0 must give
the same k and lambda, or carry a note saying what is missing (a deleted stop)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cli_in_process import rig_in_process
from simrig import record_perpendicular

pytestmark = pytest.mark.slow


#: examples per property in the test suite; RIG_FUZZ_EXAMPLES=400 for the figures in docs/reliability.md
FUZZ = settings(max_examples=int(os.environ.get("RIG_FUZZ_EXAMPLES", "60")), deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> tuple[Path, dict]:
    path = tmp_path_factory.mktemp("fuzz") / "good.h5"
    record_perpendicular(path, seed=4, width=24, frames=12)
    return path, fit_json(path)[1]["fits"][0]["values"]


def fit_json(path: Path) -> tuple[int, dict | None, str]:
    r = rig_in_process("fit", path, "--json")
    return r.returncode, (json.loads(r.stdout) if r.returncode in (0, 3) else None), r.stderr


def judge(path: Path, truth: dict) -> None:
    code, fit, err = fit_json(path)
    if code in (0, 3):  # 3: lambda not determined (stops lost), said in the output
        assert fit is not None
        if fit["notes"] or code == 3:
            return  # said what is wrong with the recording itself
        values = fit["fits"][0]["values"]
        assert values["lambda"] == pytest.approx(truth["lambda"], abs=1e-9) and \
            values["k"] == pytest.approx(truth["k"], rel=1e-9), (fit, truth)
    else:
        assert code == 2, (code, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("rig: error: "), err


@FUZZ
@given(flips=st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(1, 255)), min_size=1, max_size=8))
def test_flipped_bytes(good, tmp_path, flips):
    path, truth = good
    bad = tmp_path / "bad.h5"
    data = bytearray(path.read_bytes())
    for where, xor in flips:
        data[int(where * len(data))] ^= xor
    bad.write_bytes(bytes(data))
    judge(bad, truth)


def _stops(f: h5py.File) -> list[str]:
    return sorted(f["stops"], key=lambda k: f["stops"][k].attrs["index"])


MUTATIONS = ["nan_m2", "negative_m2", "mean_in_mm", "delete_stop", "string_attr", "zero_depth_scale", "nan_fx",
             "shape_mismatch", "count_too_large", "string_root_params", "empty_stops", "drop_dataset", "inf_mean"]


@FUZZ
@given(kind=st.sampled_from(MUTATIONS), stop=st.integers(0, 10), where=st.floats(0.0, 1.0))
def test_wrong_statistics_and_attributes(good, tmp_path, kind, stop, where):
    path, truth = good
    bad = tmp_path / "bad.h5"
    shutil.copyfile(path, bad)
    with h5py.File(bad, "a") as f:
        label = _stops(f)[stop]
        g = f["stops"][label]

        def replace(name: str, value: np.ndarray) -> None:
            del g[name]
            g.create_dataset(name, data=value)

        m2 = g["m2_m2"][()]
        n = m2.size
        idx = np.unravel_index(int(where * (n - 1)), m2.shape)
        if kind == "nan_m2":
            m2[idx] = np.nan
            replace("m2_m2", m2)
        elif kind == "negative_m2":
            m2[idx] = -abs(m2[idx]) - 1e-9
            replace("m2_m2", m2)
        elif kind == "mean_in_mm":
            replace("mean_m", g["mean_m"][()] * 1000.0)
        elif kind == "inf_mean":
            mean = g["mean_m"][()]
            mean[idx] = np.inf
            replace("mean_m", mean)
        elif kind == "delete_stop":
            del f["stops"][label]
        elif kind == "string_attr":
            g.attrs["index" if where < 0.5 else "n_frames"] = "three"
        elif kind == "zero_depth_scale":
            f["camera"].attrs["depth_scale_m"] = 0.0
        elif kind == "nan_fx":
            f["camera"].attrs["fx"] = np.nan
        elif kind == "shape_mismatch":
            replace("m2_m2", m2[:, :-1])
        elif kind == "count_too_large":
            c = g["count"][()]
            c[idx] = 10_000
            replace("count", c)
        elif kind == "string_root_params":
            f.attrs["protocol_params"] = "{not json"
        elif kind == "empty_stops":
            for k in list(f["stops"]):
                del f["stops"][k]
        elif kind == "drop_dataset":
            del g["count" if where < 0.5 else "mean_m"]
    judge(bad, truth)


def test_a_deleted_stop_is_said(good, tmp_path):
    path, _ = good
    bad = tmp_path / "ten.h5"
    shutil.copyfile(path, bad)
    with h5py.File(bad, "a") as f:
        del f["stops"][_stops(f)[4]]
    code, fit, _ = fit_json(bad)
    assert code == 0 and any("10 of 11 planned stops" in n for n in fit["notes"]), fit


def test_a_flipped_byte_in_an_attributes_header_is_one_line_not_a_crash(good, tmp_path):
    """HDF5 1.14 segfaulted reading a stop's attribute whose datatype a flipped byte had changed (the class bits of
    `settings_read_back`, a variable-length string: `rig fit` exited -11). rig writes its files with checksummed
    object headers now (protocols.recording.HDF5_LIBVER): each byte of that attribute's message flipped in turn is
    one line or the undamaged fit. In-process: a crash ends the worker, which fails the test."""
    path, truth = good
    data = path.read_bytes()
    at = data.find(b"settings_read_back")
    assert at > 0 and b"OHDR" in data  # version 2 object headers, the ones with checksums
    for offset in range(at + len("settings_read_back"), at + len("settings_read_back") + 24):
        bad = bytearray(data)
        bad[offset] ^= 0x49  # 0x01 -> 0x48 at the string's class bits was the crash
        (tmp_path / "bad.h5").write_bytes(bytes(bad))
        judge(tmp_path / "bad.h5", truth)
