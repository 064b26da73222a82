"""The HTML pages of `rig fit`, `rig compare` and `rig repeatability` (`--report DIR`): like `rig diagnose`'s, one
self-contained page with the run's metadata, the tables, the plots embedded and the text report (`html_page`)."""

from __future__ import annotations

import html
from pathlib import Path

from protocols.recording import Recording, utc_now

from .. import package_version
from ..accuracy import accuracy_lines
from ..diagnosis.bins import pooled_sigma, sigma_by_range
from ..recordings.comparison import Pair, Scatter, misfit_caution, repeatability_verdict
from ..recordings.recording_fits import RecordingResult, summarise
from .comparison_plots import plot_overlay
from .measured_predicted import plot_measured_predicted
from .comparison_text import difference_rows, results_rows, scatter_rows, setup_rows
from .html_page import figures, page, run_table, summary, table
from .run_info import RunInfo, run_info
from .output_file import write_text
from .verdict_state import UNJUDGED, headline_state, pair_state, repeatability_state


def _write(out_dir: str | Path, name: str, text: str) -> Path:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / name
    return write_text(path, text)  # a reader never sees half a page


def write_fit_page(title: str, headline: str, report: str, plots: list[Path], out_dir: str | Path,
                   run: RunInfo | None = None, state: str = UNJUDGED) -> Path:
    """fit.html: the run, the headline in one line (coloured by its `state`), the plots, the fit's text report."""
    body = (f'{run_table(run)}\n{summary(headline, state)}\n<h2>Plots</h2>\n{figures(plots)}\n'
            f"<h2>Full report</h2>\n<pre>{html.escape(report)}</pre>")
    return _write(out_dir, "fit.html", page(title, body))


def fit_report_text(fit, h, notes: list[str], acc=None) -> str:
    """fit.html's text report: the notes, the fit's report, its headline error and the accuracy against the stage."""
    return "\n".join([*(f"note: {n}" for n in notes), fit.report(), f"    headline error: {h}",
                      *(accuracy_lines(acc) if acc is not None else [])])


def fit_report(path: str, fit, d, h, text: str, out_dir: str | Path, notes: list[str]) -> Path:
    """`rig fit --report DIR`: fit.html with the run's metadata, the plot of sigma against range (measured per stop,
    the model's curve on the optical axis) and sigma measured / predicted by range and by radius."""


    with Recording(path) as rec:
        labels = rec.stop_labels()
        measured = pooled_sigma(d, d.stop, labels) if len(labels) > 1 else sigma_by_range(d)
        result = summarise(path, fit, d, h, measured, rec, notes, bool(d.projector_on.any()))
    plots = [plot_overlay([result], Path(out_dir) / "fit-sigma.png")]
    ratio = plot_measured_predicted(h, fit.model.name, Path(out_dir) / "fit-measured-predicted.png")
    plots += [ratio] if ratio is not None else []
    return write_fit_page(f"Range-error fit: {path}", f"{fit.model.name}: headline error {h}", text, plots, out_dir,
                          run_info(path, utc_now(), package_version()), headline_state(h))


def write_compare_page(results: list[RecordingResult], pairs: list[Pair], plots: list[Path],
                       out_dir: str | Path, report: str, runs: list[RunInfo] | None = None) -> Path:
    """compare.html: the verdicts, what differs in the set-up, each recording's fit, the differences of each pair,
    the overlay plot."""
    verdicts = "".join(summary(p.verdict(), pair_state(p)) for p in pairs)
    header, rows, marked = difference_rows(pairs)
    body = (f"{verdicts}\n<h2>Set-up</h2>\n{_setup(results)}\n<h2>The fits</h2>\n{table(*results_rows(results))}\n"
            "<h2>Differences</h2>\n"
            f"{table(header, rows, marked)}\n<h2>Plots</h2>\n{figures(plots)}\n{_runs(runs)}\n"
            f"<h2>Full report</h2>\n<pre>{html.escape(report)}</pre>")
    return _write(out_dir, "compare.html", page(f"Recordings compared: {', '.join(r.name for r in results)}", body))


def write_repeatability_page(results: list[RecordingResult], scatters: list[Scatter], plots: list[Path],
                             out_dir: str | Path, report: str, runs: list[RunInfo] | None = None) -> Path:
    """repeatability.html: the runs' fits, each parameter's scatter against its errors, the verdict, the plots."""
    header, rows, marked = scatter_rows(scatters)
    state = repeatability_state(scatters, misfit_caution(results))
    body = (f'{summary(repeatability_verdict(scatters, results), state)}\n<h2>Set-up</h2>\n'
            f"{_setup(results)}\n<h2>Scatter against the reported errors</h2>\n{table(header, rows, marked)}\n"
            f"<h2>The runs</h2>\n{table(*results_rows(results))}\n"
            f"<h2>Plots</h2>\n{figures(plots)}\n{_runs(runs)}\n<h2>Full report</h2>\n<pre>{html.escape(report)}</pre>")
    return _write(out_dir, "repeatability.html", page(f"Repeatability over {len(results)} runs", body))


def _setup(results: list[RecordingResult]) -> str:
    header, rows, same = setup_rows(results)
    return (table(header, rows, [True] * len(rows)) if rows else "") + (f"<p>The same in all: {html.escape(same)}</p>"
                                                                        if same else "")


def _runs(runs: list[RunInfo] | None) -> str:
    if not runs:
        return ""
    return "<h2>The recordings</h2>\n" + "\n".join(run_table(r) for r in runs)
