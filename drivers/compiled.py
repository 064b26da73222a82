"""The decorator for per-pixel kernels: numba's `njit`, or the plain Python function when numba's own switch
NUMBA_DISABLE_JIT=1 is set, without importing numba at all.

numba honours that switch itself, but only after its import (0.5 s of CPU, half of a tiny `rig run`); the kernels'
results are the same either way (tests/test_tiny_runs.py). Used by the streaming statistics (protocols/stats.py)
and the fake camera (fakes/render.py), which both sit on this layer.
"""

from __future__ import annotations

import os
from typing import Any, Callable


def njit(**options: Any) -> Callable[[Callable], Callable]:
    """`numba.njit(**options)`, or the function unchanged under NUMBA_DISABLE_JIT=1 (as numba itself would)."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0").strip() not in ("", "0"):
        return lambda function: function
    import numba

    return numba.njit(**options)
