"""`rig import`: folders of depth frames (16-bit PNG or .npy) become a normal recording.

The folder holds one sub-folder per stop and a manifest, `rig-import.toml`, with what the
frames do not say (intrinsics, baseline, depth unit, projector, each stop's distance). See
docs/import.md.

Everything is checked before a frame is folded in: the manifest, each file's header (PNG bit
depth and colour type, .npy dtype and shape), the frame size, the number of frames per stop,
and, on the first frame of each stop that has valid depth, whether the depth unit makes the
range agree with the stop's distance. Then the frames are replayed, one at a time, through the
same runner that records a live run (`protocols.runner.Runner`): a `FolderCamera` stands in
for the camera and a `NoStage` records each stop's distance. The recording is written to a
temporary file beside the output and renamed when complete, so a failed import leaves nothing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import struct
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

from drivers.camera import CameraInfo, CameraSettings, DepthCamera, Frame, FrameMetadata, Intrinsics
from drivers.stage import NoStage
from protocols.plan import Capture, Configure, Move, Plan
from protocols.runner import ProgressCallback, ProgressEvent, Runner, RunError

from .image_regions import center_box

MANIFEST_NAME = "rig-import.toml"
PROTOCOL = "import"

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

REQUIRED_KEYS = ("fx", "fy", "cx", "cy", "baseline_m", "depth_unit_m", "projector_on")
OPTIONAL_KEYS = ("exposure_us", "gain", "stop_distance_m", "stop_distance_from_name", "camera_model", "camera_serial")
#: the command-line flag that sets each manifest key
FLAGS = {
    "fx": "--fx", "fy": "--fy", "cx": "--cx", "cy": "--cy", "baseline_m": "--baseline-m",
    "depth_unit_m": "--depth-unit-m", "projector_on": "--projector on|off", "exposure_us": "--exposure-us",
    "gain": "--gain", "stop_distance_from_name": "--stop-distance-from-name",
}

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_COLOUR_TYPES = {0: "grayscale", 2: "colour (RGB)", 3: "palette (colour)", 4: "grayscale+alpha", 6: "colour (RGBA)"}
IR_PREFIX = "ir_"


class FolderImportError(ValueError):
    """The folder cannot be imported; the one-line message names the file and the problem."""


# -- the manifest ------------------------------------------------------------------------------

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
        raise FolderImportError(f"{path}: not valid TOML ({_one_line(e)}); see docs/import.md") from None


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
    return _validated(merged, where), manifest


def _validated(m: dict[str, Any], where: Path) -> ImportSettings:
    values: dict[str, Any] = {}
    for key in ("fx", "fy", "baseline_m", "depth_unit_m"):
        values[key] = _number(m, key, where, positive=True)
    for key in ("cx", "cy"):
        values[key] = _number(m, key, where)
    for key in ("exposure_us", "gain"):
        if key in m:
            values[key] = _number(m, key, where, positive=True)
    if not isinstance(m["projector_on"], bool):
        raise FolderImportError(f"{where}: projector_on = {m['projector_on']!r}; write true or false")
    values["projector_on"] = m["projector_on"]
    values["stop_distance_m"] = _distance_table(m.get("stop_distance_m", {}), where)
    values["stop_distance_from_name"] = _pattern(m.get("stop_distance_from_name"), where)
    for key in ("camera_model", "camera_serial"):
        if key in m:
            values[key] = str(m[key])
    return ImportSettings(**values)


def _number(m: dict[str, Any], key: str, where: Path, *, positive: bool = False) -> float:
    v = m[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (positive and v <= 0):
        need = "a positive number" if positive else "a number"
        raise FolderImportError(f"{where}: {key} = {v!r}; it must be {need}")
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


# -- frame files -------------------------------------------------------------------------------

@dataclass(frozen=True)
class FrameFile:
    """One file of frames: a PNG (one frame) or a .npy (one frame or a stack)."""

    path: Path
    kind: str  # "png" or "npy"
    n_frames: int
    shape: tuple[int, int]  # (height, width)

    def frames(self) -> Iterator[np.ndarray]:
        """The file's frames, one at a time, as uint16."""
        if self.kind == "png":
            yield _decode_png(self.path, self.shape)
            return
        stack = _open_npy(self.path)
        if stack.ndim == 2:
            stack = stack[np.newaxis]
        for i in range(len(stack)):
            yield _as_uint16(np.array(stack[i]), f"{self.path} (frame {i})")


def inspect_file(path: Path, *, ir: bool = False) -> FrameFile:
    """Read the file's header only; refuse what cannot be a depth frame (or an IR image)."""
    if path.suffix.lower() == ".png":
        return _inspect_png(path, ir=ir)
    return _inspect_npy(path, ir=ir)


def _inspect_png(path: Path, *, ir: bool) -> FrameFile:
    try:
        with open(path, "rb") as f:
            head = f.read(26)
    except OSError as e:
        raise FolderImportError(f"{path}: cannot be read ({e.strerror})") from None
    if len(head) < 26 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise FolderImportError(f"{path}: not a readable PNG file (no PNG header); remove it or replace it with the original")
    width, height, bit_depth, colour_type = struct.unpack(">IIBB", head[16:26])
    what = "IR images" if ir else "depth frames"
    if colour_type != 0:
        kind = PNG_COLOUR_TYPES.get(colour_type, f"colour type {colour_type}")
        raise FolderImportError(f"{path}: {kind} PNG; {what} must be grayscale PNGs"
                                + ("" if ir else " with 16 bits (0 = no data); move other images out of the stop folders"))
    if bit_depth != 16 and not (ir and bit_depth == 8):
        raise FolderImportError(f"{path}: {bit_depth}-bit grayscale PNG; {what} must be 16-bit"
                                + ("" if ir else " (an 8-bit image has lost the depth); export the camera's 16-bit depth"))
    return FrameFile(path, "png", 1, (height, width))


def _inspect_npy(path: Path, *, ir: bool) -> FrameFile:
    a = _open_npy(path)
    if ir and a.dtype.kind not in "ui":
        raise FolderImportError(f"{path}: {a.dtype} values; .npy IR images must hold integers (uint8 or uint16)")
    if not ir and (a.dtype.kind not in "ui" or a.dtype.itemsize < 2):
        raise FolderImportError(f"{path}: {a.dtype} values; .npy depth frames must hold 16-bit integer depth counts "
                                "(uint16, 0 = no data), e.g. np.round(z_m / depth_unit_m).astype(np.uint16)")
    if a.ndim not in (2, 3):
        raise FolderImportError(f"{path}: array of shape {a.shape}; a .npy file holds one frame (H, W) or a stack (N, H, W)")
    n = 1 if a.ndim == 2 else a.shape[0]
    return FrameFile(path, "npy", n, tuple(a.shape[-2:]))


def _open_npy(path: Path) -> np.ndarray:
    """Memory-map a .npy file: the header is read, the frames stay on disk until sliced."""
    try:
        return np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise FolderImportError(f"{path}: unreadable .npy file ({_one_line(e)})") from None


def _decode_png(path: Path, shape: tuple[int, int]) -> np.ndarray:
    from PIL import Image  # Pillow: needed only to decode PNGs

    try:
        with Image.open(path) as im:
            im.load()
            a = np.array(im)
    except Exception as e:  # Pillow raises many kinds for damaged files
        raise FolderImportError(f"{path}: unreadable PNG ({_one_line(e)})") from None
    if a.shape != shape:
        raise FolderImportError(f"{path}: decodes to {a.shape[::-1]} px, its header says {shape[::-1]}; the file is damaged")
    return _as_uint16(a, str(path))


def _as_uint16(a: np.ndarray, name: str) -> np.ndarray:
    if a.dtype == np.uint16:
        return a
    if a.dtype.kind in "ui" and (a.size == 0 or (a.min() >= 0 and a.max() <= 65535)):
        return a.astype(np.uint16)
    raise FolderImportError(f"{name}: values outside 0-65535 ({a.dtype}); frames must be 16-bit counts")


# -- stops -------------------------------------------------------------------------------------

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
    value = _distance_from_match(match)
    if value is None:
        raise FolderImportError(f"{folder}: the name does not give a distance by stop_distance_from_name = {pattern!r}; "
                                f"rename the folder or add it to [stop_distance_m] in {MANIFEST_NAME}")
    return value


def _distance_from_match(match: re.Match | None) -> float | None:
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


# -- checks before importing -------------------------------------------------------------------

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
            counts = _center_counts(depth)
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


def _center_counts(depth: np.ndarray) -> float | None:
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


# -- the camera that replays the folder --------------------------------------------------------

class FolderCamera(DepthCamera):
    """Replays the stops' frames as a camera, for the runner.

    Each `frames(n)` call serves the next stop, in order: the runner asks once per capture
    (the frames' metadata are the configured settings, so none is refused).
    """

    name = "import"

    def __init__(self, stops: list[StopSource], settings: ImportSettings, shape: tuple[int, int], source: Path):
        self.stops = stops
        self.settings = settings
        self.shape = shape
        self.source = source
        self._pending = iter(stops)
        self._camera_settings = CameraSettings(settings.projector_on, settings.exposure_us, settings.gain, False)
        self._frame_number = 0

    def open(self) -> None:
        pass

    def close(self) -> None:
        pass

    def info(self) -> CameraInfo:
        s, (h, w) = self.settings, self.shape
        return CameraInfo(model=s.camera_model, serial=s.camera_serial, firmware="",
                          intrinsics=Intrinsics(w, h, s.fx, s.fy, s.cx, s.cy), baseline_m=s.baseline_m,
                          depth_scale_m=s.depth_unit_m, extra={"imported_from": str(self.source)})

    def configure(self, settings: CameraSettings) -> CameraSettings:
        self._camera_settings = settings
        return settings

    def read_settings(self) -> CameraSettings:
        return self._camera_settings

    def frames(self, n: int, *, ir: bool = False) -> Iterator[Frame]:
        stop = next(self._pending)
        c = self._camera_settings
        meta = FrameMetadata(c.exposure_us, c.gain, c.projector_on, c.auto_exposure)
        ir_images = stop.ir_frames() if ir else iter(())
        served = 0
        for depth, _path in stop.frames():
            yield Frame(depth=depth, frame_number=self._frame_number, timestamp_ms=math.nan, metadata=meta,
                        ir=next(ir_images, None))
            self._frame_number += 1
            served += 1
        if served != n:
            raise FolderImportError(f"{stop.folder}: {served} frames read, {n} counted before; did the folder change during the import?")


def import_plan(stops: list[StopSource], settings: ImportSettings, source: Path) -> Plan:
    """Configure once, then per stop: 'move' to its distance (no stage: recorded only) and capture all its frames."""
    camera = CameraSettings(settings.projector_on, settings.exposure_us, settings.gain, False)
    params = dict(source_folder=str(source), stops_m=[s.distance_m for s in stops], stop_folders=[s.name for s in stops],
                  frames_per_stop=[s.n_frames for s in stops], projector_on=settings.projector_on,
                  exposure_us=settings.exposure_us, gain=settings.gain, depth_unit_m=settings.depth_unit_m)

    def steps():
        yield Configure(camera)
        for s in stops:
            yield Move(s.distance_m)
            yield Capture(s.name, s.n_frames, ir=bool(s.ir_files))

    return Plan(PROTOCOL, params, steps)


# -- the import --------------------------------------------------------------------------------

def import_folder(src: str | Path, out: str | Path, overrides: dict[str, Any] | None = None,
                  progress: ProgressCallback | None = None) -> Path:
    """Import a folder of stops into the recording `out`; return its path.

    overrides: manifest keys to set or replace (e.g. from command-line flags), None values ignored.
    progress: called with the runner's `ProgressEvent`s (rig.progress.TerminalProgress shows them).
    Raises FolderImportError with a one-line message; on any failure no output file is left.
    """
    src, out = Path(src), Path(out)
    _check_paths(src, out)
    settings, manifest = load_settings(src, overrides)
    stops = find_stops(src, settings)
    shape = check_stops(stops, settings)
    report = progress or (lambda e: None)
    n_frames = sum(s.n_frames for s in stops)
    report(ProgressEvent("message", text=f"importing {n_frames} frames in {len(stops)} stops from {src}"))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.importing")
    tmp.unlink(missing_ok=True)
    try:
        _record(stops, settings, shape, src, tmp, progress)
        write_provenance(tmp, src, manifest, overrides, stops)
        if out.exists():
            raise FolderImportError(f"{out} appeared during the import; choose another output file")
        tmp.rename(out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out


def _check_paths(src: Path, out: Path) -> None:
    if not src.is_dir():
        raise FolderImportError(f"{src} is not a folder; pass the folder that holds one sub-folder per stop")
    if out.exists():
        raise FolderImportError(f"{out} already exists; choose another output file")


def _record(stops: list[StopSource], settings: ImportSettings, shape: tuple[int, int], src: Path, path: Path,
            progress: ProgressCallback | None) -> None:
    camera = FolderCamera(stops, settings, shape, src.resolve())
    try:
        Runner(camera, NoStage(), progress=progress, sleep=lambda s: None).run(import_plan(stops, settings, src.resolve()), path)
    except RunError as e:
        raise FolderImportError(f"import of {src} stopped ({str(e).split('; ')[0]}); nothing was written") from None


def write_provenance(path: Path, src: Path, manifest: dict[str, Any], overrides: dict[str, Any] | None,
                     stops: list[StopSource]) -> None:
    """Where the frames came from: the folder, the manifest as read, the overrides, each stop's files."""
    with h5py.File(path, "a") as f:
        f.attrs["import_source_folder"] = str(src.resolve())
        f.attrs["import_manifest"] = json.dumps(manifest, default=str)
        f.attrs["import_overrides"] = json.dumps({k: v for k, v in (overrides or {}).items() if v is not None}, default=str)
        for s in stops:
            g = f["stops"][s.name]
            g.attrs["source_folder"] = s.name
            g.attrs["source_files"] = json.dumps([p.path.name for p in s.depth_files])
            g.attrs["source_ir_files"] = json.dumps([p.path.name for p in s.ir_files])
            g.attrs["source_n_frames"] = s.n_frames


def _size(shape: tuple[int, ...]) -> str:
    return f"{shape[1]}x{shape[0]} px"


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


# -- command line ------------------------------------------------------------------------------

def add_import_args(p: argparse.ArgumentParser) -> None:
    """The arguments of `rig import`: the folder, the output, and flags that override the manifest."""
    p.add_argument("folder", metavar="DIR", help=f"folder with one sub-folder per stop and {MANIFEST_NAME}")
    p.add_argument("-o", "--output", required=True, metavar="OUT.h5", help="recording to write")
    p.add_argument("--fx", type=float, help="focal length, px (overrides the manifest)")
    p.add_argument("--fy", type=float, help="focal length, px")
    p.add_argument("--cx", type=float, help="principal point column, px")
    p.add_argument("--cy", type=float, help="principal point row, px")
    p.add_argument("--baseline-m", type=float, help="stereo baseline, m")
    p.add_argument("--depth-unit-m", type=float, help="metres per depth count (0.001 for 1 mm)")
    p.add_argument("--projector", choices=["on", "off"], help="was the IR projector on")
    p.add_argument("--exposure-us", type=float)
    p.add_argument("--gain", type=float)
    p.add_argument("--stop-distance-from-name", metavar="REGEX", help='read distances from folder names, e.g. "(?P<m>[0-9.]+)m"')


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:
    """Manifest keys set on the command line (the flags that were given)."""
    o = {k: getattr(args, k) for k in ("fx", "fy", "cx", "cy", "baseline_m", "depth_unit_m", "exposure_us", "gain",
                                        "stop_distance_from_name")}
    o["projector_on"] = None if args.projector is None else args.projector == "on"
    return {k: v for k, v in o.items() if v is not None}


def run_import(args: argparse.Namespace) -> int:
    """`rig import` once its arguments are parsed; errors raise FolderImportError."""
    from .progress import TerminalProgress

    out = import_folder(args.folder, args.output, overrides_from_args(args), progress=TerminalProgress())
    print(f"imported {args.folder} -> {out} (rig fit {out}; rig diagnose {out})")
    return 0


def import_main(argv: list[str]) -> int:
    """`rig import DIR -o OUT.h5 [--fx ...]`; raises FolderImportError on bad input."""
    p = argparse.ArgumentParser(prog="rig import", description="Turn folders of depth frames (16-bit PNG or .npy) "
                                "into a recording; see docs/import.md.")
    add_import_args(p)
    return run_import(p.parse_args(argv))


if __name__ == "__main__":
    try:
        sys.exit(import_main(sys.argv[1:]))
    except FolderImportError as e:
        print(f"rig: error: {e}", file=sys.stderr)
        sys.exit(2)
