"""The stops of a folder import: one sub-folder each, its distance, its frame files, and the checks
made before any frame is folded in (frame counts, one frame size, intrinsics inside the frame, and
a depth unit that puts the first valid frame near the stop's distance)."""

from __future__ import annotations

import contextlib
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import FolderImportError
from ..image_regions import center_box
from .frame_files import FrameFile, inspect_file
from .manifest import MANIFEST_NAME, ImportSettings

IR_PREFIX = "ir_"
#: how far the mean range of a stop's first frame may be from the stop's distance (fraction)
MAX_RANGE_MISMATCH = 0.20

#: depth units in use, to suggest one when the stated unit makes the ranges disagree
COMMON_DEPTH_UNITS_M = {
    "1 mm": 1e-3,
    "0.5 mm": 5e-4,
    "0.25 mm": 2.5e-4,
    "0.2 mm": 2e-4,
    "0.1 mm": 1e-4,
    "0.05 mm": 5e-5,
    "1 m/65535": 1 / 65535,
}


@dataclass
class StopSource:
    """One stop: its sub-folder, distance, depth files and IR files (in natural order)."""

    name: str
    folder: Path
    distance_m: float
    depth_files: list[FrameFile]
    ir_files: list[FrameFile]

    @property
    def n_frames(self) -> int:
        return sum(f.n_frames for f in self.depth_files)

    def frames(self) -> Iterator[tuple[np.ndarray, Path]]:
        for f in self.depth_files:
            for depth in f.frames():
                yield depth, f.path

    def ir_frames(self) -> Iterator[np.ndarray]:
        for f in self.ir_files:
            yield from f.frames()


def find_stops(src: Path, settings: ImportSettings) -> list[StopSource]:
    """Every sub-folder is a stop; stops are ordered by distance, then by name."""
    folders = sorted((p for p in src.iterdir() if p.is_dir() and not p.name.startswith(".")), key=lambda p: natural_key(p.name))
    if not folders:
        raise FolderImportError(f"{src}: no sub-folders; put each stop's frames in a sub-folder of its own (see docs/import.md)")
    names = {p.name for p in folders}
    for name in settings.stop_distance_m:
        if name not in names:
            raise FolderImportError(f"{src / MANIFEST_NAME}: stop_distance_m names {name!r}, but {src} has no such sub-folder")
    stops = [_stop(p, settings) for p in folders]
    return sorted(stops, key=lambda s: (s.distance_m, natural_key(s.name)))


def _stop(folder: Path, settings: ImportSettings) -> StopSource:
    distance_m = stop_distance_m(folder, settings)
    files = sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in (".png", ".npy")
                    and not p.name.startswith(".")), key=lambda p: natural_key(p.name))
    depth = [inspect_file(p) for p in files if not p.name.lower().startswith(IR_PREFIX)]
    ir = [inspect_file(p, ir=True) for p in files if p.name.lower().startswith(IR_PREFIX)]
    return StopSource(folder.name, folder, distance_m, depth, ir)


def stop_distance_m(folder: Path, settings: ImportSettings) -> float:
    """The stop's distance: from the manifest's table, else from the folder's name by the pattern."""
    if folder.name in settings.stop_distance_m:
        return settings.stop_distance_m[folder.name]
    pattern = settings.stop_distance_from_name
    if pattern is None:
        raise FolderImportError(f"{folder}: no distance for this stop; add it to [stop_distance_m] in {MANIFEST_NAME} "
                                "or set stop_distance_from_name, e.g. \"(?P<m>[0-9.]+)m\"")
    match = re.search(pattern, folder.name)
    value = distance_from_match(match)
    if value is None:
        raise FolderImportError(f"{folder}: the name does not give a distance by stop_distance_from_name = {pattern!r}; "
                                f"rename the folder or add it to [stop_distance_m] in {MANIFEST_NAME}")
    return value


def distance_from_match(match: re.Match | None) -> float | None:
    """Metres from group 'm', millimetres from group 'mm', else metres from the first group or the whole match."""
    if match is None:
        return None
    groups = match.groupdict()
    if groups.get("mm"):
        text, scale = groups["mm"], 1e-3
    elif groups.get("m"):
        text, scale = groups["m"], 1.0
    else:
        text, scale = (match.group(1) if match.re.groups else match.group(0)), 1.0
    try:
        value = float(text) * scale
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) and value > 0 else None


def natural_key(name: str) -> tuple:
    """Sort frame_2 before frame_10."""
    return tuple(int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name))


def check_stops(stops: list[StopSource], settings: ImportSettings) -> tuple[int, int]:
    """Frame counts, one frame size, intrinsics inside it, and a plausible depth unit; return (height, width)."""
    for s in stops:
        if s.n_frames < 2:
            found = f" ({s.depth_files[0].path.name} alone)" if s.depth_files else " (no *.png or *.npy depth frames)"
            raise FolderImportError(f"{s.folder}: {s.n_frames} depth frame(s){found}; a stop needs at least 2 frames for a variance")
    shape = check_sizes(stops)
    check_intrinsics(settings, shape, stops[0].depth_files[0].path)
    for s in stops:
        check_depth_unit(s, settings.depth_unit_m)
    return shape


def check_sizes(stops: list[StopSource]) -> tuple[int, int]:
    first = stops[0].depth_files[0]
    for s in stops:
        for f in s.depth_files + s.ir_files:
            if f.shape != first.shape:
                raise FolderImportError(f"{f.path}: {_size(f.shape)}, but {first.path} is {_size(first.shape)}; "
                                        "all frames (and IR images) must be the same size")
    return first.shape


def check_intrinsics(settings: ImportSettings, shape: tuple[int, int], example: Path) -> None:
    h, w = shape
    for key, value, size in (("cx", settings.cx, w), ("cy", settings.cy, h)):
        if not -0.5 <= value <= size - 0.5:
            raise FolderImportError(f"{key} = {value:g} px lies outside the {_size(shape)} frames ({example}); "
                                    "give the intrinsics of the depth image at this resolution")


def check_depth_unit(stop: StopSource, depth_unit_m: float) -> None:
    """Refuse a depth unit that puts the stop's first valid frame more than 20 % from its distance."""
    with contextlib.closing(stop.frames()) as frames:
        for depth, path in frames:
            counts = center_counts(depth)
            if counts is not None:
                break
        else:
            raise FolderImportError(f"{stop.folder}: no frame has valid (non-zero) depth; is this a depth capture?")
    range_m = counts * depth_unit_m
    if abs(range_m / stop.distance_m - 1) <= MAX_RANGE_MISMATCH:
        return
    raise FolderImportError(
        f"{path}: mean range {range_m:.4g} m with depth_unit_m = {depth_unit_m:g}, but the stop is at "
        f"{stop.distance_m:g} m; {suggest_depth_unit(counts, stop.distance_m)}")


def center_counts(depth: np.ndarray) -> float | None:
    """Mean valid depth count in the central region (or the whole frame if the centre has none)."""
    for region in (depth[center_box(depth.shape)], depth):
        valid = region[region > 0]
        if valid.size:
            return float(valid.mean())
    return None


def suggest_depth_unit(mean_counts: float, distance_m: float) -> str:
    """Which common depth unit would make the mean count agree with the distance."""
    implied = distance_m / mean_counts
    name, unit = min(COMMON_DEPTH_UNITS_M.items(), key=lambda kv: abs(math.log(kv[1] / implied)))
    if abs(implied / unit - 1) <= MAX_RANGE_MISMATCH:
        return f"probably the wrong unit: depth_unit_m = {unit:.6g} ({name}) would fit"
    return (f"the frames imply about {implied:.3g} m per count, no common unit; "
            "check depth_unit_m and the stop's distance")


def _size(shape: tuple[int, ...]) -> str:
    return f"{shape[1]}x{shape[0]} px"
