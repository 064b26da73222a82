"""python -m benchmarks [--quick] [--workdir DIR] [--keep] [--json FILE] [--only NAME ...] [--repeat N]

Every figure against a baseline measured in the same run (see benchmarks/__init__.py); prints a Markdown table
(figure, ours, baseline, ratio, target, pass/fail) and writes the figures and the machine to JSON. --quick uses
a 212x120 sweep of 30 frames a stop and one seed of the blind table (a few minutes) instead of the full 848x480 x 300
and ten seeds (about half an hour, of which the blind table is 15-20 minutes). --repeat N runs the groups whose
figures are single commands (commands, small) N times, each run with its own baseline, and reports the medians.
`python -m benchmarks.table` then writes the JSON's table into docs/performance.md.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

from . import capture, data, fitting, importing
from .figures import median_of_runs, table, write_json

GROUPS = ("streaming", "capture", "camera", "run", "commands", "small", "per-sample", "scaling", "import", "table")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a small sweep (212x120, 30 frames a stop)")
    ap.add_argument("--workdir", type=Path, help="where the recordings go (default: a temporary folder)")
    ap.add_argument("--keep", action="store_true", help="keep the recordings for the next run (with --workdir)")
    ap.add_argument("--json", type=Path, default=Path("benchmark-results.json"), help="where the figures go")
    ap.add_argument("--only", nargs="*", choices=GROUPS, help="only these groups of figures")
    ap.add_argument("--repeat", type=int, default=1, metavar="N",
                    help="run the commands and small groups N times (each with its own baseline): medians")
    args = ap.parse_args(argv)
    size = data.QUICK if args.quick else data.FULL
    work = args.workdir or Path(tempfile.mkdtemp(prefix="rig-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    want = set(args.only or GROUPS)
    figures = []
    try:
        if "streaming" in want:
            figures += capture.streaming(size)
        if "capture" in want:
            figures += capture.capture(size)
        if "camera" in want:
            figures += capture.fake_camera(size)
        if want & {"run", "commands", "scaling"}:
            sweep, run_cpu, run_wall = data.sweep(work, size)
            print(f"sweep: {sweep}", file=sys.stderr)
            if "run" in want and run_cpu == run_cpu:
                from .figures import Figure

                frames = 11 * size.frames
                figures.append(Figure(f"rig run of the sweep ({frames} frames, {size.width}x{size.height}), CPU", run_cpu,
                                      frames * figures_camera_ms(figures) / 1e3 if figures_camera_ms(figures) else float("nan"),
                                      "s", "about a minute", run_wall <= 90.0, "the fake camera's rendering alone",
                                      note=f"wall {run_wall:.0f} s, {frames / run_wall:.0f} frames/s"))
            if "commands" in want:
                figures += median_of_runs([fitting.commands(sweep, work) for _ in range(max(1, args.repeat))])
            if "scaling" in want:
                figures += fitting.scaling(sweep)
        if "small" in want:
            demo = data.demo_recording(work)
            sweep_file = data.sweep_path(work, size)  # issue 30's seconds scale with the paper's script on it
            sweep_file = sweep_file if sweep_file.exists() else None
            figures += median_of_runs([fitting.small(demo, work, sweep_file) for _ in range(max(1, args.repeat))])
        if "per-sample" in want:
            figures += fitting.against_per_sample(data.raw_recording(work))
        if "import" in want:
            figures += importing.importing(data.png_folder(work, size))
        if "table" in want:  # last: the longest (about 15 minutes on 2 cores; one seed each with --quick)
            figures += fitting.blind_table(data.demo_recording(work), work, seeds=1 if args.quick else 10)
    finally:
        if not args.keep and args.workdir is None:
            shutil.rmtree(work, ignore_errors=True)
    print(table(figures))
    only = [g for g in GROUPS if g in want] if args.only else None
    write_json(figures, args.json, {"size": vars(size), "quick": args.quick, "only": only, "repeat": args.repeat})
    print(f"\nfigures: {args.json}", file=sys.stderr)
    return 0 if all(f.passed is not False for f in figures) else 1


def figures_camera_ms(figures) -> float:
    """The fake camera's ms per frame, if measured in this run."""
    return next((f.ours for f in figures if f.name.startswith("fake camera")), 0.0)


if __name__ == "__main__":
    sys.exit(main())
