"""The text of `rig compare a.h5 b.h5 ...` and `rig repeatability`: first what differs in the set-up (a row an item,
a column a recording), then one row a recording (every parameter with its error), then the verdicts in words
(`rig.recordings.comparison`)."""

from __future__ import annotations

import math

from ..recordings.camera_setup import setup_differences, shown
from ..recordings.comparison import Pair, Scatter, recorded_labels, repeatability_verdict
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


def setup_rows(results: list[RecordingResult]) -> tuple[list[str], list[list[str]], str]:
    """(header, rows, the rest): a row for each set-up item that differs between the fitted recordings, and the items
    that are the same in all, in words."""
    fitted = [r for r in results if not r.error]
    setups = [r.setup for r in fitted]
    rows = [[d.item.label, *(shown(d.item, v) for v in d.values)] for d in setup_differences(setups)]
    differing = {row[0] for row in rows}
    same = [label for label in recorded_labels(setups) if label not in differing]
    return ["set-up", *(r.name for r in fitted)], rows, ", ".join(same)


def render_setup(results: list[RecordingResult]) -> str:
    header, rows, same = setup_rows(results)
    if not rows:
        return f"set-up: the same in every recording ({same or 'nothing recorded'})\n"
    return aligned(header, rows) + "\n" + (f"the same in all: {same}\n" if same else "")


def difference_rows(pairs: list[Pair]) -> tuple[list[str], list[list[str]], list[bool]]:
    header = ["a", "b", "parameter", "a - b", "standard errors", "p", "differs"]
    rows, marked = [], []
    for pair in pairs:
        for d in pair.parameters:
            verdict = ("no verdict (the model does not fit)" if d.significant is None else
                       "yes" if d.differs else "explained by the set-up" if d.significant else "no")
            rows.append([d.a.name, d.b.name, d.parameter, f"{d.value_a - d.value_b:.3g}", f"{d.z:+.1f}",
                         f"{d.p:.1e}" if d.p > 0 else "< 1e-300", verdict])
            marked.append(d.differs)
    return header, rows, marked


def scatter_rows(scatters: list[Scatter]) -> tuple[list[str], list[list[str]], list[bool]]:
    header = ["parameter", "runs", "mean", "run-to-run s.d.", "reported error (RMS)", "ratio", "interval", "honest"]
    rows = [[s.parameter, str(s.n), f"{s.mean:.6g}", f"{s.sd:.3g}", f"{s.se:.3g}", f"{s.ratio:.2f}",
             f"{s.low:.2f}-{s.high:.2f}", "yes" if s.honest else "no"] for s in scatters]
    return header, rows, [not s.honest for s in scatters]


def render_compare(results: list[RecordingResult], pairs: list[Pair]) -> str:
    lines = [render_setup(results), aligned(*results_rows(results)), ""]
    header, rows, _ = difference_rows(pairs)
    if rows:
        lines += [aligned(header, rows), ""]
    lines += [f"verdict: {p.verdict()}" for p in pairs]
    return "\n".join(lines)


def render_repeatability(results: list[RecordingResult], scatters: list[Scatter]) -> str:
    header, rows, _ = scatter_rows(scatters)
    return "\n".join([render_setup(results), aligned(*results_rows(results)), "", aligned(header, rows), "",
                      f"verdict: {repeatability_verdict(scatters, results)}"])
