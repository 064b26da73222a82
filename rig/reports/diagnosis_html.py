"""The diagnosis as one self-contained HTML page: plots embedded, tables inline, the full text report."""

from __future__ import annotations

import base64
import html
from pathlib import Path

from ..diagnosis import Diagnosis, render_text
from .run_info import RunInfo


def write_html(diag: Diagnosis, plots: list[Path], out_dir: str | Path, run: RunInfo | None = None) -> Path:
    """The page; `run` (rig.reports.run_info) adds the run's metadata: dates, rig version, camera, settings, stage."""
    out = Path(out_dir) / "diagnosis.html"
    imgs = "\n".join(
        f'<figure><img alt="{html.escape(p.stem)}" src="data:image/png;base64,{base64.b64encode(p.read_bytes()).decode()}">'
        f"<figcaption>{html.escape(p.stem)}</figcaption></figure>" for p in plots)
    rows = "".join(
        f"<tr class='{'sig' if c.significant else ''}'><td>{c.effect.name}</td><td>{c.dbic:.1f}</td><td>{c.lrt:.1f}</td>"
        f"<td>{c.df}</td><td>{c.p_value:.1e}</td><td>{html.escape(c.effect.signature)}</td></tr>" for c in diag.candidates)
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>rig diagnosis: {html.escape(diag.source)}</title>
<style>
body {{ font-family: system-ui, sans-serif; max-width: 1200px; margin: 2em auto; padding: 0 1em; color: #222; }}
h1 {{ font-size: 1.4em; }} .summary {{ font-size: 1.15em; background: #eef6ee; padding: 0.8em; border-left: 4px solid #3a3; }}
table {{ border-collapse: collapse; }} td, th {{ border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; }}
tr.sig td {{ background: #f4f8ff; }} table.run th {{ font-weight: normal; color: #555; }} img {{ max-width: 100%; }} pre {{ background: #f6f6f6; padding: 1em; overflow-x: auto; }}
</style></head><body>
<h1>Range-error diagnosis: {html.escape(diag.source)}</h1>
{run_table(run)}
<p class="summary">{html.escape(diag.summary())}</p>
<p>Headline error of {html.escape(diag.model_fit.model.name)}: {html.escape(str(diag.model_headline))}
{"<br>With " + html.escape(diag.final_fit.model.name) + ": " + html.escape(str(diag.final_headline)) if diag.final_fit is not diag.model_fit else ""}</p>
<h2>The path</h2>
<table><tr><th>step</th><th>model</th><th>headline error</th><th>verdict</th></tr>{path_rows(diag)}</table>
<h2>Candidate effects</h2>
<table><tr><th>effect</th><th>ΔBIC</th><th>LRT</th><th>df</th><th>p</th><th>what it explains</th></tr>{rows}</table>
<h2>Plots</h2>
{imgs}
<h2>Full report</h2>
<pre>{html.escape(render_text(diag))}</pre>
</body></html>
"""
    out.write_text(page)
    return out


def path_rows(diag: Diagnosis) -> str:
    rows = []
    for st in diag.steps:
        change = "start" if st.added is None else f"+ {st.added.effect.name} (ΔBIC {st.added.dbic:.1f})"
        rows.append((change, st.name, st.headline))
    if diag.unexplained is not None:
        rows += [(f"+ empirical({st.covariate}) for {st.family}", st.fit.model.name, st.headline)
                 for st in diag.unexplained.steps]
    return "".join(f"<tr><td>{html.escape(c)}</td><td>{html.escape(m)}</td><td>{h.error_pct:.2f} % (noise {h.noise_pct:.2f} %)</td>"
                   f"<td>{html.escape(h.verdict())}</td></tr>" for c, m, h in rows)


def run_table(run: RunInfo | None) -> str:
    """The run's metadata as a table, each row marked with its key (data-key) for scripts reading the page."""
    if run is None:
        return ""
    rows = "".join(f'<tr data-key="{html.escape(k)}"><th>{html.escape(label)}</th><td>{html.escape(value)}</td></tr>'
                   for k, label, value in run.rows)
    return f'<table class="run">{rows}</table>'
