"""Python's cyclic garbage collector, set for rig's processes: commands that end when their work does, and the test
session's workers. Imports nothing but `gc`.

- `collect_less_often`: the first generation is collected every YOUNG_THRESHOLD new objects, not Python's 700.
  The imports and numba's first call make hundreds of thousands of objects that live until the process ends; at
  700 the collector ran 254 young and two full collections in a `rig fit` of the sweep (0.20 s of CPU), 43 and
  none at 20,000 (0.10 s); the quick test tier's two workers spent 3.0 s in it, 1.3 s at 20,000. A cycle of
  garbage waits for at most that many new objects (a few MB) before it is freed.
- `freeze_before_exit`: everything left is frozen (`gc.freeze`), so the collections of the interpreter's shutdown
  pass over nothing. Over numba's objects they cost 0.54-0.61 s of CPU after a `rig fit` (0.36-0.40 s after only
  importing numba and calling one cached kernel); frozen, 0.05-0.08 s. Objects are still freed as their references
  go; only a cycle still there at exit is left to the operating system, which frees the process's memory anyway.
"""

from __future__ import annotations

import gc

#: new objects between two collections of the first generation
YOUNG_THRESHOLD = 20_000


def collect_less_often() -> None:
    """The first generation collected every YOUNG_THRESHOLD new objects; the older generations as before."""
    gc.set_threshold(YOUNG_THRESHOLD, *gc.get_threshold()[1:])


def freeze_before_exit() -> None:
    """Freeze every object now tracked: the process is about to end (module docstring)."""
    gc.freeze()
