"""A verdict's state and the colour a report shows it in: green within noise, red beyond, grey where nothing was
judged (too few pixels, lambda not determined, no model that fits). The HTML pages mark a verdict with the CSS class
`verdict-<state>` (`html_page.STYLE`); the plots take the same colours, so a bad verdict is never green."""

from __future__ import annotations

import math

WITHIN, BEYOND, UNJUDGED = "within", "beyond", "unjudged"

#: state -> (background, border) in the HTML and the plots' colour (matplotlib's named colours)
COLOURS = {WITHIN: ("#eef6ee", "#3a3", "tab:green"), BEYOND: ("#fbeaea", "#c33", "tab:red"),
           UNJUDGED: ("#f0f0f0", "#888", "0.6")}


def headline_state(headline) -> str:
    """The state of a `Headline` (rig.diagnosis.scores): its `state` words in one of the three."""
    return {"within noise": WITHIN, "beyond noise": BEYOND}.get(headline.state, UNJUDGED)


def plot_colour(state: str) -> str:
    return COLOURS[state][2]


def pair_state(pair) -> str:
    """A compared pair (rig.recordings.comparison.Pair): unjudged without a verdict in standard errors or a shared
    parameter, beyond when a parameter differs, within otherwise."""
    if pair.not_judged() or not pair.parameters:
        return UNJUDGED
    return BEYOND if any(d.differs for d in pair.parameters) else WITHIN


def repeatability_state(scatters, caution: str | None) -> str:
    """Runs: beyond when a parameter scatters beyond its errors, unjudged when the model does not fit the runs
    (`misfit_caution`: their errors do not hold), within otherwise."""
    if any(math.isfinite(s.p) and not s.honest for s in scatters):
        return BEYOND
    return UNJUDGED if caution else WITHIN
