"""tests/tiny_runs.py's shortcut is sound: a tiny run with numba's compiler off writes what the compiled one does.

The same source runs both ways, the same IEEE operations on the same values, so the same samples, counts and
moments to the last bit, with one exception: a whole power. numba raises to it by products (a^3 = a a a, a^4 = (a^2)^2,
within 2 u and 3 u), numpy and Python by pow (within 1 ulp, 2 u), so the accumulator's third and fourth moments
(protocols/stats.py, `_central`: 2 n a^3 and 3 n a^4, a the mean less the first sample, and the depth unit's cube and
fourth power) may differ in their last bits, by at most 8 u n |a s|^3 + 6 u |M3| and 15 u n (a s)^4 + 7 u |M4|
(s the depth unit, and the final sum's rounding). |a s| <= sqrt(M2): the first sample is one of the pixel's, and no
sample lies further than sqrt(M2) from their mean. (The fake camera's samples are integers: a last-bit difference of
its exp or log could change one only within an ulp of a half-unit, about 1e-8 of such runs.)"""

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
U = np.finfo(np.float64).eps / 2

#: what differs between two runs of the same plan whatever the arithmetic: clocks and the host
CLOCKS = ("time", "utc", "host_")


def _datasets(path: Path) -> dict[str, np.ndarray]:
    out = {}
    with h5py.File(path) as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


@pytest.mark.numeric
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
        if name.endswith(("m3_m3", "m4_m4")):  # a whole power, by products or by pow (module docstring)
            stop = name.rsplit("/", 1)[0]
            n, m2 = a[f"{stop}/count"].astype(float), a[f"{stop}/m2_m2"]
            bound = (8 * U * n * m2**1.5 + 6 * U * np.abs(a[name]) if name.endswith("m3_m3")
                     else 15 * U * n * m2**2 + 7 * U * np.abs(a[name]))
            assert np.all(np.abs(a[name] - b[name]) <= bound), (name, np.max(np.abs(a[name] - b[name]) / bound))
        else:  # depth samples, counts, labels, and every value made by the same operations both ways: exactly
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
        compared += 1
    assert compared >= 10 and any("m2" in n or "mean" in n for n in a), sorted(a)
