"""A specification a recording is checked against (`rig check --spec spec.toml`): its lines, read from TOML.

    [[sigma]]                       # the fitted sigma_Z = k Z^lambda at a range
    at_z_m = 2.0
    sigma_pct_of_z_max = 2.0        # or sigma_mm_max = 40
    [[fill]]                        # each stop's share of valid depth
    fill_pct_min = 99.0
    to_z_m = 3.0                    # optional, as from_z_m: the stops the line covers
    [[accuracy]]                    # each stop's |depth accuracy| against the stage, % (rig.accuracy)
    depth_accuracy_pct_max = 0.5

Every key carries its unit; a table may be given once (`[fill]`) or as many lines (`[[fill]]`), each with an
optional `name`. A spec that is not TOML, names an unknown table or key, lacks a limit or gives a value outside its
range is a `SpecError`: one line naming the table, the key and the fix.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path


class SpecError(ValueError):
    """The spec cannot be read; the message names the problem and the fix, in one line."""


#: the nearest and farthest ranges a spec may name (m); a value past the farthest that is a range in mm is said to be
FARTHEST_Z_M = 50.0
NEAREST_Z_M = 0.1


@dataclass(frozen=True)
class Line:
    """One line of a spec: a `limit` (in `unit`) that the measured value must stay at or under (`bound` "max") or at
    or over ("min"), at the range `at_z_m` (sigma) or at every stop from `from_z_m` to `to_z_m` (fill, accuracy)."""

    kind: str  # "sigma", "fill", "accuracy"
    key: str  # the limit's key, e.g. "sigma_pct_of_z_max"
    limit: float
    unit: str  # "% of Z", "mm", "%"
    bound: str  # "max" or "min"
    at_z_m: float | None = None
    from_z_m: float | None = None
    to_z_m: float | None = None
    name: str | None = None

    @property
    def text(self) -> str:
        """The line in words, e.g. "sigma at 2 m at most 2 % of Z", "fill at least 99 % to 3 m"."""
        what = {"sigma": "sigma", "fill": "fill", "accuracy": "depth accuracy"}[self.kind]
        limit = f"{'at most' if self.bound == 'max' else 'at least'} {self.limit:g} {self.unit}"
        if self.kind == "accuracy":
            limit = f"within {self.limit:g} {self.unit}"
        if self.at_z_m is not None:
            return f"{what} at {self.at_z_m:g} m {limit}"
        if self.from_z_m is not None and self.to_z_m is not None:
            where = f"from {self.from_z_m:g} to {self.to_z_m:g} m"
        elif self.to_z_m is not None:
            where = f"to {self.to_z_m:g} m"
        elif self.from_z_m is not None:
            where = f"from {self.from_z_m:g} m"
        else:
            where = "at every stop"
        return f"{what} {limit} {where}"

    @property
    def label(self) -> str:
        return self.name or self.text


@dataclass(frozen=True)
class Spec:
    path: str
    lines: tuple[Line, ...]
    name: str | None = None


#: each table's limits: key -> (unit, bound, lowest, highest), the range a value must lie in (exclusive low)
LIMITS = {
    "sigma": {"sigma_pct_of_z_max": ("% of Z", "max", 0.0, 100.0), "sigma_mm_max": ("mm", "max", 0.0, 10_000.0)},
    "fill": {"fill_pct_min": ("%", "min", 1.0, 100.0)},
    "accuracy": {"depth_accuracy_pct_max": ("%", "max", 0.0, 100.0)},
}
#: each table's ranges: required and optional keys, m
RANGES = {"sigma": (("at_z_m",), ()), "fill": ((), ("from_z_m", "to_z_m")), "accuracy": ((), ("from_z_m", "to_z_m"))}
EXAMPLE = "e.g. [[sigma]] at_z_m = 2.0, sigma_pct_of_z_max = 2.0 (docs/check.md)"


def read_spec(path: str | Path) -> Spec:
    """The spec at `path` (see the module), or a SpecError naming what is wrong with it and the fix."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except FileNotFoundError:
        raise SpecError(f"--spec {path} does not exist; give a spec file ({EXAMPLE})") from None
    except IsADirectoryError:
        raise SpecError(f"--spec {path} is a folder; give the spec's .toml file") from None
    except tomllib.TOMLDecodeError as e:
        raise SpecError(f"{path} is not valid TOML ({e}); correct that line ({EXAMPLE})") from None
    except UnicodeDecodeError:
        raise SpecError(f"{path} is not UTF-8 text; save it as a UTF-8 TOML file ({EXAMPLE})") from None
    name = doc.pop("name", None)
    if name is not None and not isinstance(name, str):
        raise SpecError(f"{path}: name = {name!r} is not a string; quote it, e.g. name = \"D435 acceptance\"")
    unknown = sorted(set(doc) - set(LIMITS))
    if unknown:
        tables = ", ".join(f"[[{k}]]" for k in LIMITS)
        raise SpecError(f"{path}: unknown table [{unknown[0]}]; a spec's tables are {tables} ({EXAMPLE})")
    lines = []
    for kind in LIMITS:
        tables = doc.get(kind, [])
        tables = [tables] if isinstance(tables, dict) else tables
        if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
            raise SpecError(f"{path}: {kind} must be a table of keys; write [[{kind}]] and its keys on the lines below")
        lines += [_line(path, kind, i + 1, t) for i, t in enumerate(tables)]
    if not lines:
        raise SpecError(f"{path} holds no line to check; add one, {EXAMPLE}")
    return Spec(str(path), tuple(lines), name)


def _line(path: Path, kind: str, number: int, table: dict) -> Line:
    where = f"{path}: [[{kind}]] {number}"
    required, optional = RANGES[kind]
    allowed = [*LIMITS[kind], *required, *optional, "name"]
    for key in table:
        if key not in allowed:
            raise SpecError(f"{where}: unknown key {key!r}; its keys are {', '.join(allowed)}")
    limits = [k for k in LIMITS[kind] if k in table]
    if len(limits) != 1:
        given = "none" if not limits else " and ".join(limits)
        raise SpecError(f"{where} needs one limit, and has {given}: give one of {', '.join(LIMITS[kind])}")
    key = limits[0]
    unit, bound, low, high = LIMITS[kind][key]
    limit = _number(where, key, table[key])
    if not low < limit <= high:
        fix = (f"the limit is in %: for a fraction of {limit:g} write {key} = {100 * limit:g}"
               if key == "fill_pct_min" and 0 < limit <= 1 else "give a limit in that range")
        raise SpecError(f"{where}: {key} = {limit:g} is outside ({low:g}, {high:g}] {unit}; {fix}")
    for z_key in required:
        if z_key not in table:
            raise SpecError(f"{where} needs {z_key}, the range (m) the limit applies at, e.g. {z_key} = 2.0")
    z = {k: _range(where, k, table[k]) for k in (*required, *optional) if k in table}
    if "from_z_m" in z and "to_z_m" in z and z["from_z_m"] >= z["to_z_m"]:
        raise SpecError(f"{where}: from_z_m = {z['from_z_m']:g} is not below to_z_m = {z['to_z_m']:g}; swap them or "
                        "widen the span")
    name = table.get("name")
    if name is not None and not isinstance(name, str):
        raise SpecError(f"{where}: name = {name!r} is not a string; quote it")
    return Line(kind, key, limit, unit, bound, name=name, **z)


def _number(where: str, key: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SpecError(f"{where}: {key} = {value!r} is not a number; give a number, e.g. {key} = 2.0")
    return float(value)


def _range(where: str, key: str, value: object) -> float:
    """A range in metres, checked: a value past FARTHEST_Z_M that is a range read as millimetres is said to be."""
    z = _number(where, key, value)
    if NEAREST_Z_M <= z <= FARTHEST_Z_M:
        return z
    if NEAREST_Z_M <= z / 1000 <= FARTHEST_Z_M:
        raise SpecError(f"{where}: {key} = {z:g} is in metres, and this looks like millimetres: {key} = {z / 1000:g}")
    raise SpecError(f"{where}: {key} = {z:g} m is no range a depth camera measures; give metres, {NEAREST_Z_M:g} to "
                    f"{FARTHEST_Z_M:g}")
