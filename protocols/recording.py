"""The recording: one HDF5 file per experiment (schema in docs/data-format.md).

Writing is stop by stop: a stop's group is created when its capture starts (marked
incomplete), filled when it ends, marked complete and flushed. An interrupted run therefore
keeps every completed stop, and `RecordingWriter(path, resume=True)` drops the incomplete one
and carries on.
"""

from __future__ import annotations

import datetime as _dt
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

from .stats import PixelStats

FORMAT = "rig.recording"
FORMAT_VERSION = 1


class RecordingError(ValueError):
    """A file is not a valid recording; the message names the file and what is wrong."""


def utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def software_version() -> str:
    try:
        from importlib.metadata import version

        return version("rig")
    except Exception:  # running from a source tree without installation
        return "unknown"


@dataclass
class FrameSeries:
    """Per-frame series of one stop, for drift and dropped-frame checks."""

    frame_number: np.ndarray
    timestamp_ms: np.ndarray
    center_mean_m: np.ndarray  # mean valid depth in the central region, m (NaN if none)
    inverse_range_offset_per_m: np.ndarray  # mean over valid pixels of 1/z - 1/z_first, 1/m (drift signal)
    valid_fraction: np.ndarray  # fraction of valid pixels in the whole frame
    exposure_us: np.ndarray
    gain: np.ndarray
    projector_on: np.ndarray

    FIELDS = ("frame_number", "timestamp_ms", "center_mean_m", "inverse_range_offset_per_m", "valid_fraction",
              "exposure_us", "gain", "projector_on")


@dataclass
class StopData:
    """One stop of a recording, as read back."""

    label: str
    index: int
    commanded_position_m: float
    measured_position_m: float
    n_frames: int
    settings_requested: dict[str, Any]
    settings_read_back: dict[str, Any]
    stats: PixelStats
    series: FrameSeries | None
    ir_mean: np.ndarray | None = None
    ambient_ir_mean: np.ndarray | None = None
    attrs: dict[str, Any] = field(default_factory=dict)

    @property
    def projector_on(self) -> bool:
        return bool(self.settings_read_back.get("projector_on", self.settings_requested.get("projector_on", True)))


@dataclass
class CameraCalibration:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    depth_scale_m: float


class _OpenRecording:
    """An open HDF5 recording (`self.file`), closed by `close()` or at the end of a `with` block."""

    file: h5py.File

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self.file.id.valid:
            self.file.close()


class RecordingWriter(_OpenRecording):
    """Write a recording stop by stop. Use as a context manager."""

    def __init__(self, path: str | Path, *, resume: bool = False):
        self.path = Path(path)
        if self.path.exists() and not resume:
            raise RecordingError(f"{self.path} already exists; choose another output file or pass --resume to continue it")
        if resume and not self.path.exists():
            raise RecordingError(f"{self.path} does not exist, so there is nothing to resume; run without --resume")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.file = h5py.File(self.path, "a" if resume else "w-")
        if resume:
            _check_format(self.file, self.path)
            for label in self.incomplete_stops():
                del self.file["stops"][label]
            self.file.flush()

    # -- experiment --------------------------------------------------------------------------
    def start_experiment(self, *, protocol: str, params: dict[str, Any], camera: dict[str, Any],
                         stage: dict[str, Any], calibration: CameraCalibration) -> None:
        """Write the experiment's header (on resume, check that it is the same experiment)."""
        f = self.file
        if "format" in f.attrs:
            if f.attrs["protocol"] != protocol or json.loads(f.attrs["protocol_params"]) != _jsonable(params):
                raise RecordingError(
                    f"{self.path} holds a different experiment ({f.attrs['protocol']}); resume it with the plan that made it, or write a new file"
                )
            return
        f.attrs["format"] = FORMAT
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["software_version"] = software_version()
        f.attrs["protocol"] = protocol
        f.attrs["protocol_params"] = json.dumps(_jsonable(params))
        f.attrs["started_utc"] = utc_now()
        f.attrs["camera_model"] = str(camera.get("model", ""))
        f.attrs["camera_serial"] = str(camera.get("serial", ""))
        f.attrs["camera"] = json.dumps(_jsonable(camera))
        f.attrs["stage"] = json.dumps(_jsonable(stage))
        cam = f.require_group("camera")
        for k, v in vars(calibration).items():
            cam.attrs[k] = v
        f.require_group("stops")
        f.flush()

    def finish(self) -> None:
        self.file.attrs["ended_utc"] = utc_now()
        self.file.flush()

    # -- stops -----------------------------------------------------------------------------
    def completed_stops(self) -> set[str]:
        stops = self.file.get("stops", {})
        return {k for k in stops if bool(stops[k].attrs.get("complete", False))}

    def incomplete_stops(self) -> list[str]:
        stops = self.file.get("stops", {})
        return [k for k in stops if not bool(stops[k].attrs.get("complete", False))]

    def begin_stop(self, label: str, *, index: int, commanded_position_m: float, measured_position_m: float,
                   settings_requested: dict[str, Any], settings_read_back: dict[str, Any]) -> h5py.Group:
        g = self.file["stops"].create_group(label)
        g.attrs["complete"] = False
        g.attrs["index"] = index
        g.attrs["commanded_position_m"] = commanded_position_m
        g.attrs["measured_position_m"] = measured_position_m
        g.attrs["settings_requested"] = json.dumps(settings_requested)
        g.attrs["settings_read_back"] = json.dumps(settings_read_back)
        g.attrs["started_utc"] = utc_now()
        return g

    def raw_frames(self, g: h5py.Group, n_frames: int, shape: tuple[int, int]) -> h5py.Dataset:
        """A dataset to stream a stop's raw depth frames into, one frame per row."""
        return g.create_dataset("raw_depth", shape=(n_frames, *shape), dtype=np.uint16,
                                chunks=(1, *shape), compression="gzip", compression_opts=1)

    def end_stop(self, g: h5py.Group, *, stats: PixelStats, series: FrameSeries, ir_mean: np.ndarray | None,
                 ambient_ir_mean: np.ndarray | None, extra_attrs: dict[str, Any] | None = None) -> None:
        comp = dict(compression="gzip", compression_opts=1, shuffle=True)
        g.create_dataset("count", data=stats.count, **comp)
        g.create_dataset("mean_m", data=stats.mean_m, **comp)
        g.create_dataset("m2_m2", data=stats.m2_m2, **comp)
        g.create_dataset("m3_m3", data=stats.m3_m3, **comp)
        g.create_dataset("m4_m4", data=stats.m4_m4, **comp)
        if ir_mean is not None:
            g.create_dataset("ir_mean", data=ir_mean, **comp)
        if ambient_ir_mean is not None:
            g.create_dataset("ambient_ir_mean", data=ambient_ir_mean, **comp)
        fr = g.create_group("frames")
        for name in FrameSeries.FIELDS:
            fr.create_dataset(name, data=getattr(series, name))
        g.attrs["n_frames"] = len(series.frame_number)
        g.attrs["ended_utc"] = utc_now()
        for k, v in (extra_attrs or {}).items():
            g.attrs[k] = v
        g.attrs["complete"] = True
        self.file.flush()


def _jsonable(x: Any) -> Any:
    return json.loads(json.dumps(x, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def _check_format(f: h5py.File, path: Path) -> None:
    fmt = f.attrs.get("format")
    if fmt is not None and fmt != FORMAT:
        raise RecordingError(f"{path} is not a rig recording (format={fmt!r}); check the file name")
    ver = int(f.attrs.get("format_version", FORMAT_VERSION))
    if ver > FORMAT_VERSION:
        raise RecordingError(f"{path} has format version {ver}, newer than this rig reads ({FORMAT_VERSION}); upgrade rig")


class Recording(_OpenRecording):
    """A recording opened for reading. Stops are read one at a time, on demand."""

    REQUIRED_STOP = ("count", "mean_m", "m2_m2")

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.exists():
            raise RecordingError(f"{self.path} does not exist; check the path (rig demo writes to rig-output/)")
        try:
            self.file = h5py.File(self.path, "r")
        except OSError as e:
            raise RecordingError(f"{self.path} is not an HDF5 file ({e}); pass a recording written by rig run or rig import") from None
        f = self.file
        _check_format(f, self.path)
        if "camera" not in f or "stops" not in f:
            raise RecordingError(f"{self.path} lacks the 'camera' group or the 'stops' group; see docs/data-format.md")
        cam = f["camera"].attrs
        missing = [k for k in ("fx", "fy", "cx", "cy", "baseline_m", "depth_scale_m") if k not in cam]
        if missing:
            raise RecordingError(f"{self.path}: /camera lacks attribute(s) {missing}; see docs/data-format.md")
        self.attrs = dict(f.attrs)
        first = next(iter(f["stops"].values()), None)
        shape = first["mean_m"].shape if first is not None and "mean_m" in first else (0, 0)
        self.calibration = CameraCalibration(
            width=int(cam.get("width", shape[1])),
            height=int(cam.get("height", shape[0])),
            fx=float(cam["fx"]),
            fy=float(cam["fy"]),
            cx=float(cam["cx"]),
            cy=float(cam["cy"]),
            baseline_m=float(cam["baseline_m"]),
            depth_scale_m=float(cam["depth_scale_m"]),
        )

    @property
    def protocol(self) -> str:
        return str(self.attrs.get("protocol", "unknown"))

    @property
    def protocol_params(self) -> dict[str, Any]:
        return json.loads(self.attrs.get("protocol_params", "{}"))

    def stop_labels(self) -> list[str]:
        """Complete stops in capture order."""
        stops = self.file["stops"]
        labels = [k for k in stops if bool(stops[k].attrs.get("complete", True))]
        return sorted(labels, key=lambda k: (int(stops[k].attrs.get("index", 0)), k))

    def stops(self) -> Iterator[StopData]:
        for label in self.stop_labels():
            yield self.stop(label)

    def stop(self, label: str) -> StopData:
        g = self.file["stops"][label]
        missing = [k for k in self.REQUIRED_STOP if k not in g]
        if missing:
            raise RecordingError(f"{self.path}: stop {label!r} lacks dataset(s) {missing}; see docs/data-format.md")
        count = g["count"][()]
        shape = count.shape

        def opt(name: str) -> np.ndarray:
            return g[name][()] if name in g else np.full(shape, np.nan)

        stats = PixelStats(count=count, mean_m=g["mean_m"][()], m2_m2=g["m2_m2"][()], m3_m3=opt("m3_m3"), m4_m4=opt("m4_m4"))
        series = None
        if "frames" in g:
            fr = g["frames"]
            n = len(fr["frame_number"]) if "frame_number" in fr else 0
            series = FrameSeries(**{k: (fr[k][()] if k in fr else np.full(n, np.nan)) for k in FrameSeries.FIELDS})
        a = g.attrs
        return StopData(
            label=label,
            index=int(a.get("index", 0)),
            commanded_position_m=float(a.get("commanded_position_m", np.nan)),
            measured_position_m=float(a.get("measured_position_m", np.nan)),
            n_frames=int(a.get("n_frames", int(np.max(count)) if count.size else 0)),
            settings_requested=json.loads(a.get("settings_requested", "{}")),
            settings_read_back=json.loads(a.get("settings_read_back", "{}")),
            stats=stats,
            series=series,
            ir_mean=g["ir_mean"][()] if "ir_mean" in g else None,
            ambient_ir_mean=g["ambient_ir_mean"][()] if "ambient_ir_mean" in g else None,
            attrs=dict(a),
        )
