"""Importing folders of depth frames (`rig import`): folders of depth frames (16-bit PNG or .npy) become a normal recording.

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

import json
import os
import shutil
from pathlib import Path
from typing import Any, Callable

import h5py

from drivers.camera import CameraSettings
from drivers.errors import FolderImportError
from drivers.folder import FolderCamera, ImportSettings, StopSource, check_stops, find_stops, load_settings
from drivers.stage import NoStage

from .disk_space import is_disk_full, is_storage_failure
from .leftovers import remove_dead_leftovers
from .plan import Capture, Configure, Move, Plan
from .recording import HDF5_LIBVER
from .stop_journal import journal_dir
from .runner import PlanRefused, ProgressCallback, ProgressEvent, Runner, RunError

PROTOCOL = "import"


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


def import_folder(src: str | Path, out: str | Path, overrides: dict[str, Any] | None = None,
                  progress: ProgressCallback | None = None) -> Path:
    """Import a folder of stops into the recording `out`; return its path.

    overrides: manifest keys to set or replace (e.g. from command-line flags), None values ignored.
    progress: called with the runner's `ProgressEvent`s (rig.cli.progress.TerminalProgress shows them).
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
    def fill(tmp: Path) -> None:
        _record(stops, settings, shape, src, tmp, progress)
        write_provenance(tmp, src, manifest, overrides, stops)

    return write_aside(src, out, fill)


def write_aside(src: Path, out: Path, fill: Callable[[Path], None]) -> Path:
    """Make the recording `out` by `fill(tmp)` on a temporary file beside it, renamed in when whole: a failed
    import leaves no file (a killed one's leftovers go at the next import, protocols.leftovers); a full or failing
    disk is one line."""
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_dead_leftovers(out)  # a killed import's temporary recording, its lock and stop folder
    tmp = out.with_name(f".{out.name}.{os.getpid()}.importing")
    tmp.unlink(missing_ok=True)
    try:
        fill(tmp)
        if out.exists():
            raise FolderImportError(f"{out} appeared during the import; choose another output file")
        tmp.rename(out)
    except BaseException as e:
        tmp.unlink(missing_ok=True)
        shutil.rmtree(journal_dir(tmp), ignore_errors=True)
        if isinstance(e, (OSError, RuntimeError)) and (is_disk_full(e) or is_storage_failure(e)):  # h5py: RuntimeError
            raise import_stopped(src, e) from None
        raise
    return out


def _check_paths(src: Path, out: Path) -> None:
    if not src.is_dir():
        raise FolderImportError(f"{src} is not a folder; pass the folder that holds one sub-folder per stop")
    _check_paths_out(out)


def _check_paths_out(out: Path) -> None:
    if out.exists():
        raise FolderImportError(f"{out} already exists; choose another output file")


def _record(stops: list[StopSource], settings: ImportSettings, shape: tuple[int, int], src: Path, path: Path,
            progress: ProgressCallback | None) -> None:
    camera = FolderCamera(stops, settings, shape, src.resolve())
    try:
        Runner(camera, NoStage(), progress=progress, sleep=lambda s: None).run(import_plan(stops, settings, src.resolve()), path)
    except PlanRefused as e:
        raise FolderImportError(f"import of {src} refused before it started: {'; '.join(e.problems)}; "
                                "nothing was written") from None
    except RunError as e:
        raise import_stopped(src, e) from None


def import_stopped(src: Path, e: BaseException) -> FolderImportError:
    """The one line for an import the runner (or a full disk) stopped: what stopped it, that nothing was written,
    and, for a full disk, how much to free."""
    parts = str(e).split("; ")
    free = next((p.split(" and ")[0] for p in parts if p.startswith("free about")), "")
    full = is_disk_full(e) or "disk full" in str(e)
    fix = f"; {free} and import again" if free else ("; free some space and import again" if full else "")
    what = parts[0] if isinstance(e, RunError) else \
        f"{'disk full' if full else 'the disk failed'} writing its provenance ({type(e).__name__})"
    return FolderImportError(f"import of {src} stopped ({what}); nothing was written{fix}")


def write_provenance(path: Path, src: Path, manifest: dict[str, Any], overrides: dict[str, Any] | None,
                     stops: list[StopSource]) -> None:
    """Where the frames came from: the folder, the manifest as read, the overrides, each stop's files."""
    with h5py.File(path, "a", libver=HDF5_LIBVER) as f:
        f.attrs["import_source_folder"] = str(src.resolve())
        f.attrs["import_manifest"] = json.dumps(manifest, default=str)
        f.attrs["import_overrides"] = json.dumps({k: v for k, v in (overrides or {}).items() if v is not None}, default=str)
        for s in stops:
            g = f["stops"][s.name]
            g.attrs["source_folder"] = s.name
            g.attrs["source_files"] = json.dumps([p.path.name for p in s.depth_files])
            g.attrs["source_ir_files"] = json.dumps([p.path.name for p in s.ir_files])
            g.attrs["source_n_frames"] = s.n_frames
