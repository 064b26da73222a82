"""Compile rig's numba kernels once, in one process, before the test workers start (`python3 dev.py test` runs it).

From a fresh clone no kernel is compiled yet (numba keeps them in __pycache__ once it has), and the suite's four
workers, and the commands their tests start, each compiled the same ~20 kernels at once in their first minute:
~120 s of CPU of a fresh clone's run went there. This script runs a tiny simulation (the fake camera's kernels,
the streaming statistics) and a diagnosis of a coarse depth unit (the likelihood's, the range transform's, the
outlier mixture's, rounding's, the bins'); the tests then load them from the cache. Not compiled here: grouping's
(it needs 100,000 pixel-stops), which only tests/test_grouping.py uses. ~15 s of CPU from a fresh clone at first,
17-32 s on 2026-11-27 (the loading's and the headline's passes compiled since; the spread is the machine's stretches
of the day), ~2 s when everything is compiled already.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    """Always 0: a failure here is the tests' to report, with their own words."""
    from rig.cli import main as rig
    from rig.cli.shared import model_data
    from rig.diagnosis import diagnose

    t0 = time.process_time()
    with tempfile.TemporaryDirectory(prefix="rig-warm-") as tmp:
        a, b = str(Path(tmp, "filtered.h5")), str(Path(tmp, "coarse.h5"))
        codes = [rig(["simulate", "--effect", effect, "--width", "16", "--frames", "20", "--seed", "1", path, "-q"])
                 for effect, path in (("temporal_filter", a), ("coarse_depth_unit", b))]
        if not codes[1]:  # the diagnosis `rig diagnose` makes, without its plots and page (no kernel there: ~3 s)
            try:
                diagnose(model_data(b)[0], source=b, jobs=1)
            except Exception as e:  # noqa: BLE001 - the tests will meet it and say it
                codes.append(f"diagnose: {type(e).__name__}: {e}")
    print(f"warm_kernels: numba's kernels compiled or loaded in {time.process_time() - t0:.1f} s of CPU"
          + ("" if codes == [0, 0] else f" (exit codes {codes}: the tests will say what is wrong)"), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
