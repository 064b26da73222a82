"""The text of `rig compare a.h5 b.h5 ...` and `rig repeatability`: one row a recording (every parameter with its
error), then the verdicts in words (`rig.recordings.comparison`)."""

from __future__ import annotations

import math

from ..recordings.comparison import Difference, Scatter, pair_verdict, repeatability_verdict
from ..recordings.recording_fits import RecordingResult


def parameter_names(results: list[RecordingResult]) -> list[str]:
    """Every free parameter of any fit, in the order they first appear."""
    return list(dict.fromkeys(n for r in results if not r.error for n in r.free))


def _cell(r: RecordingResult, name: str) -> str:
    if name not in r.values:
        return "-"
    se = r.errors.get(name, math.nan) if name in r.free else 0.0
    return f"{r.values[name]:.6g} ± {se:.2g}" if name in r.free else f"{r.values[name]:.6g} (fixed)"


def results_rows(results: list[RecordingResult]) -> tuple[list[str], list[list[str]]]:
    """(header, rows): a row a recording, its model, every parameter ± error, its headline error."""
    names = parameter_names(results)
    header = ["recording", "model", *names, "headline error"]
    rows = []
    for r in results:
        if r.error:
            rows.append([r.name, f"error: {r.error}", *("" for _ in names), ""])
        else:
            rows.append([r.name, r.model, *(_cell(r, n) for n in names),
                         f"{r.headline_pct:.2f} % (noise {r.noise_pct:.2f} %)"])
    return header, rows


def aligned(header: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in [header, *rows])


def difference_rows(pairs: list[list[Difference]]) -> tuple[list[str], list[list[str]], list[bool]]:
    header = ["a", "b", "parameter", "a - b", "standard errors", "p", "differs"]
    rows, marked = [], []
    for pair in pairs:
        for d in pair:
            rows.append([d.a.name, d.b.name, d.parameter, f"{d.value_a - d.value_b:.3g}", f"{d.z:+.1f}", f"{d.p:.1e}" if d.p > 0 else "< 1e-300",
                         "yes" if d.significant else "no"])
            marked.append(d.significant)
    return header, rows, marked


def scatter_rows(scatters: list[Scatter]) -> tuple[list[str], list[list[str]], list[bool]]:
    header = ["parameter", "runs", "mean", "run-to-run s.d.", "reported error (RMS)", "ratio", "interval", "honest"]
    rows = [[s.parameter, str(s.n), f"{s.mean:.6g}", f"{s.sd:.3g}", f"{s.se:.3g}", f"{s.ratio:.2f}",
             f"{s.low:.2f}-{s.high:.2f}", "yes" if s.honest else "no"] for s in scatters]
    return header, rows, [not s.honest for s in scatters]


def render_compare(results: list[RecordingResult], pairs: list[list[Difference]]) -> str:
    lines = [aligned(*results_rows(results)), ""]
    header, rows, _ = difference_rows(pairs)
    if rows:
        lines += [aligned(header, rows), ""]
    lines += [f"verdict: {pair_verdict(p)}" for p in pairs]
    return "\n".join(lines)


def render_repeatability(results: list[RecordingResult], scatters: list[Scatter]) -> str:
    header, rows, _ = scatter_rows(scatters)
    return "\n".join([aligned(*results_rows(results)), "", aligned(header, rows), "",
                      f"verdict: {repeatability_verdict(scatters, results)}"])
