"""A spec's lines judged against one recording's figures, each with the measurement's own error.

The rule, per figure: the margin is the distance from the measured value to the limit, in the value's standard
errors, positive on the allowed side. A figure passes when its margin is above DECIDED_SE, fails when it is below
-DECIDED_SE, and is not decided between: the limit lies within DECIDED_SE standard errors of the value. A line of
several stops fails when one of them fails, else is not decided when one is, else passes; a line with nothing to
judge (lambda not determined, a range the fit does not reach, no stop in its span, no truth) is not decided, and
says why. A recording takes the worst of its lines, in the same order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .figures import RecordingFigures, sigma_at
from .spec import Line, Spec

#: a limit further than this many standard errors from the measured value decides the figure
DECIDED_SE = 2.0
#: a stop counts as in a line's span, and a range as in the fit's, within this share of the range
RANGE_TOLERANCE = 0.01

PASS, FAIL, NOT_DECIDED, ERROR = "pass", "fail", "not decided", "error"

#: exit status of `rig check`: every line of every recording passes; one fails; a recording cannot be read (or the
#: command is given wrongly); none fails, and one is not decided
EXIT_PASS, EXIT_FAIL, EXIT_UNREADABLE, EXIT_NOT_DECIDED = 0, 1, 2, 3
#: the verdict the exit status stands for
OVERALL = {EXIT_PASS: PASS, EXIT_FAIL: FAIL, EXIT_UNREADABLE: ERROR, EXIT_NOT_DECIDED: NOT_DECIDED}


@dataclass(frozen=True)
class Item:
    """One figure a line judges: at `where` (a stop's label, or the range the fit is read at), range `z_m`, the
    measured `value` and its standard error `se` in the line's unit, and the margin in standard errors."""

    where: str
    z_m: float
    value: float
    se: float
    margin_se: float
    verdict: str


@dataclass(frozen=True)
class LineVerdict:
    line: Line
    verdict: str
    items: tuple[Item, ...] = ()
    reason: str = ""  # why the line is not decided when no figure could decide it ("" otherwise)

    @property
    def worst(self) -> Item | None:
        """The figure nearest to failing (the smallest margin), None without figures."""
        judged = [i for i in self.items if not math.isnan(i.margin_se)]
        return min(judged, key=lambda i: i.margin_se) if judged else (self.items[0] if self.items else None)


@dataclass(frozen=True)
class RecordingVerdict:
    path: str
    verdict: str
    lines: tuple[LineVerdict, ...] = ()
    notes: tuple[str, ...] = ()
    error: str = ""


def judge(margin_se: float) -> str:
    """The rule (see the module) for one figure's margin, in standard errors."""
    if margin_se > DECIDED_SE:
        return PASS
    if margin_se < -DECIDED_SE:
        return FAIL
    return NOT_DECIDED


def worst_of(verdicts: list[str]) -> str:
    """fail over not decided over pass; nothing to judge is not decided."""
    if not verdicts:
        return NOT_DECIDED
    for v in (ERROR, FAIL, NOT_DECIDED):
        if v in verdicts:
            return v
    return PASS


def margin(value: float, se: float, line: Line) -> float:
    """(limit - value) / se for an upper limit, (value - limit) / se for a lower one; with no error (se 0) the side
    alone (+-inf, NaN on the limit); NaN where the value or its error is not known."""
    inside = line.limit - value if line.bound == "max" else value - line.limit
    if not (math.isfinite(inside) and math.isfinite(se) and se >= 0):
        return math.nan
    if se == 0:
        return math.copysign(math.inf, inside) if inside else math.nan
    return inside / se


def evaluate(spec: Spec, f: RecordingFigures) -> RecordingVerdict:
    """Every line of `spec` judged on the recording's figures `f`."""
    if f.error:
        return RecordingVerdict(f.path, ERROR, error=f.error, notes=tuple(f.notes))
    lines = tuple({"sigma": _sigma, "fill": _fill, "accuracy": _accuracy}[line.kind](line, f) for line in spec.lines)
    return RecordingVerdict(f.path, worst_of([v.verdict for v in lines]), lines, tuple(f.notes))


def _item(line: Line, where: str, z_m: float, value: float, se: float) -> Item:
    m = margin(value, se, line)
    return Item(where, z_m, value, se, m, judge(m))


def _line(line: Line, items: list[Item], reason: str = "") -> LineVerdict:
    if not items:
        return LineVerdict(line, NOT_DECIDED, (), reason)
    return LineVerdict(line, worst_of([i.verdict for i in items]), tuple(items), reason)


def _sigma(line: Line, f: RecordingFigures) -> LineVerdict:
    """The fit's sigma at the line's range judged; where a stop lies at that range, its own measured sigma too, and
    the line is decided only where both decide alike (a fit that misses the stop's sigma does not decide it)."""
    z = line.at_z_m
    scale = 100.0 / z if line.key == "sigma_pct_of_z_max" else 1e3  # % of Z, or mm
    sigma_m, se_m = sigma_at(f, z)
    fit = _item(line, f"{z:g} m (fit)", z, scale * sigma_m, scale * se_m)
    lo, hi = f.z_range_m
    if f.lambda_problem:
        return LineVerdict(line, NOT_DECIDED, (_undecided(fit),), f.lambda_problem)
    if not lo * (1 - RANGE_TOLERANCE) <= z <= hi * (1 + RANGE_TOLERANCE):
        return LineVerdict(line, NOT_DECIDED, (_undecided(fit),),
                           f"{z:g} m is outside the fitted ranges, {lo:.2f}-{hi:.2f} m, and the fit is not "
                           f"extrapolated; record stops that reach {z:g} m")
    at = [m for m in f.measured_sigma if abs(m[1] - z) <= RANGE_TOLERANCE * z]
    if not at:
        return _line(line, [fit])
    label, z_stop, sigma_stop, se_stop = min(at, key=lambda m: abs(m[1] - z))
    stop = _item(line, f"the {label} stop (measured)", z_stop, scale * sigma_stop, scale * se_stop)
    if stop.verdict == fit.verdict:
        return _line(line, [fit, stop])
    return LineVerdict(line, NOT_DECIDED, (fit, stop),
                       f"the fit ({fit.verdict}) and the stop's own sigma ({stop.verdict}) decide differently: the "
                       f"power law misses the stop's sigma by {abs(fit.value - stop.value) / stop.se:.3g} of its "
                       f"standard errors (rig diagnose says what is missing)")


def _undecided(i: Item) -> Item:
    return Item(i.where, i.z_m, i.value, i.se, i.margin_se, NOT_DECIDED)


def _in_span(line: Line, z_m: float) -> bool:
    lo = line.from_z_m * (1 - RANGE_TOLERANCE) if line.from_z_m is not None else -math.inf
    hi = line.to_z_m * (1 + RANGE_TOLERANCE) if line.to_z_m is not None else math.inf
    return lo <= z_m <= hi or (line.from_z_m is None and line.to_z_m is None)


def _no_stop(line: Line, f: RecordingFigures, what: str) -> str:
    known = [s.z_m for s in f.stops if math.isfinite(s.z_m)]
    span = f"{min(known):.2f}-{max(known):.2f} m" if known else "none at a known range"
    return f"no stop {what} lies in the line's span (the recording's stops: {span}); record stops there"


def _fill(line: Line, f: RecordingFigures) -> LineVerdict:
    stops = [s for s in f.stops if _in_span(line, s.z_m)]
    items = [_item(line, s.stop, s.z_m, 100.0 * s.fill, 100.0 * s.fill_se) for s in stops]
    return _line(line, items, "" if items else _no_stop(line, f, "at a known range"))


def _accuracy(line: Line, f: RecordingFigures) -> LineVerdict:
    if f.accuracy_why_not:
        return LineVerdict(line, NOT_DECIDED, (), f"accuracy not measured: {f.accuracy_why_not}")
    stops = [s for s in f.stops if _in_span(line, s.z_m) and math.isfinite(s.depth_accuracy_pct)]
    items = [_item(line, s.stop, s.z_m, abs(s.depth_accuracy_pct), s.depth_accuracy_se_pct) for s in stops]
    return _line(line, items, "" if items else _no_stop(line, f, "whose distance is known"))


def exit_status(verdicts: list[RecordingVerdict]) -> int:
    """EXIT_UNREADABLE when a recording cannot be read, else EXIT_FAIL when a line fails anywhere, else
    EXIT_NOT_DECIDED when one is not decided, else EXIT_PASS."""
    overall = worst_of([v.verdict for v in verdicts])
    return {v: k for k, v in OVERALL.items()}[overall]
