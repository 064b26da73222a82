"""One BLAS thread per process, unless the environment says otherwise.

rig works in parallel with processes (`--jobs`, the test suite's workers), not with BLAS's threads: numpy's and
scipy's OpenBLAS each start a worker thread per core, which spin between the short products a fit makes and,
beside a process pool's workers, only take cores from them (`rig diagnose` of the demo's recording: 23.5 -> 19.8 s
of CPU on 2 cores at the same wall time; tests/test_diagnosis.py 246 -> 160 s). Works only before numpy is
imported: the command line and tests/conftest.py call it first. Imports nothing.
"""

from __future__ import annotations

import os


def one_blas_thread() -> None:
    """Set OPENBLAS/OMP/MKL_NUM_THREADS to 1 where the environment leaves them unset."""
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")
