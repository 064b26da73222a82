"""The reports' pictures as a person sees them: a verdict's box coloured by its state (never green when beyond
noise), "Full report" text wrapped, not clipped, every axis with its unit. Read with the standard library's HTML
parser and matplotlib's own artists, on tiny recordings (32 px wide, 8 frames a stop)."""

from __future__ import annotations

import re
from html.parser import HTMLParser
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
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
    """Two projector-on runs of one camera (seeds 1, 2), and a projector-off run: k and lambda differ by ~100 s.e."""
    root = tmp_path_factory.mktemp("tiny")
    out = {}
    for name, seed, on in (("on-1", 1, True), ("on-2", 2, True), ("off", 9, False)):
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


@pytest.fixture(scope="module")
def fitted(tiny):
    from rig.fleet.many import fit_for_comparison
    from rig.recordings.recording_fits import FitJob

    return [fit_for_comparison(FitJob(str(tiny[n]))) for n in ("on-1", "on-2")]


def kept(monkeypatch, draw) -> list:
    """The figures `draw()` saves, kept open (plt.close a no-op while it runs) to read their artists."""
    before = set(plt.get_fignums())
    monkeypatch.setattr(plt, "close", lambda *a, **k: None)
    draw()
    monkeypatch.undo()
    figs = [plt.figure(n) for n in plt.get_fignums() if n not in before]
    assert figs
    return figs


def labelled_ticks(axis) -> list[str]:
    """The texts of the major tick labels a reader sees: inside the view, not empty."""
    low, high = sorted(axis.get_view_interval())
    return [t.get_text() for t, v in zip(axis.get_ticklabels(), axis.get_majorticklocs())
            if low <= v <= high and t.get_visible() and t.get_text()]


def test_every_axis_has_its_unit_and_a_log_axis_several_labels(fitted, monkeypatch, tmp_path):
    from rig.reports.comparison_plots import plot_overlay

    [fig] = kept(monkeypatch, lambda: plot_overlay(fitted, tmp_path / "overlay.png"))
    try:
        for ax in fig.axes:
            assert ax.get_xlabel() == "Z [m]" and ax.get_ylabel() == "σ_Z [mm]"
        loglog = fig.axes[1]
        assert loglog.get_xscale() == loglog.get_yscale() == "log"
        # 0.5-2 m and ~1-13 mm: matplotlib's default would label 1 (m) alone and 1, 10 (mm)
        x, y = labelled_ticks(loglog.xaxis), labelled_ticks(loglog.yaxis)
        assert len(x) >= 3 and len(y) >= 3, (x, y)
        assert [float(t) for t in x] == sorted(float(t) for t in x)  # numbers, in order
    finally:
        plt.close(fig)


def test_the_repeatability_plot_names_its_runs_gives_units_and_keeps_the_legend_off_them(fitted, monkeypatch,
                                                                                          tmp_path):
    from rig.recordings.comparison import scatter
    from rig.reports.comparison_plots import plot_runs

    scatters = scatter(fitted)
    [fig] = kept(monkeypatch, lambda: plot_runs(fitted, scatters, tmp_path / "runs.png"))
    try:
        panels = {ax.get_title().split(":")[0]: ax for ax in fig.axes}
        assert panels["k"].get_ylabel() == "k [m^(1-lambda)]" and panels["lambda"].get_ylabel() == "lambda [1]"
        fig.canvas.draw()
        legend = fig.legends[0].get_window_extent()
        for ax in fig.axes:
            assert [t.get_text() for t in ax.get_xticklabels()] == ["on-1.h5", "on-2.h5"]
            assert "[" in ax.get_ylabel() and "?" not in ax.get_ylabel()
            points = ax.transData.transform(ax.lines[0].get_xydata())  # the runs' markers, in pixels
            assert not any(legend.contains(px, py) for px, py in points)
            assert not legend.overlaps(ax.get_window_extent())
    finally:
        plt.close(fig)


@pytest.mark.parametrize("low, high, least", [(1.1, 1.9, 2), (0.3, 3.0, 3), (0.1, 1e5, 5)])
def test_a_log_axis_of_any_span_has_several_labelled_ticks(low, high, least):
    from rig.reports.log_ticks import label_log_axis

    fig, ax = plt.subplots()
    try:
        ax.set_yscale("log")
        ax.plot([0, 1], [low, high])
        label_log_axis(ax.yaxis)
        fig.canvas.draw()
        shown = labelled_ticks(ax.yaxis)
        assert least <= len(shown) <= 12, shown  # several, and not a crowd
        assert all(low * 0.9 <= float(t) <= high * 1.1 for t in shown)
    finally:
        plt.close(fig)


def test_a_spatially_constant_sigma_map_says_its_value_instead_of_a_colour_bar(small_recording, monkeypatch,
                                                                               tmp_path):
    """The paper's model, k Z^lambda, has no term over the image: its map is one number a range, not a colour scale
    stretched over float rounding."""
    from rig.noise_model import NoiseModel
    from rig.reports.sigma_map import write_sigma_maps

    out = tmp_path / "m.json"
    assert rig_in_process("export", small_recording, "-o", out, "--jobs", "1", "-q").returncode == 0
    model = NoiseModel.load(out)
    [fig] = kept(monkeypatch, lambda: write_sigma_maps(model, [0.5, 2.0], tmp_path / "m.sigma-map"))
    try:
        panels = [ax for ax in fig.axes if ax.get_title().startswith("Z = ")]
        assert len(panels) == 2 and len(fig.axes) == 2  # no colour bar's axes
        k, lam = (model.doc["parameters"][i]["value"] for i in (0, 1))
        for ax, z in zip(panels, (0.5, 2.0)):
            assert not ax.images
            [text] = [t.get_text() for t in ax.texts]
            value_mm = float(text.split(":\n")[1].split(" mm")[0])
            assert text.startswith("constant over the image:")
            # the value shown is k Z^lambda to its 4 printed digits (rounding: half a unit in the 4th, 5e-4)
            assert value_mm == pytest.approx(1e3 * k * z**lam, rel=5e-4)
            assert ax.get_xlabel() == "u (px)" and ax.get_ylabel() == "v (px)"
    finally:
        plt.close(fig)


@pytest.mark.slow  # 3-4 s: a diagnosis runs every candidate effect
def test_the_before_after_plot_shows_a_radial_effects_error_by_radius(monkeypatch, tmp_path):
    """A hidden slant_range (sigma grows with the ray's length, so with the radius): by range the start and final
    curves overlap; by radius the start's residual climbs across the image and the final's is flat."""
    from rig.cli import main

    rec = tmp_path / "s.h5"
    assert main(["simulate", "--seed", "2", "--effect", "slant_range", "--width", "32", "--frames", "8", str(rec)]) == 0
    figs = kept(monkeypatch, lambda: main(["diagnose", str(rec), "--out", str(tmp_path / "rep")]))
    try:
        [fig] = [f for f in figs if any(ax.get_title().startswith("by radius") for ax in f.axes)]
        by = {ax.get_title().split(":")[0]: ax for ax in fig.axes}
        assert by["by range"].get_xlabel() == "Z [m]" and by["by radius"].get_xlabel() == "ρ = radius / f [1]"
        curves = lambda ax: {c.get_label(): c.lines[0].get_ydata() for c in ax.containers}  # noqa: E731 (errorbars)
        lines = curves(by["by radius"])
        start, final = lines["active"], lines["active+slant_range"]
        spread = lambda y: float(np.ptp(y))  # noqa: E731  (percent of ln sigma)
        assert spread(start) > 15 and spread(start) > 4 * spread(final), lines
        ranges = curves(by["by range"])
        assert len(ranges) == 2 and spread(ranges["active"]) < spread(start) / 4  # by range the effect is hidden
    finally:
        for f in figs:
            plt.close(f)


def test_the_fit_page_has_a_measured_over_predicted_panel(small_recording, monkeypatch, tmp_path):
    figs = kept(monkeypatch, lambda: rig_in_process("fit", small_recording, "--report", tmp_path / "rep", "-q"))
    try:
        page = (tmp_path / "rep" / "fit.html").read_text()
        assert '<img alt="fit-measured-predicted"' in page and page.count("data:image/png;base64,") == 2
        [fig] = [f for f in figs if any(ax.get_ylabel() == "σ measured / σ predicted [1]" for ax in f.axes)]
        assert [(ax.get_title(), ax.get_xlabel()) for ax in fig.axes] == [("by range", "Z [m]"),
                                                                         ("by radius", "ρ = radius / f [1]")]
        fig.canvas.draw()
        legend = fig.axes[0].get_legend().get_window_extent()
        for ax in fig.axes:
            [points] = ax.containers
            ratio = points.lines[0].get_ydata()
            low, high = ax.get_ylim()
            assert low < 1 < high and np.all((low < ratio) & (ratio < high))  # 1 and every point in view
            assert not any(legend.contains(*px) for px in ax.transData.transform(points.lines[0].get_xydata()))
    finally:
        for f in figs:
            plt.close(f)


#: what a person's browser window might be: half a laptop's screen
VIEWPORT = (800, 600)
PROBE = """<script>
const boxes = [...document.querySelectorAll('pre, table')];
document.body.dataset.page = [document.documentElement.scrollWidth, document.documentElement.clientWidth].join(' ');
document.body.dataset.pre = boxes.filter(b => b.tagName == 'PRE').map(b => [b.scrollWidth, b.clientWidth].join(' ')).join(';');
</script></body>"""


@pytest.mark.slow  # 3 s wall: Chromium starts (0.5 s of its CPU), after a fit
def test_a_report_rendered_by_chromium_fits_the_window_and_hides_no_text(small_recording, tmp_path):
    """The fit page in headless Chromium (Debian's chromium) at 800 x 600: the page is no wider than the window, and
    the "Full report" block (lines of 250 characters) shows every line whole: its scroll width is its width. A small
    script added at the end of a copy of the page writes what the browser laid out into the DOM Chromium dumps."""
    import resource
    import shutil
    import subprocess

    browser = shutil.which("chromium")
    assert browser, "this test renders a report in Chromium: install it (Debian: apt-get install chromium)"
    r = rig_in_process("fit", small_recording, "--report", tmp_path / "rep", "-q")
    assert r.returncode == 0, r.stderr
    page = (tmp_path / "rep" / "fit.html").read_text()
    assert max(map(len, page.split("<pre>")[1].splitlines())) > 150  # a line wider than the window, to wrap
    probe = tmp_path / "probe.html"
    probe.write_text(page.replace("</body>", PROBE))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    dom = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", f"--user-data-dir={tmp_path / 'profile'}",
                          f"--window-size={VIEWPORT[0]},{VIEWPORT[1]}", "--dump-dom", probe.as_uri()],
                         capture_output=True, text=True, timeout=60).stdout
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(f"chromium CPU {after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime:.2f} s")
    scroll, client = map(int, re.search(r'data-page="(\d+) (\d+)"', dom).groups())
    assert 0 < client <= VIEWPORT[0] and scroll <= client, (scroll, client)  # no sideways scrolling of the page
    [pre] = re.search(r'data-pre="([^"]*)"', dom).group(1).split(";")
    pre_scroll, pre_client = map(int, pre.split())
    assert pre_scroll <= pre_client, pre  # nothing of the full report hidden to the right
