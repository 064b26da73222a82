"""GRBL 1.1 real-time status reports (`<Idle|MPos:1.000,0.000,0.000|FS:0,0>`), parsed strictly.

What a report holds (gnea/grbl doc/markdown/interface.md, "Real-time Status Reports"; grbl/report.c,
report_realtime_status):
- the state: Idle, Run, Hold:0 or Hold:1, Jog, Alarm, Door:0-3, Check, Home, Sleep. `Hold:0` means the
  hold is complete and ready to resume; `Hold:1` that it is still decelerating, and "a reset will throw
  an alarm" (interface.md), i.e. ALARM:3 and a lost position;
- the position first: `MPos` (machine) when $10 bit 0 is set, else `WPos` (work), with WPos = MPos - WCO;
- `WCO`, the work offset, only in some reports: the first after a reset, then every 10th when idle and
  every 30th when busy (report.c, REPORT_WCO_REFRESH_IDLE_COUNT / _BUSY_COUNT), and `Ov` likewise
  (10 / 20), in the report after a WCO one;
- `Bf` (planner blocks, serial bytes free; $10 bit 1), `Ln`, `FS` (feed, spindle) or `F`, `Pn` (pins),
  `A` (accessories).

GRBL has no checksum, so a report garbled on the wire is caught by its shape alone: a flipped letter in a
field name (`MPPs`), a doubled separator (`MPos::5.964`), a number that is not one, a field that is not
GRBL's, or a field twice all give None, and the caller asks again.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_REPORT = re.compile(r"^<(Idle|Run|Hold:[01]|Jog|Alarm|Door:[0-3]|Check|Home|Sleep)((?:\|[^|<>]*)*)>$")
_NUMBER = r"-?\d+(?:\.\d+)?"
_AXES = rf"{_NUMBER}(?:,{_NUMBER}){{0,5}}"
#: each field GRBL 1.1 prints, with the shape of its value
_FIELDS = {
    "MPos": re.compile(_AXES), "WPos": re.compile(_AXES), "WCO": re.compile(_AXES),
    "Bf": re.compile(r"\d+,\d+"), "Ln": re.compile(r"\d+"), "FS": re.compile(rf"{_NUMBER},{_NUMBER}"),
    "F": re.compile(_NUMBER), "Pn": re.compile(r"[XYZABCPDHRS]+"), "Ov": re.compile(r"\d+,\d+,\d+"),
    "A": re.compile(r"[SCFM]+"),
}


@dataclass(frozen=True)
class StatusReport:
    """One report as the controller sent it, in its own units (mm, or inches with $13=1)."""

    #: "Idle", "Run", "Hold:0", "Hold:1", "Door:1", ...
    state: str
    #: the axes of MPos (machine=True) or WPos (machine=False)
    position: tuple[float, ...]
    machine: bool
    #: the work offset, in the reports that carry it
    wco: tuple[float, ...] | None
    #: the current feed rate, units/min (FS or F), if reported
    feed: float | None

    @property
    def kind(self) -> str:
        """The state without its sub-state: "Hold", "Door", "Idle", ..."""
        return self.state.split(":")[0]


def _axes(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split(","))


def parse_status(text: str) -> StatusReport | None:
    """The report in `text`, or None if it is not one GRBL 1.1 could have sent (garbled on the wire)."""
    match = _REPORT.match(text)
    if not match:
        return None
    fields: dict[str, str] = {}
    for item in match.group(2).split("|")[1:]:
        name, sep, value = item.partition(":")
        shape = _FIELDS.get(name)
        if not sep or shape is None or name in fields or not shape.fullmatch(value):
            return None
        fields[name] = value
    if ("MPos" in fields) == ("WPos" in fields):
        return None  # exactly one of them is in every report
    machine = "MPos" in fields
    feed_text = fields.get("FS", fields.get("F"))
    return StatusReport(
        state=match.group(1),
        position=_axes(fields["MPos" if machine else "WPos"]),
        machine=machine,
        wco=_axes(fields["WCO"]) if "WCO" in fields else None,
        feed=float(feed_text.split(",")[0]) if feed_text is not None else None,
    )
