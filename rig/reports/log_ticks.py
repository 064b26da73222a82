"""Tick labels on a logarithmic axis that a reader can read values off ("%g"): each power of ten over more than three
decades, 1, 2 and 5 of each decade over fewer, and, when that gives fewer than two labels (an axis spanning less than
a factor of 2.5), four values spread evenly in the logarithm (two significant digits). Matplotlib's default labels
only powers of ten: one tick, or none, over 0.5-3 m."""

from __future__ import annotations

import matplotlib.ticker as ticker
import numpy as np

#: the fewest labelled ticks a log axis shows
MIN_LABELS = 2


def label_log_axis(axis) -> None:
    """Label `axis` (a matplotlib XAxis or YAxis already on a log scale, its data plotted) as the module says."""
    low, high = sorted(axis.get_view_interval())
    decades = np.log10(high / low) if low > 0 else np.inf
    axis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0,) if decades > 3 else (1.0, 2.0, 5.0)))
    axis.set_major_formatter(ticker.FormatStrFormatter("%g"))
    axis.set_minor_locator(ticker.LogLocator(base=10, subs=np.arange(1.0, 10.0)))
    axis.set_minor_formatter(ticker.NullFormatter())
    if len(shown_ticks(axis)) < MIN_LABELS and low > 0:
        values = [float(f"{v:.2g}") for v in np.geomspace(low, high, 6)[1:-1]]
        axis.set_major_locator(ticker.FixedLocator(sorted(set(values))))


def shown_ticks(axis) -> list[float]:
    """The major tick values inside the axis' view."""
    low, high = sorted(axis.get_view_interval())
    return [v for v in axis.get_major_locator()() if low <= v <= high]
