"""tests/tiny_runs.py's shortcut is sound: a tiny run with numba's compiler off writes what the compiled one does
(the same samples and counts; moments to 1e-12)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np

from tiny_runs import tiny_run_env
import pytest

pytestmark = pytest.mark.slow


RIG = [str(Path(sys.executable).parent / "rig")]
RUN = ["run", "--protocol", "perpendicular", "--camera", "fake:width=16,height=9,seed=1", "--stage", "fake:",
       "--stops", "0.5:1.5:0.5", "--frames", "5", "-q"]
#: what differs between two runs of the same plan whatever the arithmetic: clocks and the host
CLOCKS = ("time", "utc", "host_")


def _datasets(path: Path) -> dict[str, np.ndarray]:
    out = {}
    with h5py.File(path) as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


def test_a_tiny_run_without_the_compiler_writes_the_same_statistics(tmp_path):
    subprocess.run(RIG + RUN + ["-o", "compiled.h5"], cwd=tmp_path, check=True, capture_output=True, timeout=120)
    subprocess.run(RIG + RUN + ["-o", "interpreted.h5"], cwd=tmp_path, check=True, capture_output=True, timeout=120,
                   env=tiny_run_env())
    a, b = _datasets(tmp_path / "compiled.h5"), _datasets(tmp_path / "interpreted.h5")
    assert sorted(a) == sorted(b)
    compared = 0
    for name in a:
        if any(c in name for c in CLOCKS):
            continue
        assert a[name].dtype == b[name].dtype, name
        if a[name].dtype.kind == "f":  # compiled code fuses multiply-adds: the last bit may differ
            np.testing.assert_allclose(a[name], b[name], rtol=1e-12, atol=0, equal_nan=True, err_msg=name)
        else:  # depth samples, counts, labels: exactly
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
        compared += 1
    assert compared >= 10 and any("m2" in n or "mean" in n for n in a), sorted(a)
