"""The reports' pictures as a person sees them: a verdict's box coloured by its state (never green when beyond
noise), "Full report" text wrapped, not clipped, every axis with its unit. Read with the standard library's HTML
parser and matplotlib's own artists, on tiny recordings (32 px wide, 8 frames a stop)."""

from __future__ import annotations

import re
from html.parser import HTMLParser
from pathlib import Path

import pytest
from cli_in_process import rig_in_process
from simrig import record_perpendicular

STOPS = [0.5, 1.0, 1.5, 2.0]


class Boxes(HTMLParser):
    """The summary boxes of a page: (classes, text) each, and the page's style sheet."""

    def __init__(self) -> None:
        super().__init__()
        self.boxes: list[tuple[list[str], str]] = []
        self.style = ""
        self._in: str | None = None

    def handle_starttag(self, tag, attrs):
        classes = (dict(attrs).get("class") or "").split()
        if tag == "p" and "summary" in classes:
            self.boxes.append((classes, ""))
            self._in = "p"
        elif tag == "style":
            self._in = "style"

    def handle_endtag(self, tag):
        if tag in ("p", "style"):
            self._in = None

    def handle_data(self, data):
        if self._in == "p":
            classes, text = self.boxes[-1]
            self.boxes[-1] = (classes, text + data)
        elif self._in == "style":
            self.style += data


def read_page(path: Path) -> Boxes:
    b = Boxes()
    b.feed(path.read_text())
    return b


def css_rule(style: str, selector: str) -> dict[str, str]:
    m = re.search(re.escape(selector) + r"\s*\{([^}]*)\}", style)
    assert m, f"no CSS rule for {selector}"
    return {k.strip(): v.strip() for k, v in (d.split(":", 1) for d in m.group(1).split(";") if ":" in d)}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> dict[str, Path]:
    """A projector-on run and a projector-off run of one camera: k and lambda differ by ~100 s.e."""
    root = tmp_path_factory.mktemp("tiny")
    out = {}
    for name, seed, on in (("on-1", 1, True), ("off", 9, False)):
        out[name] = root / f"{name}.h5"
        record_perpendicular(out[name], seed=seed, width=32, frames=8, stops_m=STOPS, exposure_us=3300.0, gain=32.0,
                             projector_on=on)
    return out


def test_a_verdict_beyond_noise_is_never_in_a_green_box_and_full_reports_wrap(tiny, tmp_path):
    r = rig_in_process("compare", tiny["on-1"], tiny["off"], "--jobs", "1", "--plot", tmp_path / "c.png",
                       "--report", tmp_path / "differ", "-q")
    assert r.returncode == 0, r.stderr
    page = read_page(tmp_path / "differ" / "compare.html")
    [(classes, text)] = page.boxes
    assert "k differs by" in text and "verdict-beyond" in classes
    beyond, within = css_rule(page.style, ".verdict-beyond"), css_rule(page.style, ".verdict-within")
    assert beyond["background"] != within["background"] and beyond["border-color"] != within["border-color"]
    # the "Full report" block wraps its long lines instead of running off the page's right edge
    pre = css_rule(page.style, "pre")
    assert pre["white-space"] == "pre-wrap" and pre["overflow-wrap"] == "anywhere"
    # the alike pair's box is green: tests/test_recordings_compared.py
