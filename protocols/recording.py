"""The recording: one HDF5 file per experiment (schema in docs/data-format.md), read stop by stop.

While a run is under way, or after it was interrupted, its completed stops are also in one file
each beside it (`stop_journal`); `Recording` reads both, so an interrupted run is readable as it
stands. A stop that cannot be read (a damaged file written by an older rig) is skipped and named
in `skipped`, never a traceback. Writing: `recording_writer.RecordingWriter`.
"""

from __future__ import annotations

import datetime as _dt
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import h5py
import numpy as np

# the calibration a recording stores is the one intrinsics type, with baseline and depth unit (re-exported here
# for the readers of recordings)
from drivers.camera import CameraCalibration  # noqa: F401

from .stats import PixelStats

FORMAT = "rig.recording"
FORMAT_VERSION = 1
#: the HDF5 structures every file rig writes uses: from HDF5 1.8's on, whose object headers carry checksums, so a
#: flipped byte in an attribute's header reads as "incorrect metadata checksum" instead of being believed (HDF5
#: 1.14 segfaulted reading an attribute whose type bits a flipped byte had changed, tests/test_fuzz_recordings.py);
#: readable by HDF5 1.10 and later (h5py since 2.9)
HDF5_LIBVER = ("v108", "v110")


from . import stop_journal as journal  # noqa: E402
from .recording_errors import RecordingError  # noqa: E402,F401  (re-exported: the readers' error)
from .run_lock import holder  # noqa: E402
from .truncated_file import LOST_INDEX, open_hdf5, truncated_words  # noqa: E402
from .stop_attributes import count_attribute, count_or_zero, number_attribute, stop_counts  # noqa: E402


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
    #: per pixel, IR samples at the sensor's full scale `ir_full_scale_dn` (clipped); None: not checked (older files)
    ir_saturated: np.ndarray | None = None
    ir_full_scale_dn: float | None = None

    @property
    def projector_on(self) -> bool:
        return bool(self.settings_read_back.get("projector_on", self.settings_requested.get("projector_on", True)))


def jsonable(x: Any) -> Any:
    """`x` as plain JSON data (arrays as lists, anything else unknown as its str)."""
    return json.loads(json.dumps(x, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def check_format(f: h5py.File, path: Path, *, strict: bool = False) -> None:
    """Refuse files of another format or a newer version; with `strict` (resume), a missing `format` too."""
    fmt = f.attrs.get("format")
    if (fmt is None and strict) or (fmt is not None and fmt != FORMAT):
        raise RecordingError(f"{path} is not a rig recording (format={fmt!r}); check the file name")
    try:
        ver = int(f.attrs.get("format_version", FORMAT_VERSION))
    except (TypeError, ValueError):
        raise RecordingError(f"{path}: its format_version {f.attrs.get('format_version')!r} is not a number; "
                             "see docs/data-format.md") from None
    if ver > FORMAT_VERSION:
        raise RecordingError(f"{path} has format version {ver}, newer than this rig reads ({FORMAT_VERSION}); upgrade rig")


#: what h5py raises on a damaged file (HDF5's own errors arrive as any of these)
H5_ERRORS = (OSError, KeyError, ValueError, TypeError, RuntimeError, IndexError)


class Recording:
    """A recording opened for reading, with the stop files of a run under way or interrupted. Stops are
    read one at a time, on demand, and checked (`check_stop`): a value that cannot be right is a one-line
    error naming the stop and the field; a stop that cannot be read at all is skipped and named in `skipped`."""

    REQUIRED_STOP = ("count", "mean_m", "m2_m2")

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise RecordingError(f"{self.path} is a folder, not a recording; give one of its .h5 files (rig fit and rig "
                                 "compare take a folder with --many or as several recordings)" if self.path.is_dir() else
                                 f"{self.path} does not exist; check the path (rig demo writes to rig-output/)")
        # truncated: (bytes there, bytes it should have) of a file whose end is missing (protocols.truncated_file)
        self.file, self.truncated = open_hdf5(self.path)
        self._stop_files: dict[str, h5py.File] = {}
        try:
            self._read_header()
            if self.truncated and not self.stop_labels():
                raise RecordingError(truncated_words(self.path, *self.truncated, LOST_INDEX))
        except RecordingError:
            self.close()
            raise
        except H5_ERRORS as e:
            self.close()
            if self.truncated:
                raise RecordingError(truncated_words(self.path, *self.truncated, LOST_INDEX)) from None
            raise RecordingError(f"{self.path}: its header cannot be read ({type(e).__name__}: {e}); the file is damaged: "
                                 "copy it aside and record again (docs/reliability.md)") from None
        except BaseException:
            self.close()
            raise

    def _read_header(self) -> None:
        f = self.file
        check_format(f, self.path)
        if "camera" not in f or "stops" not in f:
            raise RecordingError(f"{self.path} lacks the 'camera' group or the 'stops' group; see docs/data-format.md")
        cam = f["camera"].attrs
        missing = [k for k in ("fx", "fy", "cx", "cy", "baseline_m", "depth_scale_m") if k not in cam]
        if missing:
            raise RecordingError(f"{self.path}: /camera lacks attribute(s) {missing}; see docs/data-format.md")
        self.attrs = dict(f.attrs)
        self.writer = holder(self.path)  # a live run still writing it, if any
        self.skipped: list[str] = []
        self._where: dict[str, tuple[str, str | Path]] = {}
        stops = f["stops"]
        for label in list(stops):
            try:
                complete = bool(stops[label].attrs.get("complete", True))
            except H5_ERRORS as e:
                self.skipped.append(f"stop {label!r}: unreadable ({type(e).__name__}: {e})")
                continue
            if complete:
                self._where[label] = ("main", label)
        for label, p in journal.completed_stop_files(self.path).items():
            self._where.setdefault(label, ("file", p))
        shape = self._first_shape()

        def number(key: str, default: float | None = None, *, positive: bool = False) -> float:
            raw = cam.get(key, default)
            try:
                v = float(raw)
            except (TypeError, ValueError):
                raise RecordingError(f"{self.path}: /camera attribute {key} is {raw!r}, not a number; see docs/data-format.md") from None
            if not np.isfinite(v) or (positive and v <= 0):
                raise RecordingError(f"{self.path}: /camera attribute {key} is {v!r}; it must be a finite"
                                     f"{' positive' if positive else ''} number (see docs/data-format.md)")
            return v

        self.calibration = CameraCalibration(
            width=int(number("width", shape[1])), height=int(number("height", shape[0])),
            fx=number("fx", positive=True), fy=number("fy", positive=True), cx=number("cx"), cy=number("cy"),
            baseline_m=number("baseline_m", positive=True), depth_scale_m=number("depth_scale_m", positive=True),
        )
        if not 1e-7 <= self.calibration.depth_scale_m <= 0.1:
            raise RecordingError(f"{self.path}: /camera depth_scale_m = {self.calibration.depth_scale_m:g} m per unit is "
                                 "implausible (a RealSense uses 0.001 or 0.0001); set it in metres per depth unit")

    def _first_shape(self) -> tuple[int, int]:
        for label in self._where:
            try:
                g = self._group(label)
                if "mean_m" in g and len(g["mean_m"].shape) == 2:
                    return tuple(g["mean_m"].shape)  # type: ignore[return-value]
            except H5_ERRORS + (RecordingError,):
                continue
        return (0, 0)

    def _group(self, label: str) -> h5py.Group:
        kind, where = self._where[label]
        if kind == "main":
            return self.file["stops"][where]
        f = self._stop_files.get(label)
        if f is None:
            try:
                f = self._stop_files[label] = h5py.File(where, "r")
            except OSError as e:
                raise RecordingError(f"{where}: unreadable ({e})") from None
        return f[journal.STOP_GROUP]

    @property
    def protocol(self) -> str:
        return str(self.attrs.get("protocol", "unknown"))

    @property
    def protocol_params(self) -> dict[str, Any]:
        try:
            params = json.loads(self.attrs.get("protocol_params", "{}"))
        except (TypeError, ValueError):
            raise RecordingError(f"{self.path}: protocol_params is not valid JSON; see docs/data-format.md") from None
        return params if isinstance(params, dict) else {}

    @property
    def in_progress(self) -> bool:
        """A live run is still writing this recording."""
        return self.writer is not None

    @property
    def assembled(self) -> bool:
        """All stops are in the file itself (no stop files beside it)."""
        return all(kind == "main" for kind, _ in self._where.values())

    def notes(self) -> list[str]:
        """What a reader of a fit must know about the recording itself: still being written, interrupted
        (which planned stops are missing), frames dropped or duplicated, entries skipped as unreadable, a single stop."""
        labels = self.stop_labels()
        out = []
        if self.in_progress:
            out.append(f"still being written by PID {self.writer.get('pid')} ({len(labels)} stops complete so far)")
        planned = self.protocol_params.get("stops_m")
        if isinstance(planned, list) and planned and not self.in_progress:
            want = [f"{float(z):.3f}m" for z in planned if isinstance(z, (int, float)) and not isinstance(z, bool)]
            missing = [w for w in want if w not in labels]
            if missing:
                out.append(f"{len(want) - len(missing)} of {len(want)} planned stops (missing {', '.join(missing[:5])}"
                           f"{', ...' if len(missing) > 5 else ''}); rig run ... --resume records the rest")
        elif "ended_utc" not in self.attrs and not self.in_progress and labels:
            out.append("the run did not finish (no ended_utc); rig run ... --resume records the rest")
        lost, as_recorded, saturated = [], {}, {}
        for label in labels:
            a = self._group(label).attrs
            if count_or_zero(a, "ir_saturated_pixels"):
                saturated[label] = count_or_zero(a, "ir_saturated_pixels")
            dropped, repeated = count_or_zero(a, "frames_dropped"), count_or_zero(a, "frames_duplicated")
            if dropped or repeated:
                lost.append(f"{label} {dropped} dropped, {repeated} duplicated")
            if a.get("settings_as_recorded"):
                as_recorded.setdefault(str(a["settings_as_recorded"]), []).append(label)
        for said, where in as_recorded.items():
            stops = "every stop" if len(where) == len(labels) else ", ".join(where[:5]) + (", ..." if len(where) > 5 else "")
            out.append(f"played back from a recording, whose settings are as it was made ({stops}): {said}")
        if lost:
            out.append("frames lost or repeated on the way (duplicates left out): " + "; ".join(lost[:5])
                       + ("; ..." if len(lost) > 5 else ""))
        if saturated:
            out.append(saturation_note(saturated, self.calibration.width * self.calibration.height))
        if self.truncated:
            out.append(truncated_words(self.path, *self.truncated, "the stops whose bytes are missing are skipped"))
        out += [f"skipped {s}" for s in self.skipped]
        out += [f"imported: {n}" for n in json.loads(self.attrs.get("import_notes", "[]"))]  # protocols/bag_import.py
        if len(labels) == 1 and self.protocol != "tilted":
            out.append("one stop only: the range dependence rests on that stop's spread of ranges")
        return out

    def exclude(self, label: str, why: str) -> None:
        """Leave a readable stop out (it contradicts itself or the rest: rig.models.data.stop_checks); the notes say why."""
        if label in self._where:
            del self._where[label]
            self.skipped.append(f"stop {label!r} (left out of the fit): {why.removeprefix(f'stop {label!r}: ')}")

    def stop_labels(self) -> list[str]:
        """Complete, readable stops in capture order (the unreadable ones are named in `skipped`)."""
        keyed = []
        for label in list(self._where):
            try:
                index = count_attribute(self._group(label).attrs, "index", 0, self.path, label)
            except H5_ERRORS + (RecordingError,) as e:
                self.skipped.append(f"stop {label!r}: unreadable ({type(e).__name__}: {e})")
                del self._where[label]
                continue
            keyed.append((index, label))
        return [label for _, label in sorted(keyed)]

    def stops(self) -> Iterator[StopData]:
        for label in self.stop_labels():
            yield self.stop(label)

    def stop(self, label: str, *, third_moment: bool = True) -> StopData:
        """One stop, read and checked; `third_moment=False` leaves m3_m3 unread (NaN), which no fit uses."""
        try:
            return self._read_stop(label, third_moment)
        except RecordingError:
            raise
        except H5_ERRORS as e:
            raise RecordingError(f"{self.path}: stop {label!r} cannot be read ({type(e).__name__}: {e}); "
                                 "the file is damaged: copy it aside and re-record that stop with --resume") from None

    def _read_stop(self, label: str, third_moment: bool = True) -> StopData:
        g = self._group(label)
        missing = [k for k in self.REQUIRED_STOP if k not in g]
        if missing:
            raise RecordingError(f"{self.path}: stop {label!r} lacks dataset(s) {missing}; see docs/data-format.md")
        count = g["count"][()]
        shape = count.shape

        def opt(name: str) -> np.ndarray:
            return g[name][()] if name in g else np.full(shape, np.nan)

        m3 = opt("m3_m3") if third_moment else np.full(shape, np.nan)
        # the lag-1 statistics (frame independence) are absent from older recordings: not checked (None)
        lag = {k: g[k][()] if k in g else None for k in ("lag1_pairs", "lag1_m2")}
        a = dict(g.attrs)  # every attribute read once (each read from the file costs 0.1 ms)
        counts = stop_counts(a, lag["lag1_pairs"] is not None, self.path, label)  # each checked with the stop
        stats = PixelStats(count=count, mean_m=g["mean_m"][()], m2_m2=g["m2_m2"][()], m3_m3=m3, m4_m4=opt("m4_m4"),
                           **lag, frames_repeated=counts["frames_repeated"])
        series = None
        if "frames" in g:
            fr = g["frames"]
            n = len(fr["frame_number"]) if "frame_number" in fr else 0
            series = FrameSeries(**{k: (fr[k][()] if k in fr else np.full(n, np.nan)) for k in FrameSeries.FIELDS})

        def attr_json(key: str) -> dict[str, Any]:
            try:
                v = json.loads(a.get(key, "{}"))
            except (TypeError, ValueError):
                raise RecordingError(f"{self.path}: stop {label!r} attribute {key} is not valid JSON; see docs/data-format.md") from None
            return v if isinstance(v, dict) else {}

        stop = StopData(
            label=label,
            index=counts["index"] or 0,
            commanded_position_m=number_attribute(a, "commanded_position_m", self.path, label),
            measured_position_m=number_attribute(a, "measured_position_m", self.path, label),
            n_frames=counts["n_frames"] if counts["n_frames"] is not None else int(np.max(count)) if count.size else 0,
            settings_requested=attr_json("settings_requested"),
            settings_read_back=attr_json("settings_read_back"),
            stats=stats,
            series=series,
            ir_mean=g["ir_mean"][()] if "ir_mean" in g else None,
            ambient_ir_mean=g["ambient_ir_mean"][()] if "ambient_ir_mean" in g else None,
            attrs=a,
            ir_saturated=g["ir_saturated"][()] if "ir_saturated" in g else None,
            ir_full_scale_dn=float(g["ir_saturated"].attrs.get("full_scale_dn", np.nan)) if "ir_saturated" in g else None,
        )
        check_stop(self.path, stop, (self.calibration.height, self.calibration.width))
        return stop

    def close(self) -> None:
        for f in self._stop_files.values():
            if f.id.valid:
                f.close()
        self._stop_files.clear()
        if self.file.id.valid:
            self.file.close()

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def saturation_note(pixels_by_stop: dict[str, int], pixels_per_stop: int) -> str:
    """The note for IR clipped at the sensor's top: how many pixel-stops, where, and what was done with them."""
    where = [f"{label} {n / max(pixels_per_stop, 1):.0%}" for label, n in pixels_by_stop.items()]
    return (f"IR saturated (samples at the sensor's full scale) at {sum(pixels_by_stop.values())} pixel-stops ("
            + ", ".join(where[:5]) + (", ..." if len(where) > 5 else "") + "): their brightness, and that of pixels smoothed "
            "with them, is only a lower bound, so it is kept out of the brightness covariates and brightness checks "
            "(their ranges are fitted as any)")


#: the nearest and farthest ranges a depth camera's statistics can hold, m (outside: wrong units)
PLAUSIBLE_RANGE_M = (0.02, 70.0)


def check_stop(path: Path, s: StopData, shape: tuple[int, int]) -> None:
    """Refuse statistics that cannot be right, naming the stop and the field (docs/reliability.md)."""
    def bad(field: str, what: str, fix: str = "the file is damaged or was written wrongly; see docs/data-format.md") -> RecordingError:
        return RecordingError(f"{path}: stop {s.label!r} {field} {what}; {fix}")

    st = s.stats
    for name in ("count", "mean_m", "m2_m2", "m3_m3", "m4_m4"):
        arr = getattr(st, name)
        if arr.ndim != 2 or arr.shape != st.count.shape:
            raise bad(name, f"has shape {arr.shape}, not the stop's {st.count.shape}")
    if shape[0] and shape[1] and st.count.shape != shape:
        raise bad("count", f"has shape {st.count.shape}, but the camera is {shape[1]}x{shape[0]}",
                  "a recording holds one camera resolution; record the stop again into a new file")
    for name, arr in (("ir_mean", s.ir_mean), ("ambient_ir_mean", s.ambient_ir_mean), ("lag1_pairs", st.lag1_pairs),
                      ("lag1_m2", st.lag1_m2), ("ir_saturated", s.ir_saturated)):
        if arr is not None and arr.shape != st.count.shape:
            raise bad(name, f"has shape {arr.shape}, not the stop's {st.count.shape}")
    if st.lag1_pairs is not None and np.any(st.lag1_pairs >= np.maximum(st.count, 1)):
        raise bad("lag1_pairs", "has more consecutive pairs than samples at some pixel")
    if st.lag1_m2 is not None and st.lag1_pairs is not None and not np.isfinite(st.lag1_m2[st.lag1_pairs > 0]).all():
        raise bad("lag1_m2", "is not finite at a pixel with consecutive pairs (the stop would drop out of the lag-1 check)")
    if s.ir_saturated is not None and s.n_frames > 0 and np.any(s.ir_saturated > s.n_frames):
        raise bad("ir_saturated", f"counts more clipped samples than the stop's {s.n_frames} frames at some pixel")
    count = st.count
    # integers are whole and finite: only their sign to check (one pass, not four)
    whole = np.issubdtype(count.dtype, np.integer) and not (count.size and count.min() < 0)
    if not whole and (not np.issubdtype(count.dtype, np.number) or not np.all(np.isfinite(count)) or np.any(count < 0)
                      or np.any(count != np.round(count))):
        raise bad("count", "holds values that are not whole numbers of samples")
    if s.n_frames < 0 or (count.size and int(np.max(count)) > s.n_frames > 0):
        raise bad("count", f"reaches {int(np.max(count))} samples, more than the stop's {s.n_frames} frames")
    valid = count > 0
    mean = st.mean_m if valid.all() else st.mean_m[valid]  # no copy of the image when every pixel has samples
    # every value finite exactly when the least and the greatest are (NaN and inf reach them): two passes, not three
    lo, hi = (float(mean.min()), float(mean.max())) if mean.size else (0.0, 0.0)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise bad("mean_m", f"is not finite at {int(np.sum(~np.isfinite(mean)))} pixels that have samples")
    # the median is plausible when every value is (a stop's whole range in one pass each way, not a partition)
    if mean.size and not PLAUSIBLE_RANGE_M[0] <= lo <= hi <= PLAUSIBLE_RANGE_M[1]:
        med = float(np.median(mean))
        if not PLAUSIBLE_RANGE_M[0] <= med <= PLAUSIBLE_RANGE_M[1]:
            raise bad("mean_m", f"has a median of {med:g}, not a range in metres",
                      "statistics must be in metres (mm divided by 1000); see docs/data-format.md")
    two = count > 1
    every = two.all()
    for name in ("m2_m2", "m4_m4"):
        arr = getattr(st, name) if every else getattr(st, name)[two]
        if not arr.size or (float(arr.min()) >= 0 and np.isfinite(float(arr.max()))):  # NaN fails the first
            continue
        if name == "m4_m4" and np.all(np.isnan(arr)):
            continue  # optional, absent
        if not np.all(np.isfinite(arr)) or np.any(arr < 0):
            n_bad = int(np.sum(~np.isfinite(arr) | (arr < 0)))
            raise bad(name, f"is negative or not finite at {n_bad} pixels (a sum of squares cannot be)")
