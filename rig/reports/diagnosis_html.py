"""The diagnosis as one self-contained HTML page: plots embedded, tables inline, the full text report."""

from __future__ import annotations

import html
from pathlib import Path

from ..diagnosis import Diagnosis, render_text
from .html_page import figures, page, run_table, summary
from .run_info import RunInfo
from .output_file import write_text
from .verdict_state import UNJUDGED, headline_state


def write_html(diag: Diagnosis, plots: list[Path], out_dir: str | Path, run: RunInfo | None = None) -> Path:
    """The page; `run` (rig.reports.run_info) adds the run's metadata: dates, rig version, camera, settings, stage."""
    out = Path(out_dir) / "diagnosis.html"
    rows = "".join(
        f"<tr class='{'sig' if c.significant else ''}'><td>{c.effect.name}</td><td>{c.dbic:.1f}</td><td>{c.lrt:.1f}</td>"
        f"<td>{c.df}</td><td>{c.p_value:.1e}</td><td>{html.escape(c.effect.signature)}</td></tr>" for c in diag.candidates)
    body = f"""{run_table(run)}
{summary(diag.summary(), diagnosis_state(diag))}
<p>Headline error of {html.escape(diag.model_fit.model.name)}: {html.escape(str(diag.model_headline))}
{"<br>With " + html.escape(diag.final_fit.model.name) + ": " + html.escape(str(diag.final_headline)) if diag.final_fit is not diag.model_fit else ""}</p>
<h2>The path</h2>
<table><tr><th>step</th><th>model</th><th>headline error</th><th>verdict</th></tr>{path_rows(diag)}</table>
<h2>Candidate effects</h2>
<table><tr><th>effect</th><th>ΔBIC</th><th>LRT</th><th>df</th><th>p</th><th>what it explains</th></tr>{rows}</table>
<h2>Plots</h2>
{figures(plots)}
<h2>Full report</h2>
<pre>{html.escape(render_text(diag))}</pre>"""
    write_text(out, page(f"Range-error diagnosis: {diag.source}", body))
    return out


def path_rows(diag: Diagnosis) -> str:
    rows = []
    for st in diag.steps:
        change = "start" if st.added is None else f"+ {st.added.effect.name} (ΔBIC {st.added.dbic:.1f})"
        rows.append((change, st.name, st.headline))
    if diag.unexplained is not None:
        rows += [(f"+ {st.added}" + (f" for {st.family}" if st.is_empirical else " (the catalogue tried again)"),
                  st.fit.model.name, st.headline) for st in diag.unexplained.steps]
    return "".join(f"<tr><td>{html.escape(c)}</td><td>{html.escape(m)}</td><td>{h.error_pct:.2f} % (noise {h.noise_pct:.2f} %)</td>"
                   f"<td class='verdict-{headline_state(h)}'>{html.escape(h.verdict())}</td></tr>" for c, m, h in rows)


def diagnosis_state(diag: Diagnosis) -> str:
    """The summary's state: unjudged when the model's headline judged nothing, else the final model's state."""
    return headline_state(diag.final_headline) if diag.model_headline.judged else UNJUDGED
