"""Writing a recording stop by stop, so that whatever instant the process dies at, every stop it
reported done is readable and `--resume` carries on (the mechanism: `stop_journal`).

    RecordingWriter(path)                 takes the run's lock; a leftover file with no complete
                                          stop is replaced, any other existing file is refused
    RecordingWriter(path, resume=True)    the file must be a rig recording; incomplete stops dropped
    start_experiment(...)                 writes the header (atomically), or on resume checks that
                                          camera and stage are the same (`identity`) and that the plan
                                          changes only stops not yet recorded (`plan_check.resume_problems`);
                                          such a change replaces the header's plan (atomically)
    begin_stop / raw_frames / end_stop    one stop, in its own file, renamed into place when complete
    finish()                              assembles run.h5 from the header and the stop files
"""

from __future__ import annotations

import io
import json
import os
import shutil
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from . import stop_journal as journal
from .disk_space import FILE_OVERHEAD_BYTES, free_bytes, is_disk_full, megabytes
from .plan import Plan
from .plan_check import plan_change, resume_problems
from drivers.camera import CameraCalibration

from .recording import (FORMAT, FORMAT_VERSION, HDF5_LIBVER, FrameSeries, Recording, check_format, jsonable,
                        software_version, utc_now)
from .leftovers import remove_dead_leftovers
from .recording_errors import AssemblyError, RecordingError
from .run_lock import RunLock
from .stats import PixelStats

#: a recording up to this size is assembled in memory (statistics: ~15 MB a stop at 848x480; peak memory about 3x
#: the size); bigger ones (raw frames kept) on disk
IN_MEMORY_ASSEMBLY_BYTES = 256 * 2**20

#: what must be the same for a run to be resumed into a file (what may differ: docs/reliability.md)
CAMERA_IDENTITY = ("model", "serial", "width", "height", "depth_scale_m", "simulated")
STAGE_IDENTITY = ("kind", "driver", "limits_m", "offset_m", "direction", "rail_mm", "microstep_um")


def camera_identity(camera: dict[str, Any], calibration: CameraCalibration) -> dict[str, Any]:
    intr = camera.get("intrinsics", {}) if isinstance(camera.get("intrinsics"), dict) else {}
    got = {"model": camera.get("model"), "serial": camera.get("serial"), "width": intr.get("width", calibration.width),
           "height": intr.get("height", calibration.height), "depth_scale_m": camera.get("depth_scale_m", calibration.depth_scale_m),
           "simulated": bool(camera.get("simulated", False))}
    return {k: got[k] for k in CAMERA_IDENTITY}


def stage_identity(stage: dict[str, Any]) -> dict[str, Any]:
    return {k: stage.get(k) for k in STAGE_IDENTITY if k in stage}


def _differences(what: str, old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    out = []
    for k in dict.fromkeys([*old, *new]):
        a, b = jsonable(old.get(k)), jsonable(new.get(k))
        if a != b:
            out.append(f"{what} {k} {a!r} in the file, {b!r} now")
    return out


HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def is_empty_leftover(path: Path) -> bool:
    """A file a run left before its first stop: a rig header with no complete stop and no stop files, or a
    torn HDF5 file of a few kilobytes (a kill inside the first write). Anything else is somebody's data."""
    if journal.completed_stop_files(path):
        return False
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT:
                return False
            stops = f.get("stops")
            return stops is None or not any(bool(stops[k].attrs.get("complete", True)) for k in stops)
    except (OSError, KeyError, ValueError, RuntimeError):
        with open(path, "rb") as fh:
            head = fh.read(8)
        return head == HDF5_SIGNATURE and path.stat().st_size <= 4096


class RecordingWriter:
    """Write a recording stop by stop. Use as a context manager."""

    def __init__(self, path: str | Path, *, resume: bool = False):
        self.path = Path(path)
        self.resume = resume
        self._open_stop: tuple[h5py.File, str, Path | None] | None = None
        self.lock = RunLock(self.path).acquire()
        try:
            remove_dead_leftovers(self.path)  # a killed writer's copies and temporary files (protocols.leftovers)
            self._prepare()
        except BaseException:
            self.lock.release()
            raise

    def _prepare(self) -> None:
        p = self.path
        if self.resume:
            if not p.exists():
                raise RecordingError(f"{p} does not exist, so there is nothing to resume; run without --resume")
            try:
                with h5py.File(p, "r") as f:
                    check_format(f, p, strict=True)
            except OSError as e:
                raise RecordingError(f"{p} cannot be read as HDF5 ({e}); it is not a recording to resume: "
                                     "write a new file (its complete stops, if any, are read by rig fit)") from None
            journal.remove_partials(p)
            return
        if p.exists():
            if not is_empty_leftover(p):
                raise RecordingError(f"{p} already exists; choose another output file or pass --resume to continue it")
            p.unlink()  # a run killed before its first stop left it: not worth keeping, and not a trap
        d = journal.journal_dir(p)
        if d.is_dir():
            shutil.rmtree(d)
        p.parent.mkdir(parents=True, exist_ok=True)

    # -- experiment --------------------------------------------------------------------------
    def start_experiment(self, *, plan: Plan, camera: dict[str, Any], stage: dict[str, Any],
                         calibration: CameraCalibration) -> str:
        """Write the experiment's header. On resume, check that it is the same experiment, and when the plan
        changes only stops not yet recorded, record the new plan; return that change in words ("" if none)."""
        if self.resume:
            change = self.resume_change(plan, camera, stage, calibration)
            if change:
                self._replace_plan(plan.params)
            return change
        attrs = {
            "format": FORMAT, "format_version": FORMAT_VERSION, "software_version": software_version(),
            "protocol": plan.name, "protocol_params": json.dumps(jsonable(plan.params)), "started_utc": utc_now(),
            "camera_model": str(camera.get("model", "")), "camera_serial": str(camera.get("serial", "")),
            "camera": json.dumps(jsonable(camera)), "stage": json.dumps(jsonable(stage)),
        }
        with h5py.File("header", "w", driver="core", backing_store=False, libver=HDF5_LIBVER) as f:
            f.attrs.update(attrs)
            cam = f.create_group("camera")
            for k, v in vars(calibration).items():
                cam.attrs[k] = v
            f.create_group("stops")
            f.flush()
            image = f.id.get_file_image()
        journal.write_bytes_durably(image, self.path)
        return ""

    def resume_change(self, plan: Plan, camera: dict[str, Any], stage: dict[str, Any],
                      calibration: CameraCalibration) -> str:
        """Refuse (RecordingError naming every difference, file value against now) to resume with other devices
        or a plan that changes recorded stops; return how the plan changes, in words ("" if it does not).
        Writes nothing."""
        with h5py.File(self.path, "r") as f:
            a = dict(f.attrs)
            cam_attrs = dict(f["camera"].attrs) if "camera" in f else {}
        try:
            old_params = json.loads(a.get("protocol_params", "{}"))
            old_camera = json.loads(a.get("camera", "{}"))
            old_stage = json.loads(a.get("stage", "{}"))
        except (TypeError, ValueError):
            raise RecordingError(f"{self.path}: its header attributes are not valid JSON; write a new file") from None
        recorded = self.completed_stops()
        diffs = resume_problems(str(a.get("protocol")), old_params, plan, recorded)
        old_cal = CameraCalibration(**{k: cam_attrs.get(k, getattr(calibration, k)) for k in vars(calibration)})
        diffs += _differences("camera", camera_identity(old_camera, old_cal), camera_identity(camera, calibration))
        diffs += _differences("stage", stage_identity(old_stage), stage_identity(stage))
        if diffs:
            raise RecordingError(f"{self.path} holds a different experiment ({'; '.join(diffs[:4])}"
                                 f"{'; ...' if len(diffs) > 4 else ''}); resume it with the devices and plan that made it "
                                 "(of the plan, only stops not yet recorded may change), or write a new file")
        return plan_change(old_params, plan.params)

    def _replace_plan(self, params: dict[str, Any]) -> None:
        """Put the resumed run's plan in the header (a copy, renamed into place: the file is old or new, never
        half), keeping the plans it replaces in `plan_history`."""
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.header")
        try:
            shutil.copyfile(self.path, tmp)
            with h5py.File(tmp, "a", libver=HDF5_LIBVER) as f:
                try:
                    history = json.loads(f.attrs.get("plan_history", "[]"))
                except (TypeError, ValueError):
                    history = []
                history = history if isinstance(history, list) else []
                history.append({"protocol_params": json.loads(f.attrs.get("protocol_params", "{}")),
                                "replaced_utc": utc_now()})
                f.attrs["plan_history"] = json.dumps(history)
                f.attrs["protocol_params"] = json.dumps(jsonable(params))
            journal.commit(tmp, self.path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise

    # -- stops -----------------------------------------------------------------------------
    def completed_stops(self) -> set[str]:
        """The stops --resume keeps: journaled ones, and those of the file that are complete, read back (checksums)
        and that a reader accepts (`Recording.stop`: every field and attribute checked). Any other stop is recorded
        again, and the assembly replaces it: what a reader skips, --resume repairs."""
        done = set(journal.completed_stop_files(self.path))
        found = set()
        try:
            with h5py.File(self.path, "r") as f:
                stops = f.get("stops", {})
                for k in list(stops):
                    try:  # one stop's damaged header is that stop's: the others are kept
                        if bool(stops[k].attrs.get("complete", False)) and _readable(stops[k]):
                            found.add(k)
                    except (OSError, RuntimeError, KeyError, ValueError, TypeError):
                        pass
        except (OSError, RuntimeError, KeyError, ValueError, TypeError):  # a header too damaged to list its stops
            return done
        try:
            with Recording(self.path) as rec:
                for label in sorted(found):
                    try:
                        rec.stop(label)
                        done.add(label)
                    except (RecordingError, OSError, RuntimeError, KeyError, ValueError, TypeError, IndexError):
                        pass
        except RecordingError:
            pass
        return done

    def begin_stop(self, label: str, *, index: int, commanded_position_m: float, measured_position_m: float,
                   settings_requested: dict[str, Any], settings_read_back: dict[str, Any],
                   keep_raw: bool = False) -> h5py.Group:
        """Open the stop's own file: in memory (written out whole by `end_stop`), or with raw frames on disk
        as `<label>.h5.partial`."""
        if self._open_stop is not None:
            raise RecordingError(f"stop {self._open_stop[1]!r} is still open; end it before beginning {label!r}")
        d = journal.journal_dir(self.path)
        d.mkdir(exist_ok=True)
        if keep_raw:
            partial = journal.partial_file(self.path, label)
            f = h5py.File(partial, "w", libver=HDF5_LIBVER)
        else:
            partial = None
            f = h5py.File(label, "w", driver="core", backing_store=False, libver=HDF5_LIBVER)
        self._open_stop = (f, label, partial)
        g = f.create_group(journal.STOP_GROUP)
        g.attrs["complete"] = False
        g.attrs["index"] = index
        g.attrs["commanded_position_m"] = commanded_position_m
        g.attrs["measured_position_m"] = measured_position_m
        g.attrs["settings_requested"] = json.dumps(settings_requested)
        g.attrs["settings_read_back"] = json.dumps(settings_read_back)
        g.attrs["started_utc"] = utc_now()
        return g

    def raw_frames(self, g: h5py.Group, n_frames: int, shape: tuple[int, int]) -> h5py.Dataset:
        """A dataset to stream a stop's raw depth frames into, one frame per row (begin the stop with keep_raw)."""
        return g.create_dataset("raw_depth", shape=(n_frames, *shape), dtype=np.uint16,
                                chunks=(1, *shape), compression="gzip", compression_opts=1)

    def end_stop(self, g: h5py.Group, *, stats: PixelStats, series: FrameSeries, ir_mean: np.ndarray | None,
                 ambient_ir_mean: np.ndarray | None, extra_attrs: dict[str, Any] | None = None,
                 ir_saturated: np.ndarray | None = None, ir_full_scale_dn: float | None = None) -> None:
        """Fill the stop and make it durable: when this returns, the stop survives any crash.

        ir_saturated: per pixel, the IR samples at the full scale `ir_full_scale_dn` (clipped), written with
        ir_mean, and the pixels with any as the stop's `ir_saturated_pixels` (docs/data-format.md)."""
        if self._open_stop is None:
            raise RecordingError("end_stop without begin_stop")
        f, label, partial = self._open_stop
        h, w = stats.count.shape
        # a flipped byte is an error, not a value (Fletcher-32); chunks of whole rows, about 256 kB, so a reader
        # takes a stop in a few dozen chunks (h5py's own guess cut a full-resolution stop into 128)
        comp = dict(compression="gzip", compression_opts=1, shuffle=True, fletcher32=True,
                    chunks=(max(1, min(h, (1 << 15) // max(w, 1))), w))
        g.create_dataset("count", data=stats.count, **comp)
        g.create_dataset("mean_m", data=stats.mean_m, **comp)
        g.create_dataset("m2_m2", data=stats.m2_m2, **comp)
        g.create_dataset("m3_m3", data=stats.m3_m3, **comp)
        g.create_dataset("m4_m4", data=stats.m4_m4, **comp)
        if stats.lag1_pairs is not None and stats.lag1_m2 is not None:  # frame independence (docs/data-format.md)
            g.create_dataset("lag1_pairs", data=stats.lag1_pairs, **comp)
            g.create_dataset("lag1_m2", data=stats.lag1_m2, **comp)
            g.attrs["frames_repeated"] = int(stats.frames_repeated or 0)
        if ir_mean is not None:
            g.create_dataset("ir_mean", data=ir_mean, **comp)
            if ir_saturated is not None and ir_full_scale_dn is not None:
                g.create_dataset("ir_saturated", data=ir_saturated.astype(np.uint32), **comp)
                g["ir_saturated"].attrs["full_scale_dn"] = float(ir_full_scale_dn)
                g.attrs["ir_saturated_pixels"] = int(np.count_nonzero(ir_saturated))
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
        final = journal.stop_file(self.path, label)
        self._open_stop = None
        if partial is None:
            f.flush()
            image = f.id.get_file_image()
            f.close()
            journal.write_bytes_durably(image, final)
        else:
            f.close()
            journal.commit(partial, final)

    def abandon_stop(self) -> None:
        """Drop the stop being written (an error or an abort): its partial file is removed."""
        if self._open_stop is None:
            return
        f, _, partial = self._open_stop
        self._open_stop = None
        try:
            f.close()
        except Exception:  # noqa: BLE001 - a failing file is being thrown away
            pass
        if partial is not None:
            partial.unlink(missing_ok=True)

    # -- the end -----------------------------------------------------------------------------
    def assembly_bytes(self) -> int:
        """Free space `finish` needs: a copy of the header file and of every stop file."""
        files = journal.completed_stop_files(self.path)
        return self.path.stat().st_size + sum(p.stat().st_size for p in files.values()) + FILE_OVERHEAD_BYTES

    def finish(self) -> None:
        """Copy the stops into a new run.h5 (written aside, renamed into place), then remove the stop files.
        A complete file is left as it is (its `ended_utc` too)."""
        files = journal.completed_stop_files(self.path)
        if not files:
            with h5py.File(self.path, "r") as f:
                complete = "ended_utc" in f.attrs
            if complete:  # a kill inside the last clean-up can leave the folder with no stop in it
                shutil.rmtree(journal.journal_dir(self.path), ignore_errors=True)
                return
        need, free = self.assembly_bytes(), free_bytes(self.path.parent)
        if need > free:
            raise RecordingError(f"disk full: assembling {self.path} needs about {megabytes(need)} and "
                                 f"{megabytes(free)} are free; free about {megabytes(need - free)} and rerun with --resume")
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.assembling")
        try:
            if need <= IN_MEMORY_ASSEMBLY_BYTES:
                # HDF5 gets no disk to write to: it assembles in memory and Python writes the file whole, so a full
                # disk is a plain OSError (HDF5 1.14 crashes in close() after a failed write: SIGSEGV, found by
                # injecting ENOSPC at each pwrite64, tests/fault_matrix.py)
                image = io.BytesIO(self.path.read_bytes())
                try:
                    with h5py.File(image, "a", libver=HDF5_LIBVER) as out:
                        _copy_stops(out, files)
                except _DamagedLink:  # a stop whose header is damaged cannot be unlinked: a new file without it
                    image = io.BytesIO()
                    _rebuild(self.path, image, files)
                journal.write_bytes_durably(image.getvalue(), self.path)
            else:  # too big for memory (raw frames kept): assembled on disk, beside the recording
                shutil.copyfile(self.path, tmp)
                try:
                    with h5py.File(tmp, "a", libver=HDF5_LIBVER) as out:
                        _copy_stops(out, files)
                except _DamagedLink:
                    _rebuild(self.path, tmp, files)
                journal.commit(tmp, self.path)
        except (OSError, RuntimeError) as e:  # h5py says a full disk as RuntimeError ("errno = 28")
            tmp.unlink(missing_ok=True)
            if not is_disk_full(e):
                raise
            raise AssemblyError(f"disk full while assembling {self.path} (it needs about {megabytes(need)}); every stop "
                                 f"stays readable in {journal.journal_dir(self.path)}; free some space and rerun with "
                                 "--resume") from None
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        shutil.rmtree(journal.journal_dir(self.path), ignore_errors=True)

    def close(self) -> None:
        self.abandon_stop()
        self.lock.release()

    def __enter__(self) -> "RecordingWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _DamagedLink(Exception):
    """A stop to replace whose object header is damaged: HDF5 cannot unlink it (its checksum fails)."""


def _rebuild(old_path: Path, target: Any, files: dict[str, Path]) -> None:
    """A new recording in `target` (a path or a file object): the old one's header and every stop of it that reads
    and is not replaced, then the completed stop files (`_copy_stops`). A stop that cannot be copied was skipped by
    every reader; it is left out (a replacement for it is in `files` when the plan still holds it)."""
    with h5py.File(old_path, "r") as old, h5py.File(target, "w", libver=HDF5_LIBVER) as out:
        out.attrs.update(dict(old.attrs))
        for name in old:
            if name != "stops":
                old.copy(old[name], out, name=name)
        stops = out.create_group("stops")
        for label in old["stops"]:
            if label not in files:
                try:
                    old.copy(old["stops"][label], stops, name=label)
                except (KeyError, RuntimeError, OSError, ValueError, TypeError):
                    pass
        _copy_stops(out, files)


def _copy_stops(out: h5py.File, files: dict[str, Path]) -> None:
    """Each completed stop file's group into the recording (replacing a stop of that label), then `ended_utc`."""
    stops = out.require_group("stops")
    for label, p in files.items():
        if label in stops:
            try:
                del stops[label]
            except (KeyError, RuntimeError) as e:
                raise _DamagedLink(label) from e
        with h5py.File(p, "r") as src:
            src.copy(src[journal.STOP_GROUP], stops, name=label)
    out.attrs["ended_utc"] = utc_now()


def _readable(g: h5py.Group) -> bool:
    """Every statistics dataset of a stop reads back (its Fletcher-32 checksums hold): a damaged stop is not done,
    so --resume records it again and the assembly replaces it. Raw frames are not read (their size)."""
    try:
        for name, item in g.items():
            if isinstance(item, h5py.Group):
                if not _readable(item):
                    return False
            elif name != "raw_depth":
                item[()]
    except (OSError, RuntimeError, ValueError, KeyError, TypeError):  # TypeError: a damaged object header's None
        return False
    return True
