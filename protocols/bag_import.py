"""Importing bags (`rig import run.bag`): RealSense and ROS 1/ROS 2 bags become a normal recording.

A bag is one stop; a folder of bags is one stop per bag. What the bag says (intrinsics from
`camera_info`, the depth unit, the baseline, the camera's identity, the projector, exposure and gain,
each frame's number, time and metadata) is taken from it; what it does not say (each stop's distance,
a ROS bag's projector state) is asked for with the flags the folder import uses, or read from an
optional `rig-import.toml` beside the bags. The frames are replayed through the same runner as a live
run (`drivers.bag.BagCamera`), which takes the recording's settings as they were made and notes them.
The recording is written to a temporary file beside the output and renamed when complete.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import h5py

from drivers.bag import BagCamera, BagFacts, BagStop, is_bag, read_facts
from drivers.bag.contents import agree_metric_unit
from drivers.bag.contents import frames as bag_frames
from drivers.camera import CameraSettings
from drivers.errors import FolderImportError
from drivers.folder.manifest import FLAGS, MANIFEST_NAME, OPTIONAL_KEYS, REQUIRED_KEYS, read_manifest
from drivers.folder.stops import MAX_RANGE_MISMATCH, center_counts, distance_from_match, natural_key, suggest_depth_unit
from drivers.stage import NoStage

from .bag_spans import parse_distances, parse_time_spans, stops_at_gaps, stops_in_time
from .folder_import import PROTOCOL, _check_paths_out, import_stopped, write_aside
from .plan import Capture, Configure, Move, Plan
from .recording import HDF5_LIBVER
from .runner import PlanRefused, ProgressCallback, ProgressEvent, Runner, RunError

#: how far two bags' intrinsics may differ (px) and still be one camera at one resolution
INTRINSICS_TOLERANCE_PX = 1e-3


def find_bags(src: Path) -> list[Path]:
    """The bags to import: `src` itself, or the bags in the folder `src` (natural order)."""
    if is_bag(src):
        return [src]
    if not src.is_dir():
        raise FolderImportError(f"{src}: not a bag (.bag, .db3, .mcap) or a folder of them")
    bags = sorted((p for p in src.iterdir() if not p.name.startswith(".") and is_bag(p)), key=lambda p: natural_key(p.name))
    if not bags:
        raise FolderImportError(f"{src}: no bags (.bag, .db3, .mcap or ROS 2 bag folders) in it")
    return bags


def import_bags(src: str | Path, out: str | Path, overrides: dict[str, Any] | None = None,
                progress: ProgressCallback | None = None, *, topic: str | None = None,
                distance_m: float | None = None, stops_in_time: str | None = None,
                stops_at_gaps: str | None = None) -> Path:
    """Import a bag, or a folder of bags (one stop each), into the recording `out`; return its path.

    overrides: import keys (the manifest's names: fx, ..., projector_on, stop_distance_from_name) that replace
    what the bags say; None values are ignored. distance_m: the distance of a single bag's stop, in m.
    stops_in_time ('Z@T0-T1,...') or stops_at_gaps ('Z1,Z2,...'): one bag holding several stops (protocols.bag_spans).
    Raises FolderImportError with a one-line message; on any failure no output file is left.
    """
    src, out = Path(src), Path(out)
    _check_paths_out(out)
    bags = find_bags(src)
    manifest = read_manifest(src) if src.is_dir() and not is_bag(src) else {}
    unknown = sorted(set(manifest) - set(REQUIRED_KEYS) - set(OPTIONAL_KEYS))
    if unknown:
        raise FolderImportError(f"{src / MANIFEST_NAME}: unknown key(s) {unknown}; the keys are {list(REQUIRED_KEYS + OPTIONAL_KEYS)}")
    facts = [read_facts(b, topic) for b in bags]
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    values = {**_agreed(facts), **manifest, **given}
    unclear = [f for f in facts if f.baseline_problem]
    if unclear and "baseline_m" not in {**manifest, **given}:
        raise FolderImportError(f"{unclear[0].path}: {unclear[0].baseline_problem}")
    missing = [k for k in REQUIRED_KEYS if k not in values]
    if missing:
        raise FolderImportError(f"{src}: the bag does not say {', '.join(missing)}; pass {', '.join(FLAGS[k] for k in missing)}")
    if stops_in_time is not None or stops_at_gaps is not None:
        stops = _spans(facts, src, distance_m, stops_in_time, stops_at_gaps)
    else:
        stops = _stops(facts, values, distance_m, src)
    for s in stops:
        _check_depth_unit(s, float(values["depth_unit_m"]))
    notes = import_notes(facts)
    report = progress or (lambda e: None)
    report(ProgressEvent("message", text=f"importing {sum(s.n_frames for s in stops)} frames in {len(stops)} "
                                         f"stop{'s' * (len(stops) != 1)} from {src} ({facts[0].extra['bag_format']})"
                                         + "".join(f"; note: {n}" for n in notes)))
    def fill(tmp: Path) -> None:
        _record(stops, values, src, tmp, progress)
        _provenance(tmp, src, facts, manifest, given, stops)
        if notes:
            with h5py.File(tmp, "a", libver=HDF5_LIBVER) as f:
                f.attrs["import_notes"] = json.dumps(notes)

    return write_aside(src, out, fill)


def import_notes(facts: list[BagFacts]) -> list[str]:
    """What a reader of the recording must know about the depth imported: depth aligned to another camera (taken
    as it is, with this note in the output and the recording, `Recording.notes`)."""
    aligned = sorted({f.aligned for f in facts if f.aligned})
    return [f"{a}; a fit of it describes the aligned stream, not the sensor: import the sensor's own depth topic "
            "for that" for a in aligned]


def recorded_notes(path: Path) -> list[str]:
    """The notes an import left in the recording at `path` (`import_notes`; none for other recordings)."""
    with h5py.File(path, "r") as f:
        raw = f.attrs.get("import_notes")
    notes = json.loads(raw) if raw is not None else []
    return [str(n) for n in notes] if isinstance(notes, list) else []


def _agreed(facts: list[BagFacts]) -> dict[str, Any]:
    """What every bag says alike: one camera at one resolution (else a one-line refusal naming the two bags)."""
    first = facts[0]
    for f in facts[1:]:
        if f.depth_format.metres != first.depth_format.metres:
            raise FolderImportError(f"{f.path} is {f.encoding}, {first.path} {first.encoding}; import the stops of one stream")
        if (f.width, f.height) != (first.width, first.height):
            raise FolderImportError(f"{f.path} is {f.width}x{f.height} px, {first.path} {first.width}x{first.height}; "
                                    "import the stops of one stream at one resolution")
        for key in ("fx", "fy", "cx", "cy"):
            a, b = getattr(first, key), getattr(f, key)
            if math.isfinite(a) and math.isfinite(b) and abs(a - b) > INTRINSICS_TOLERANCE_PX:
                raise FolderImportError(f"{f.path}: {key} = {b:g} px, but {first.path} says {a:g}; one camera per import")
    agree_metric_unit(facts)
    return first.known()


def _stops(facts: list[BagFacts], values: dict[str, Any], distance_m: float | None, src: Path) -> list[BagStop]:
    table = values.get("stop_distance_m", {}) or {}
    pattern = values.get("stop_distance_from_name")
    if distance_m is not None and len(facts) > 1:
        raise FolderImportError(f"--distance-m gives one distance, but {src} holds {len(facts)} bags; name each "
                                "bag's distance with --stop-distance-from-name or [stop_distance_m] in rig-import.toml")
    stops = []
    for f in facts:
        label = f.path.name if f.path.is_dir() else f.path.stem
        if distance_m is not None:
            z = float(distance_m)
        elif label in table or f.path.name in table:
            z = float(table.get(label, table.get(f.path.name)))
        elif pattern:
            z = distance_from_match(re.search(str(pattern), label))
            if z is None:
                raise FolderImportError(f"{f.path}: the name gives no distance by --stop-distance-from-name {pattern!r}; "
                                        "rename it or give its distance in [stop_distance_m]")
        else:
            one = "pass --distance-m Z (the camera-to-wall distance in m)" if len(facts) == 1 else \
                "pass --stop-distance-from-name REGEX or add [stop_distance_m] to rig-import.toml beside the bags"
            raise FolderImportError(f"{f.path}: no distance for this stop (a bag does not record it); {one}")
        if not (math.isfinite(z) and z > 0):
            raise FolderImportError(f"{f.path}: distance {z!r} m; give a positive distance in metres")
        if f.n_frames < 2:
            raise FolderImportError(f"{f.path}: {f.n_frames} depth frame(s) on {f.topic}; a stop needs at least 2 for a variance")
        stops.append(BagStop(label, f, z))
    if len({s.label for s in stops}) != len(stops):
        raise FolderImportError(f"{src}: two bags share a name; rename one (a stop is named after its bag)")
    return sorted(stops, key=lambda s: (s.distance_m, natural_key(s.label)))


def _spans(facts: list[BagFacts], src: Path, distance_m: float | None, in_time: str | None,
           at_gaps: str | None) -> list[BagStop]:
    """The stops of one bag told apart by time spans or pauses."""
    if len(facts) != 1 or distance_m is not None or (in_time is not None and at_gaps is not None):
        raise FolderImportError(f"{src}: --stops-in-time and --stops-at-gaps split one bag into stops; give one of them, "
                                "for one bag, without --distance-m")
    if in_time is not None:
        stops = stops_in_time(facts[0], parse_time_spans(in_time))
    else:
        stops = stops_at_gaps(facts[0], parse_distances(at_gaps or ""))
    if len({s.label for s in stops}) != len(stops):
        raise FolderImportError(f"{src}: two stops at the same distance; give each stop its own distance")
    return sorted(stops, key=lambda s: s.distance_m)


def _check_depth_unit(stop: BagStop, depth_unit_m: float) -> None:
    """Refuse a depth unit (or distance) that puts the stop's first valid frame more than 20 % from its distance."""
    for frame in bag_frames(stop.facts, stop.window_ms, depth_unit_m):
        counts = center_counts(frame.depth)
        if counts is not None:
            break
    else:
        raise FolderImportError(f"{stop.facts.path}: no frame has valid (non-zero) depth; is {stop.facts.topic} a depth topic?")
    range_m = counts * depth_unit_m
    if abs(range_m / stop.distance_m - 1) > MAX_RANGE_MISMATCH:
        raise FolderImportError(f"{stop.facts.path}: mean range {range_m:.4g} m at the centre, but the stop's distance is "
                                f"{stop.distance_m:g} m; check the distance, or the depth unit: "
                                f"{suggest_depth_unit(counts, stop.distance_m)}")


def _record(stops: list[BagStop], values: dict[str, Any], src: Path, path: Path, progress: ProgressCallback | None) -> None:
    first = stops[0].facts
    settings = CameraSettings(projector_on=bool(values["projector_on"]), exposure_us=float(values.get("exposure_us", math.nan)),
                              gain=float(values.get("gain", math.nan)), auto_exposure=bool(first.auto_exposure))
    calibration = {k: float(values[k]) for k in ("fx", "fy", "cx", "cy", "baseline_m", "depth_unit_m")}
    identity = {"camera_model": str(values.get("camera_model", "")), "camera_serial": str(values.get("camera_serial", "")),
                "camera_firmware": first.camera_firmware}
    extra = {"imported_from": str(src.resolve()), **first.extra}
    if first.depth_format.metres and calibration["depth_unit_m"] != first.depth_unit_m:  # --depth-unit-m for metres
        extra.pop("metric_depth", None)
        extra["depth_unit_source"] = f"{first.depth_format} metres rounded to counts of {calibration['depth_unit_m']:g} m (given)"
    camera = BagCamera(stops, settings, calibration, identity, extra)
    params = dict(source_folder=str(src.resolve()), stops_m=[s.distance_m for s in stops], stop_folders=[s.label for s in stops],
                  frames_per_stop=[s.n_frames for s in stops], projector_on=settings.projector_on,
                  exposure_us=settings.exposure_us, gain=settings.gain, depth_unit_m=calibration["depth_unit_m"])

    def steps():
        yield Configure(settings)
        for s in stops:
            yield Move(s.distance_m)
            yield Capture(s.label, s.n_frames)

    try:
        Runner(camera, NoStage(), progress=progress, sleep=lambda s: None).run(Plan(PROTOCOL, params, steps), path)
    except PlanRefused as e:
        raise FolderImportError(f"import of {src} refused before it started: {'; '.join(e.problems)}; nothing was written") from None
    except RunError as e:
        raise import_stopped(src, e) from None


def _provenance(path: Path, src: Path, facts: list[BagFacts], manifest: dict[str, Any], given: dict[str, Any],
                stops: list[BagStop]) -> None:
    """Where the frames came from: the bags, what they said, the overrides, each stop's bag and topic."""
    with h5py.File(path, "a", libver=HDF5_LIBVER) as f:
        f.attrs["import_source_folder"] = str(src.resolve())
        f.attrs["import_manifest"] = json.dumps({"bag": facts[0].known(), "rig-import.toml": manifest}, default=str)
        f.attrs["import_overrides"] = json.dumps(given, default=str)
        for s in stops:
            g = f["stops"][s.label]
            g.attrs["source_folder"] = str(s.facts.path.name)
            g.attrs["source_files"] = json.dumps([s.facts.path.name])
            g.attrs["source_topic"] = s.facts.topic
            g.attrs["source_format"] = str(s.facts.extra.get("bag_format", ""))
            g.attrs["source_n_frames"] = s.n_frames
            if s.window_ms is not None:  # one bag, several stops: the stop's frames, by header stamp
                g.attrs["source_window_s"] = [(t - s.facts.stamps_ms[0]) / 1e3 for t in s.window_ms]
