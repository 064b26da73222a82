"""Small widgets, one job each. They show values; they compute nothing about the camera."""

from __future__ import annotations

import math
from typing import Iterable, Sequence

from rich.segment import Segment
from rich.style import Style as RichStyle
from rich.table import Table
from rich.text import Text
from textual.binding import Binding
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.strip import Strip
from textual.widgets import DataTable, Label, OptionList, ProgressBar, SelectionList, Static
from textual_plotext import PlotextPlot

from rig.diagnosis import Headline

from .live import RunState, format_duration
from .results_service import BinRow, CandidateRow, FitRow, HistoryEntry, ShapeCurve


class StatusLine(Static):
    """One line of what just happened; its class says how it went (info, ok, busy, error)."""

    LEVELS = ("info", "ok", "busy", "error")

    def show(self, text: str, level: str = "info") -> None:
        for lv in self.LEVELS:
            self.set_class(lv == level, f"-{lv}")
        self.update(Text(text))

    @property
    def text(self) -> str:
        return str(self.render())


class KeyValues(Static):
    """Label/value rows, e.g. a device's read-back. `plain` holds them as text."""

    plain = ""

    def show_rows(self, rows: Iterable[tuple[str, str]], title: str = "") -> None:
        rows = list(rows)
        self.plain = "\n".join([title] * bool(title) + [f"{k}: {v}" for k, v in rows])
        t = Table.grid(padding=(0, 1))
        t.add_column(style="bold", no_wrap=True)
        t.add_column(overflow="fold")
        if title:
            t.add_row(Text(title, style="underline"), "")
        for k, v in rows:
            t.add_row(k, v)
        self.update(t)


class SigmaPlot(PlotextPlot):
    """Sigma at the image centre against range, one point per completed stop."""

    def on_mount(self) -> None:
        self.show_points([])

    def show_points(self, points: Sequence[tuple[float, float]]) -> None:
        plt = self.plt
        plt.clear_data()
        plt.clear_figure()
        plt.title("sigma at the centre vs range")
        plt.xlabel("Z [m]")
        plt.ylabel("sigma [mm]")
        pts = [(z, s * 1000) for z, s in points if math.isfinite(z) and math.isfinite(s)]
        if pts:
            z, s = zip(*pts)
            plt.plot(list(z), list(s), marker="braille")
            plt.scatter(list(z), list(s), marker="dot")
            lo, hi = min(z), max(z)
            pad = max(0.05, 0.05 * (hi - lo))
            plt.xlim(lo - pad, hi + pad)
            plt.ylim(0, max(s) * 1.1)
        else:
            plt.xlim(0, 3.5)
            plt.ylim(0, 1)
        self.points = pts
        self.refresh()


def headline_words(headline: Headline) -> str:
    """A headline error as the chart shows it: "1.10 % ok" within noise, "11.36 %" beyond, "not judged" where no
    bin holds enough pixels to compare sigma in (a recording a few pixels wide; its error is nan)."""
    if not headline.judged:
        return "not judged"
    return f"{headline.error_pct:.2f} %{' ok' if headline.within_noise else ''}"


class HeadlineChart(Static):
    """The headline error after each change of the model, as bars, with the level noise alone gives.
    A change whose error is within noise says "ok" (the bar's colour says it too). The bars take the width
    the chart has, so the numbers beside them are never cut."""

    plain = ""
    history: Sequence[HistoryEntry] = ()

    def show_history(self, history: Sequence[HistoryEntry]) -> None:
        self.history = list(history)
        self.plain = "\n".join(f"{h.change}: {headline_words(h.headline)}" for h in history)
        if not history:
            self.update("")
            return
        label_w, value_w = 14, len("100.00 % ok")
        width = max(4, (self.content_size.width or 37) - label_w - value_w - 2)
        top = max((h.headline.error_pct for h in history if h.headline.judged), default=0.0) or 1.0
        t = Table.grid(padding=(0, 1))
        t.add_column(width=label_w, overflow="fold")
        t.add_column(no_wrap=True, width=width)
        t.add_column(no_wrap=True, width=value_w)
        for h in history:  # no bar where nothing was judged (the error is nan there)
            n = min(h.headline.error_pct / top, 1.0) * width if h.headline.judged else 0.0
            bar = "█" * int(n) + ("▌" if n - int(n) >= 0.5 else "")
            style = "green" if h.headline.within_noise else "red"
            t.add_row(h.change, Text(bar, style=style), headline_words(h.headline))
        last = history[-1].headline
        t.add_row("noise alone", "", f"{last.noise_pct:.2f} %" if last.judged else "-")
        self.update(t)

    def on_resize(self) -> None:
        if self.history:
            self.show_history(self.history)


class ShapePlot(PlotextPlot):
    """The shape of what the catalogue does not explain: the empirical sigma multiplier along its covariate.
    Hidden when everything is explained."""

    title = ""

    def on_mount(self) -> None:
        self.show_shape(None)

    def show_shape(self, shape: ShapeCurve | None) -> None:
        self.display = shape is not None
        self.title = shape.title if shape is not None else ""
        plt = self.plt
        plt.clear_data()
        plt.clear_figure()
        if shape is not None:
            plt.title(shape.title)
            plt.xlabel(f"{shape.covariate} [{shape.unit}]")
            plt.ylabel("sigma x")
            plt.plot(shape.x, shape.multiplier, marker="braille")
        self.refresh()


class FitTable(Static):
    """The fitted parameters and their standard errors. Numbers are never cut: a long parameter name
    folds onto a second line instead."""

    plain = ""

    def on_mount(self) -> None:
        self.show_rows([])

    def show_rows(self, rows: Sequence[FitRow]) -> None:
        self.plain = "\n".join(f"{r.name} {r.value} {r.se}" for r in rows)
        t = Table(box=None, padding=(0, 1), show_edge=False, header_style="bold")
        t.add_column("parameter", overflow="fold", ratio=1)
        t.add_column("value", no_wrap=True, min_width=max([len(r.value) for r in rows] + [5]))
        t.add_column("+/- se", no_wrap=True, min_width=max([len(r.se) for r in rows] + [6]))
        for r in rows:
            t.add_row(r.name, r.value, r.se)
        self.update(t)


class BinTable(DataTable):
    """Measured over predicted sigma by radius and by range (* = off by more than 3 se)."""

    def on_mount(self) -> None:
        self.cursor_type = "none"
        self.add_columns("bin", "meas/pred", "+/-", "")

    def show_rows(self, rows: Sequence[BinRow]) -> None:
        self.clear()
        section = None
        for r in rows:
            if r.section != section:
                section = r.section
                self.add_row(Text(f"by {section}", style="bold underline"), "", "", "")
            self.add_row(r.label, f"{r.ratio:.3f}", f"{r.pm:.3f}", Text("*", style="bold red") if r.flagged else "")


class EffectList(SelectionList[str]):
    """Effects: those in the model are checked; the others ranked by evidence. Space adds or removes.
    Each line says its state in words: [x] checked (in the next fit), [ ] not, not only by colour."""

    BINDINGS = [Binding("space", "select", "Tick effect")]

    def show_rows(self, rows: Sequence[CandidateRow]) -> None:
        """Show `rows`; the same effects again (after a refit) keep the highlighted line, new ones start at the top."""
        same = [r.effect for r in rows] == [self.get_option_at_index(i).value for i in range(self.option_count)]
        keep = self.highlighted if same else None
        self.clear_options()
        self.add_options([(r.prompt(), r.effect, r.in_model) for r in rows])
        if rows:
            self.highlighted = keep if keep is not None else 0

    def checked(self) -> list[str]:
        """Checked effects in list order (those already in the model first)."""
        chosen = set(self.selected)
        return [self.get_option_at_index(i).value for i in range(self.option_count)
                if self.get_option_at_index(i).value in chosen]

    def mark(self, index: int) -> str:
        """The line's state in words."""
        return "[x]" if self.get_option_at_index(index).value in self.selected else "[ ]"

    def render_line(self, y: int) -> Strip:
        """Textual's line without its coloured toggle, with [x] or [ ] in front instead."""
        line = OptionList.render_line(self, y)
        index = self.scroll_offset.y + y
        if not 0 <= index < self.option_count:
            return line
        style = next(iter(line)).style if line.cell_length else self.rich_style
        return Strip([Segment(self.mark(index) + " ", style + RichStyle(meta={"option": index})), *line])


class RunProgress(Vertical):
    """Where the run is: a bar over stops and one over the current stop's frames."""

    def compose(self) -> ComposeResult:
        yield Label("stops", id="stops-label")
        yield ProgressBar(total=1, show_eta=False, id="stops-bar")
        yield Label("frames", id="frames-label")
        yield ProgressBar(total=1, show_eta=False, id="frames-bar")

    def show_state(self, s: RunState) -> None:
        stop = f"  now {s.stop}" if s.stop and s.active else ""
        self.query_one("#stops-label", Label).update(f"stops {s.stops_done}/{s.n_stops}{stop}")
        self.query_one("#stops-bar", ProgressBar).update(total=max(s.n_stops, 1), progress=s.stops_done)
        self.query_one("#frames-label", Label).update(f"frames {s.frame}/{s.n_frames}")
        self.query_one("#frames-bar", ProgressBar).update(total=max(s.n_frames, 1), progress=s.frame)


class LiveStats(KeyValues):
    """The current stop's fill rate and sigma at the centre, time, and frames lost."""

    def show_state(self, s: RunState) -> None:
        def num(x: float, fmt: str) -> str:
            return fmt.format(x) if math.isfinite(x) else "-"

        self.show_rows([
            ("fill rate", num(100 * s.fill_rate, "{:.1f} %")),
            ("sigma centre", num(1000 * s.centre_sigma_m, "{:.3f} mm")),
            ("range centre", num(s.centre_mean_m, "{:.3f} m")),
            ("elapsed", format_duration(s.elapsed_s)),
            ("remaining", format_duration(s.remaining_s) if s.active or s.status == "done" else "--:--"),
            ("dropped", str(s.dropped)),
            ("refused", f"{s.refused} (wrong settings)"),
            ("output", s.output or "-"),
        ])
