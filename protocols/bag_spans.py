"""One bag holding several stops: its frames told apart by time spans, or by the pauses between them.

A lab that records a whole sweep into one bag either notes when the camera stood at each distance
(`--stops-in-time "0.5@0-12,1.0@20-32"`: distance in m @ start-end in seconds from the bag's first
depth frame) or pauses the recorder while the stage moves (`--stops-at-gaps 0.5,1.0,1.5`: the frames
are split wherever none came for GAP_S seconds or GAP_PERIODS frame periods, whichever is longer, and
the pieces take the distances in order). Frames outside every span (the camera moving) are left out.
"""

from __future__ import annotations

import math
import statistics

from drivers.bag import BagFacts, BagStop
from drivers.errors import FolderImportError

#: a pause between two depth frames at least this long (s) ends a stop, for --stops-at-gaps ...
GAP_S = 1.0
#: ... and at least this many frame periods
GAP_PERIODS = 10


def parse_time_spans(text: str) -> list[tuple[float, float, float]]:
    """'Z@T0-T1,...' -> [(z_m, t0_s, t1_s), ...]; a one-line error naming the piece that is not of that form."""
    out = []
    for piece in (p.strip() for p in text.split(",") if p.strip()):
        try:
            z, span = piece.split("@")
            t0, t1 = span.split("-")
            z_m, t0_s, t1_s = float(z), float(t0), float(t1)
        except ValueError:
            raise FolderImportError(f"--stops-in-time: {piece!r} is not DISTANCE_M@START_S-END_S (e.g. 1.5@20-32)") from None
        if not (z_m > 0 and math.isfinite(z_m) and 0 <= t0_s < t1_s and math.isfinite(t1_s)):
            raise FolderImportError(f"--stops-in-time: {piece!r}: the distance must be positive and the span start "
                                    "before its end, in seconds from the bag's first frame")
        out.append((z_m, t0_s, t1_s))
    if not out:
        raise FolderImportError("--stops-in-time is empty; give DISTANCE_M@START_S-END_S for each stop")
    return out


def parse_distances(text: str) -> list[float]:
    """'Z1,Z2,...' in m; a one-line error naming what is not a positive number."""
    out = []
    for piece in (p.strip() for p in text.split(",") if p.strip()):
        try:
            z = float(piece)
        except ValueError:
            z = math.nan
        if not (z > 0 and math.isfinite(z)):
            raise FolderImportError(f"--stops-at-gaps: {piece!r} is not a distance in m; give them in order, e.g. 0.5,1.0,1.5")
        out.append(z)
    if not out:
        raise FolderImportError("--stops-at-gaps is empty; give each stop's distance in m, in the bag's order")
    return out


def _label(z_m: float) -> str:
    return f"{z_m:.3f}m"


def stops_in_time(facts: BagFacts, spans: list[tuple[float, float, float]]) -> list[BagStop]:
    """One stop per span of seconds from the bag's first depth frame."""
    t_first = facts.stamps_ms[0]
    stops = [BagStop(_label(z), facts, z, (t_first + 1e3 * t0, t_first + 1e3 * t1)) for z, t0, t1 in spans]
    ordered = sorted(spans, key=lambda s: s[1])
    for (za, _a0, a1), (zb, b0, _b1) in zip(ordered, ordered[1:]):
        if b0 <= a1:
            raise FolderImportError(f"--stops-in-time: the spans of {za:g} m and {zb:g} m overlap; a frame belongs to one stop")
    length_s = (facts.stamps_ms[-1] - t_first) / 1e3
    for s, (z, t0, t1) in zip(stops, spans):
        if s.n_frames < 2:
            raise FolderImportError(f"{facts.path}: {s.n_frames} frame(s) between {t0:g} s and {t1:g} s (the {z:g} m stop); "
                                    f"the bag's frames span 0-{length_s:.1f} s; a stop needs at least 2")
    return stops


def pieces(stamps_ms: list[float]) -> list[tuple[float, float]]:
    """The runs of frames between pauses: (first, last) stamp in ms of each."""
    if len(stamps_ms) < 2:
        return [(stamps_ms[0], stamps_ms[0])] if stamps_ms else []
    intervals = [b - a for a, b in zip(stamps_ms, stamps_ms[1:])]
    gap_ms = max(1e3 * GAP_S, GAP_PERIODS * statistics.median(intervals))
    out, start = [], stamps_ms[0]
    for a, b in zip(stamps_ms, stamps_ms[1:]):
        if b - a >= gap_ms:
            out.append((start, a))
            start = b
    out.append((start, stamps_ms[-1]))
    return out


def stops_at_gaps(facts: BagFacts, distances_m: list[float]) -> list[BagStop]:
    """The bag's runs of frames between pauses, one stop each, taking the distances in order."""
    runs = pieces(facts.stamps_ms)
    if len(runs) != len(distances_m):
        t0 = facts.stamps_ms[0]
        found = ", ".join(f"{(a - t0) / 1e3:.1f}-{(b - t0) / 1e3:.1f} s" for a, b in runs[:8]) + (", ..." if len(runs) > 8 else "")
        raise FolderImportError(f"{facts.path}: {len(runs)} run(s) of frames between pauses of {GAP_S:g} s or more "
                                f"({found}), but {len(distances_m)} distances; give one distance per run, or spans "
                                "with --stops-in-time")
    stops = [BagStop(_label(z), facts, z, run) for z, run in zip(distances_m, runs)]
    for s in stops:
        if s.n_frames < 2:
            raise FolderImportError(f"{facts.path}: the {s.distance_m:g} m run holds {s.n_frames} frame; a stop needs at least 2")
    return stops
