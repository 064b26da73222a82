"""One figure of the benchmark table: ours against the baseline measured in the same run, and its target."""

from __future__ import annotations

import json
import platform
import resource
import statistics
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable


@dataclass
class Figure:
    """ours and baseline in `unit` (lower is better unless `higher_is_better`); `target`: in words; `passed`:
    whether ours meets it (None: no target); `ratio` = ours / baseline."""

    name: str
    ours: float
    baseline: float
    unit: str
    target: str
    passed: bool | None
    baseline_name: str = ""
    note: str = ""
    extra: dict = field(default_factory=dict)
    paired_ratio: float | None = None  # several runs': the median of each run's own ratio (`median_of_runs`)

    @property
    def ratio(self) -> float:
        if self.paired_ratio is not None:
            return self.paired_ratio
        return self.ours / self.baseline if self.baseline else float("nan")


def best_of(fn: Callable[[], object], repeats: int = 3) -> float:
    """The least CPU time (s) of `repeats` calls (CPU time: these machines are shared and noisy)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def run_measured(cmd: list[str], cwd: Path | None = None) -> tuple[float, float, float, str]:
    """Run a command in a child that reports its own child's CPU time (s), peak memory (MB) and wall time (s)."""
    probe = ("import resource, subprocess, sys, time, json; t = time.monotonic(); "
             "p = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
             "u = resource.getrusage(resource.RUSAGE_CHILDREN); "
             "print(json.dumps([u.ru_utime + u.ru_stime, u.ru_maxrss / 1024, time.monotonic() - t, p.returncode, "
             "p.stdout[-2000:] + p.stderr[-2000:]]))")
    out = subprocess.run([sys.executable, "-c", probe, *cmd], capture_output=True, text=True, cwd=cwd, check=True)
    cpu, peak_mb, wall, status, text = json.loads(out.stdout.strip().splitlines()[-1])
    if status != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {status}: {text}")
    return cpu, peak_mb, wall, text


def machine() -> dict:
    """What the figures were measured on."""
    cpu = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import os

    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    versions = {}
    for name in ("numpy", "numba"):
        try:
            versions[name] = __import__(name).__version__
        except ImportError:
            pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform(),
            **versions, "load_average": [round(x, 2) for x in load],
            "max_rss_self_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def provenance() -> dict:
    """When the figures were measured, and of which commit (git's, `+changes` when the tree differs from it)."""
    from datetime import datetime, timezone

    out = {"utc": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M")}
    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                                check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True,
                               text=True, check=True).stdout.strip()
        out["commit"] = commit + ("+changes" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        pass
    return out


def median_of_runs(runs: list[list[Figure]]) -> list[Figure]:
    """One group's figures from several runs, each against its own baseline (a run alternates the baseline with ours):
    the median of ours and of the baseline, passed if it passed in most runs, every run's ratio in the note, and as
    the ratio the median of the runs' own ratios (each ours against the baseline of its own run: the ratio of the
    two medians would pair seconds from different runs). On a shared machine one run's ratio moved 15-25 % within
    an hour (docs/performance.md); the median decides."""
    if len(runs) == 1:
        return runs[0]
    out = []
    for same in zip(*runs):
        first = same[0]
        passes = [f.passed for f in same if f.passed is not None]
        ratios = ", ".join(f"{f.ratio:.2f}" for f in same)
        out.append(Figure(first.name, float(statistics.median(f.ours for f in same)),
                          float(statistics.median(f.baseline for f in same)), first.unit, first.target,
                          None if not passes else sum(passes) > len(passes) / 2, first.baseline_name,
                          note=f"median of {len(same)} runs (ratios {ratios}); {first.note}".rstrip("; "),
                          extra={**first.extra, "runs": [{"ours": f.ours, "baseline": f.baseline} for f in same]},
                          paired_ratio=float(statistics.median(f.ratio for f in same))))
    return out


def table(figures: list[Figure]) -> str:
    """The results as a Markdown table: figure, ours, baseline, ratio, target, pass/fail, note."""
    rows = ["| figure | ours | baseline | ratio | target | | note |", "|---|---|---|---|---|---|---|"]
    for f in figures:
        verdict = "" if f.passed is None else ("pass" if f.passed else "FAIL")
        base = f"{_fmt(f.baseline)} {f.unit} ({f.baseline_name})" if f.baseline_name else f"{_fmt(f.baseline)} {f.unit}"
        rows.append(f"| {f.name} | {_fmt(f.ours)} {f.unit} | {base} | {f.ratio:.2f} | {f.target} | {verdict} | {f.note} |")
    return "\n".join(rows)


def _fmt(x: float) -> str:
    if x != x:
        return "-"
    if abs(x) >= 100:
        return f"{x:.0f}"
    if abs(x) >= 1:
        return f"{x:.2f}"
    return f"{x:.3g}"


def write_json(figures: list[Figure], path: Path, settings: dict) -> None:
    """The figures, the machine, the settings and when (docs/performance.md's table is made from this file:
    `python -m benchmarks.table`)."""
    doc = {"machine": machine(), "measured": provenance(), "settings": settings,
           "figures": [{**asdict(f), "ratio": f.ratio} for f in figures]}
    path.write_text(json.dumps(doc, indent=2, allow_nan=True).replace("NaN", "null"))
