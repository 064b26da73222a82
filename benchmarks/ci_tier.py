"""The benchmark's quick tier for CI: `python -m benchmarks.ci_tier` (run by `python3 dev.py test` after the suite).

The figures that cost seconds, not minutes, at the full sweep's size (848x480, 300 frames a stop: the
capture's fixed costs weigh as in the full run): the streaming statistics against `frame.sum()`, a whole capture
through the runner, the fake camera's rendering. Each ratio is printed beside its target and the ratio
`benchmark-results.json` last recorded (the full run's same figure, with its date), so a regression is seen in
CI's log before it lands. Printed, never judged: on a shared machine the seconds move 10-25 % within an hour
(docs/performance.md), so the status is 0 whatever the
ratios; a benchmark that cannot run at all is an error.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from . import capture
from .data import Size

#: the full sweep's image and frames a stop (the capture records 3 stops of them; the others take their own counts)
CI_SIZE = Size(848, 480, 300, 0)
RECORDED = Path(__file__).resolve().parents[1] / "benchmark-results.json"


def recorded() -> tuple[dict[str, float], str]:
    """The ratios benchmark-results.json holds, by figure name, and when they were measured."""
    try:
        data = json.loads(RECORDED.read_text())
    except (OSError, ValueError):
        return {}, "none recorded"
    ratios = {f["name"]: f["ratio"] for f in data.get("figures", []) if isinstance(f.get("ratio"), (int, float))}
    return ratios, str(data.get("measured", {}).get("utc", data.get("measured", "")))[:16] or "undated"


def main() -> int:
    t0 = time.process_time()
    figures = [*capture.streaming(CI_SIZE), *capture.capture(CI_SIZE), *capture.fake_camera(CI_SIZE)]
    last, when = recorded()
    print(f"benchmarks (quick tier, {CI_SIZE.width}x{CI_SIZE.height}; printed, not judged; last recorded: "
          f"benchmark-results.json, {when}):")
    print(f"  {'figure':<58} {'ours':>16} {'ratio':>8} {'last':>8}  target (ratio: ours / baseline)")
    for f in figures:
        before = last.get(f.name)
        ours = f"{f.ours:.3g} {f.unit}"
        print(f"  {f.name:<58} {ours:>16} {f.ratio:8.3g} {before if before is None else format(before, '8.3g'):>8}  "
              f"{f.target}" + (f"; baseline: {f.baseline_name}" if f.baseline_name else ""))
    print(f"  ({time.process_time() - t0:.1f} s of CPU in this process)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
