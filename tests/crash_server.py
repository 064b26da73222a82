"""What the fork server of tests/test_crash_safety.py imports once: the crash child and everything it runs.

Each trial is then a fork of that process (multiprocessing's "forkserver"), not a new interpreter: ~0.1 s of
CPU instead of ~1 s of imports. Its runs are tiny (16x9 px), so numba's compiler is off (tests/tiny_runs.py);
set here, before numba is imported, in the server's process only.
"""

import os

os.environ["NUMBA_DISABLE_JIT"] = "1"

import crash_child  # noqa: E402,F401
