"""A check's verdicts as text (a block per recording, then the fleet's summary) and as `rig.check/1` JSON
(docs/check.md; numbers that are not finite are null, as in every rig document)."""

from __future__ import annotations

from dataclasses import asdict

from .. import package_version
from .spec import Line, Spec
from .verdicts import (DECIDED_SE, ERROR, FAIL, NOT_DECIDED, OVERALL, PASS, RANGE_TOLERANCE, LineVerdict,
                       RecordingVerdict)

SCHEMA = "rig.check/1"
RULE = (f"a figure passes or fails when its limit is more than {DECIDED_SE:g} standard errors from the measured value, "
        "and is not decided nearer")
VERDICTS = (PASS, FAIL, NOT_DECIDED)


def line_text(v: LineVerdict) -> list[str]:
    """A line's verdict in a line of text: every figure of a sigma line, the nearest to failing of a line of stops;
    and its reason, where it has one."""
    out = f"  {v.verdict.upper() if v.verdict == FAIL else v.verdict:<12} {v.line.label}"
    shown = list(v.items) if v.line.kind == "sigma" else [v.worst] if v.items else []
    out += "".join(f"{': ' if n == 0 else '; '}{_figure(i, v.line.unit)}" for n, i in enumerate(shown))
    if v.line.kind != "sigma" and len(v.items) > 1:
        failed = sum(i.verdict == FAIL for i in v.items)
        open_ = sum(i.verdict == NOT_DECIDED for i in v.items)
        out += f" (the nearest of {len(v.items)} stops; {failed} fail, {open_} not decided)"
    return [out] + ([f"  {'':<12} why: {v.reason}"] if v.reason else [])


def _figure(i, unit: str) -> str:
    """"0.7984 +/- 0.0018 % of Z at 2 m (fit), 674 s.e. inside"."""
    text = f"{i.value:.4g} +/- {i.se:.2g} {unit} at {i.where}"
    if i.margin_se == i.margin_se:  # not NaN
        text += f", {abs(i.margin_se):.3g} s.e. {'inside' if i.margin_se >= 0 else 'outside'}"
    return text


def render(spec: Spec, verdicts: list[RecordingVerdict], status: int) -> str:
    """The text report: the spec and the rule, each recording's lines, and the fleet's summary for several."""
    out = [f"spec: {spec.path}" + (f" ({spec.name})" if spec.name else "") + f", {len(spec.lines)} lines; {RULE}"]
    for v in verdicts:
        out.append("")
        out.append(f"{v.path}: {v.verdict.upper() if v.verdict in (FAIL, ERROR) else v.verdict}")
        out += [f"  note: {n}" for n in v.notes]
        if v.error:
            out.append(f"  error: {v.error}")
        for line in v.lines:
            out += line_text(line)
    if len(verdicts) > 1:
        out += ["", _fleet_line(verdicts), f"  {'line':<48} {'pass':>5} {'fail':>5} {'not decided':>12}"]
        for label, counts in _by_line(spec, verdicts):
            out.append(f"  {label:<48} {counts[PASS]:>5} {counts[FAIL]:>5} {counts[NOT_DECIDED]:>12}")
    out += ["", f"verdict: {OVERALL[status].upper() if status else 'every line passes'} (exit {status})"]
    return "\n".join(out)


def _fleet_line(verdicts: list[RecordingVerdict]) -> str:
    counts = _count(v.verdict for v in verdicts)
    return (f"fleet: {len(verdicts)} recordings; {counts[PASS]} pass every line, {counts[FAIL]} fail, "
            f"{counts[NOT_DECIDED]} not decided" + (f", {counts[ERROR]} unreadable" if counts[ERROR] else ""))


def _count(verdicts) -> dict[str, int]:
    out = dict.fromkeys((*VERDICTS, ERROR), 0)
    for v in verdicts:
        out[v] += 1
    return out


def _by_line(spec: Spec, verdicts: list[RecordingVerdict]) -> list[tuple[str, dict[str, int]]]:
    """Each line's verdicts over the recordings that could be read."""
    read = [v for v in verdicts if not v.error]
    return [(line.label, _count(v.lines[i].verdict for v in read)) for i, line in enumerate(spec.lines)]


def _line_json(line: Line) -> dict:
    return {"label": line.label, "text": line.text, **asdict(line)}


def document(spec: Spec, verdicts: list[RecordingVerdict], status: int) -> dict:
    """The `rig.check/1` document (docs/check.md)."""
    return {
        "schema": SCHEMA, "command": "check", "rig_version": package_version(),
        "spec": {"file": spec.path, "name": spec.name, "lines": [_line_json(line) for line in spec.lines]},
        "rule": {"decided_se": DECIDED_SE, "range_tolerance": RANGE_TOLERANCE},
        "recordings": [{
            "file": v.path, "verdict": v.verdict, "error": v.error or None, "notes": list(v.notes),
            "lines": [{"label": lv.line.label, "verdict": lv.verdict, "reason": lv.reason or None,
                       "items": [asdict(i) for i in lv.items]} for lv in v.lines],
        } for v in verdicts],
        "summary": {
            "verdict": OVERALL[status], "exit_status": status,
            "recordings": {k.replace(" ", "_"): n for k, n in _count(v.verdict for v in verdicts).items()},
            "lines": [{"label": label, **{k.replace(" ", "_"): counts[k] for k in VERDICTS}}
                      for label, counts in _by_line(spec, verdicts)],
        },
    }
