"""The environment for commands a test starts dozens of times on tiny simulated runs (16x9 px, a few frames).

Numba compiles nothing there (NUMBA_DISABLE_JIT=1): the per-pixel loops of the fake camera and of the streaming
statistics run as the Python they are written in, which on 144 pixels is quicker than loading their compiled code
(0.8 s of a `rig run`'s 1.9 s of CPU; 1.1 s without it), and numba is then not even imported (drivers/compiled.py: 0.4 s more). What is tested there is files, locks, kills and full disks,
not arithmetic; test_tiny_runs.py checks that such a run writes the same recording (the same samples, counts and
moments, but for the last bits of the third and fourth moments' whole powers). Not for
imports of real recordings or diagnoses: at 640x480 px or 70,000 rows the interpreted loops cost far more.
"""

from __future__ import annotations

import os


def tiny_run_env() -> dict[str, str]:
    """os.environ with numba's compiler off (see the module docstring)."""
    return {**os.environ, "NUMBA_DISABLE_JIT": "1"}
