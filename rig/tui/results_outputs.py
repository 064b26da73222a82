"""What leaves the Results screen, without Textual: the noise model file (e), the fit report (w), a comparison with
another recording (c), and the report in a browser (b) where there is a display. Each is what its command does with
the model on the screen, through the command's own functions: `rig export REC --model M`
(`rig.reports.noise_model_file`), `rig fit REC --model M --report DIR` (`rig.reports.report_pages`) and
`rig compare REC OTHER --model M` (`rig.fleet.many`, `rig.recordings.comparison`, `rig.reports.comparison_text`)."""

from __future__ import annotations

import os
import sys
import webbrowser
from dataclasses import dataclass
from pathlib import Path

from protocols.recording import Recording

from rig.accuracy import accuracy_of
from rig.analysis import recording_notes
from rig.diagnosis import headline
from rig.fleet.many import fit_all_for_comparison
from rig.recordings.comparison import differences
from rig.recordings.recording_fits import FitJob
from rig.reports.comparison_text import render_compare
from rig.reports.noise_model_file import default_model_path, model_document, write_model, written_line
from rig.reports.report_pages import fit_report, fit_report_text

from .results_service import ResultsSession

#: browsers that run in the terminal, which the TUI holds (webbrowser registers them when TERM is set)
CONSOLE_BROWSERS = frozenset({"www-browser", "links", "elinks", "lynx", "w3m"})


@dataclass
class Written:
    path: Path
    line: str  # what was written, in one line
    warning: str = ""  # what the reader must know (a lambda the data do not determine)


def _opened(session: ResultsSession) -> tuple[Path, object, object]:
    if session.path is None or session.fit is None or session.data is None:
        raise ValueError("open a recording first (enter in its path field, or ctrl+o)")
    return session.path, session.fit, session.data


def model_file(session: ResultsSession) -> Path:
    """Where e writes: where `rig export` writes by default."""
    return default_model_path(_opened(session)[0])


def export_model(session: ResultsSession, out: Path) -> Written:
    """The model on the screen as `rig export REC --model M -o OUT` writes it."""
    path, fit, d = _opened(session)
    with Recording(path) as rec:
        notes = recording_notes(rec)
    doc, h = model_document(fit, d, path, notes)
    write_model(doc, out)
    warning = "" if h.determined else f"the file is written, but {h.lambda_status.reason}; {h.lambda_status.fix}"
    return Written(out, written_line(doc, out, h), warning)


def report_folder(session: ResultsSession) -> Path:
    """Where w writes fit.html: RECORDING-report/ beside the recording."""
    path = _opened(session)[0]
    return path.with_name(path.stem + "-report")


def write_report(session: ResultsSession, folder: Path) -> Path:
    """fit.html of the model on the screen, as `rig fit REC --model M --report FOLDER` writes it; its path."""
    path, fit, d = _opened(session)
    with Recording(path) as rec:
        notes, protocol, params = recording_notes(rec), rec.protocol, rec.protocol_params
    h, acc = headline(fit, d), accuracy_of(d, None, protocol, params)
    return fit_report(str(path), fit, d, h, fit_report_text(fit, h, notes, acc), folder, notes)


def compare(session: ResultsSession, other: str) -> tuple[str, list[str]]:
    """The recording on the screen against `other`, with its model, as `rig compare REC OTHER --model M`: the text
    report and each pair's verdict. A ValueError names what stops it (the same file twice, a file that is not there)."""
    path = _opened(session)[0]
    other = other.strip()
    if not other:
        raise ValueError("give the recording to compare with")
    if not Path(other).exists():
        raise ValueError(f"{other} does not exist; check the path")
    if Path(other).resolve() == path.resolve():
        raise ValueError(f"{other} is the recording on the screen; give another to compare it with")
    effects = (str(Path(session.effects_file).resolve()),) if session.effects_file else ()
    model = session.fit.model.name  # type: ignore[union-attr]
    results = list(fit_all_for_comparison([FitJob(str(path), model, effects), FitJob(other, model, effects)], 1))
    if all(r.error for r in results):
        raise ValueError("; ".join(f"{r.name}: {r.error}" for r in results))
    pairs = differences(results)
    notes = [f"note: {r.name}: {n}" for r in results for n in r.notes]
    errors = [f"{r.name}: {r.error}" for r in results if r.error]
    return "\n".join([*notes, render_compare(results, pairs), *errors]), [p.verdict() for p in pairs] + errors


def display_available(environ=os.environ, platform: str = sys.platform) -> bool:
    """Whether a browser can open a window here: on macOS and Windows, always; elsewhere when X or Wayland is there
    (the test `webbrowser` makes before it looks for graphical browsers)."""
    return platform in ("darwin", "win32") or bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"))


def graphical_browser() -> webbrowser.BaseBrowser | None:
    """The browser `webbrowser` would use, when there is a display and it opens a window of its own; None when it
    would run in this terminal (lynx, w3m, ...: it would take the screen from the TUI) or there is none."""
    if not display_available():
        return None
    try:
        browser = webbrowser.get()
    except webbrowser.Error:
        return None
    if getattr(browser, "name", "") in CONSOLE_BROWSERS:
        return None
    if isinstance(browser, webbrowser.UnixBrowser) and not browser.background:  # elinks
        return None
    return browser


def open_in_browser(page: Path) -> str:
    """Open `page` in the graphical browser; "" when it did, else why not."""
    browser = graphical_browser()
    if browser is None:
        return "no display or graphical browser here: open the page where there is one"
    if not browser.open(page.resolve().as_uri()):
        return f"the browser ({getattr(browser, 'name', type(browser).__name__)}) did not start"
    return ""
