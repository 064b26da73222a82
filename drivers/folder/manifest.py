"""The import manifest, `rig-import.toml`: what the frames do not say about themselves.

Intrinsics, baseline, depth unit, projector state, and each stop's distance (a table, or a
pattern that reads it from the folder's name). Command-line flags override its keys.
See docs/import.md.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import FolderImportError

MANIFEST_NAME = "rig-import.toml"

REQUIRED_KEYS = ("fx", "fy", "cx", "cy", "baseline_m", "depth_unit_m", "projector_on")
OPTIONAL_KEYS = ("exposure_us", "gain", "stop_distance_m", "stop_distance_from_name", "camera_model", "camera_serial")
#: the command-line flag that sets each manifest key
FLAGS = {
    "fx": "--fx", "fy": "--fy", "cx": "--cx", "cy": "--cy", "baseline_m": "--baseline-m",
    "depth_unit_m": "--depth-unit-m", "projector_on": "--projector on|off", "exposure_us": "--exposure-us",
    "gain": "--gain", "stop_distance_from_name": "--stop-distance-from-name",
}


@dataclass(frozen=True)
class ImportSettings:
    """What the frames do not say, from the manifest and the overrides."""

    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    depth_unit_m: float
    projector_on: bool
    exposure_us: float = math.nan  # NaN: not known
    gain: float = math.nan
    stop_distance_m: dict[str, float] = field(default_factory=dict)
    stop_distance_from_name: str | None = None
    camera_model: str = "imported frames"
    camera_serial: str = ""


def read_manifest(src: Path) -> dict[str, Any]:
    """The manifest as written ({} when there is none)."""
    path = src / MANIFEST_NAME
    if not path.exists():
        return {}
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise FolderImportError(f"{path}: not valid TOML ({one_line(e)}); see docs/import.md") from None


def load_settings(src: Path, overrides: dict[str, Any] | None = None) -> tuple[ImportSettings, dict[str, Any]]:
    """Merge the manifest with the overrides (None values are ignored); return (settings, manifest as read)."""
    manifest = read_manifest(src)
    where = src / MANIFEST_NAME
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    unknown = sorted(set(manifest) - set(REQUIRED_KEYS) - set(OPTIONAL_KEYS))
    if unknown:
        raise FolderImportError(f"{where}: unknown key(s) {unknown}; the keys are {list(REQUIRED_KEYS + OPTIONAL_KEYS)}")
    unknown = sorted(set(given) - set(REQUIRED_KEYS) - set(OPTIONAL_KEYS))
    if unknown:
        raise FolderImportError(f"unknown override(s) {unknown}; the keys are {list(REQUIRED_KEYS + OPTIONAL_KEYS)}")
    merged = {**manifest, **given}
    missing = [k for k in REQUIRED_KEYS if k not in merged]
    if missing:
        state = "lacks" if where.exists() else "does not exist, so it lacks"
        flags = ", ".join(FLAGS[k] for k in missing)
        raise FolderImportError(f"{where} {state} {', '.join(missing)}; add them (see docs/import.md) or pass {flags}")
    return _validated(merged, where, given=set(given)), manifest


#: the largest stereo baseline and depth unit a depth camera has (m): beyond them, a number in mm written as metres
MOST_BASELINE_M = 1.0
MOST_DEPTH_UNIT_M = 0.01


def _validated(m: dict[str, Any], where: Path, given: set[str] = frozenset()) -> ImportSettings:
    """The settings checked; a bad value is named as it was given: `--baseline-m 50` or `rig-import.toml: fx = -5`."""
    values: dict[str, Any] = {}
    for key in ("fx", "fy", "baseline_m", "depth_unit_m"):
        values[key] = _number(m, key, where, positive=True, flag=key in given)
    for key, most, example in (("baseline_m", MOST_BASELINE_M, "a D435's is 0.050"),
                               ("depth_unit_m", MOST_DEPTH_UNIT_M, "0.001 for 1 mm, 0.0001 for 0.1 mm")):
        if values[key] > most:  # millimetres written as metres, most likely
            said = f"{FLAGS[key]} {values[key]:g}:" if key in given else f"{where}: {key} ="
            raise FolderImportError(f"{said} {values[key]:g} m is more than a stereo camera's {most:g} m; "
                                    f"give it in metres ({example}: {values[key] / 1000:g} if that was mm)")
    for key in ("cx", "cy"):
        values[key] = _number(m, key, where, flag=key in given)
    for key in ("exposure_us", "gain"):
        if key in m:
            values[key] = _number(m, key, where, positive=True, flag=key in given)
    if not isinstance(m["projector_on"], bool):
        raise FolderImportError(f"{where}: projector_on = {m['projector_on']!r}; write true or false")
    values["projector_on"] = m["projector_on"]
    values["stop_distance_m"] = _distance_table(m.get("stop_distance_m", {}), where)
    values["stop_distance_from_name"] = _pattern(m.get("stop_distance_from_name"), where)
    for key in ("camera_model", "camera_serial"):
        if key in m:
            values[key] = str(m[key])
    return ImportSettings(**values)


def _number(m: dict[str, Any], key: str, where: Path, *, positive: bool = False, flag: bool = False) -> float:
    """m[key] as a float; flag: it was given on the command line (FLAGS[key]), not in the manifest at `where`."""
    v = m[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (positive and v <= 0):
        need = "a positive number" if positive else "a number"
        said = f"{FLAGS[key]} {v!r}" if flag else f"{where}: {key} = {v!r}"
        raise FolderImportError(f"{said}; it must be {need}")
    return float(v)


def _distance_table(table: Any, where: Path) -> dict[str, float]:
    if not isinstance(table, dict):
        raise FolderImportError(f"{where}: stop_distance_m must be a table of sub-folder = distance in m, e.g. [stop_distance_m] near = 0.5")
    return {str(name): _number(table, name, where, positive=True) for name in table}


def _pattern(text: Any, where: Path) -> str | None:
    if text is None:
        return None
    try:
        re.compile(str(text))
    except re.error as e:
        raise FolderImportError(f"{where}: stop_distance_from_name = {text!r} is not a regular expression ({e})") from None
    return str(text)


def one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__
