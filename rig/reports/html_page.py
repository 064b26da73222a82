"""What every HTML report of rig shares: one self-contained page (plots embedded as PNG data), its style, and the
run's metadata table. `rig diagnose` (diagnosis_html), `rig fit`, `rig compare` and `rig repeatability`
(report_pages) write their pages with it."""

from __future__ import annotations

import base64
import html
from pathlib import Path

from .run_info import RunInfo
from .verdict_state import COLOURS

STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1200px; margin: 2em auto; padding: 0 1em; color: #222; }
h1 { font-size: 1.4em; } .summary { font-size: 1.15em; padding: 0.8em; border-left: 4px solid; }
table { border-collapse: collapse; display: block; max-width: 100%; overflow-x: auto; } td, th { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: left; }
tr.sig td { background: #f4f8ff; } table.run th { font-weight: normal; color: #555; } img { max-width: 100%; }
pre { background: #f6f6f6; padding: 1em; white-space: pre-wrap; overflow-wrap: anywhere; }
""" + "".join(f".verdict-{state} {{ background: {bg}; border-color: {border}; }}\n"
              for state, (bg, border, _) in COLOURS.items())


def page(title: str, body: str) -> str:
    """A whole page: `title` (text) in the head and as the heading, then `body` (HTML)."""
    t = html.escape(title)
    return (f'<!doctype html>\n<html lang="en"><head><meta charset="utf-8"><title>{t}</title>\n<style>{STYLE}</style>'
            f"</head><body>\n<h1>{t}</h1>\n{body}\n</body></html>\n")


def figures(plots: list[Path]) -> str:
    """The plots embedded (data URLs), so the page is one file that can be mailed or archived."""
    return "\n".join(
        f'<figure><img alt="{html.escape(p.stem)}" src="data:image/png;base64,{base64.b64encode(p.read_bytes()).decode()}">'
        f"<figcaption>{html.escape(p.stem)}</figcaption></figure>" for p in plots)


def run_table(run: RunInfo | None) -> str:
    """The run's metadata as a table, each row marked with its key (data-key) for scripts reading the page."""
    if run is None:
        return ""
    rows = "".join(f'<tr data-key="{html.escape(k)}"><th>{html.escape(label)}</th><td>{html.escape(value)}</td></tr>'
                   for k, label, value in run.rows)
    return f'<table class="run">{rows}</table>'


def table(header: list[str], rows: list[list[str]], marked: list[bool] | None = None) -> str:
    """A plain table from text cells (escaped here); `marked` rows are highlighted."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(f"<tr class='{'sig' if marked and marked[i] else ''}'>" + "".join(f"<td>{html.escape(c)}</td>" for c in r)
                   + "</tr>" for i, r in enumerate(rows))
    return f"<table><tr>{head}</tr>{body}</table>"


def summary(text: str, state: str) -> str:
    """A verdict in a box coloured by its `state` (rig.reports.verdict_state): green only within noise."""
    return f'<p class="summary verdict-{state}" data-state="{state}">{html.escape(text)}</p>'
