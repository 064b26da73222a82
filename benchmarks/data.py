"""The benchmark's data: a perpendicular sweep recorded by `rig run` (timed: the whole-run figure), a small
recording that keeps its raw frames (for the per-sample baseline), and a folder of 16-bit PNGs for `rig import`."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .figures import run_measured

RIG = str(Path(sys.executable).with_name("rig"))


@dataclass(frozen=True)
class Size:
    """The sweep's image size and frames per stop (11 stops, 0.5-3.0 m), and the PNG folder's frames."""

    width: int
    height: int
    frames: int
    png_frames: int

    @property
    def pixel_stops(self) -> int:
        return 11 * self.width * self.height


FULL = Size(848, 480, 300, 1100)
QUICK = Size(212, 120, 30, 110)


def sweep_path(workdir: Path, size: Size) -> Path:
    """Where the sweep of `size` is (or will be) recorded in `workdir`."""
    return workdir / f"sweep-{size.width}x{size.height}-{size.frames}.h5"


def sweep(workdir: Path, size: Size) -> tuple[Path, float, float]:
    """The sweep (recorded now, or kept from an earlier run with --keep): (path, CPU s, wall s) of `rig run`."""
    path = sweep_path(workdir, size)
    if path.exists():
        return path, float("nan"), float("nan")
    cpu, _, wall, _ = run_measured([RIG, "-q", "run", "--protocol", "perpendicular", "--camera",
                                    f"fake:width={size.width},height={size.height},depth_unit_mm=0.1",
                                    "--frames", str(size.frames), "-o", str(path)])
    return path, cpu, wall


def raw_recording(workdir: Path) -> Path:
    """106x60, 11 stops of 30 frames, raw frames kept: 2.1 million samples the per-sample baseline can fit."""
    path = workdir / "raw-106x60.h5"
    if not path.exists():
        from protocols import Runner, perpendicular
        from rig.devices import open_devices

        devices = open_devices("fake:width=106,height=60,depth_unit_mm=0.1,seed=3", "fake:")
        Runner(devices.camera, devices.stage, sleep=devices.sleep).run(
            perpendicular(frames_per_stop=30, keep_raw=True, ir=False), path)
    return path


def png_folder(workdir: Path, size: Size) -> Path:
    """`size.png_frames` 16-bit PNGs of the fake camera in 11 stop folders, with a manifest (docs/import.md)."""
    folder = workdir / f"pngs-{size.width}x{size.height}-{size.png_frames}"
    if (folder / "rig-import.toml").exists():
        return folder
    from PIL import Image

    from drivers.camera import CameraSettings
    from fakes.camera import FakeCamera
    from fakes.world import FakeWorld

    world = FakeWorld.perpendicular(1.0)
    cam = FakeCamera(world, width=size.width, height=size.height, depth_scale_m=1e-4)
    per_stop = size.png_frames // 11
    with cam:
        cam.configure(CameraSettings())
        for i, z in enumerate(np.linspace(0.5, 3.0, 11)):
            world.wall.distance_m = float(z)
            stop = folder / f"{z:.2f}m"
            stop.mkdir(parents=True, exist_ok=True)
            for j, f in enumerate(cam.frames(per_stop)):
                Image.fromarray(f.depth).save(stop / f"depth_{j:04d}.png")
    i = cam.intrinsics
    (folder / "rig-import.toml").write_text(
        f"fx = {i.fx}\nfy = {i.fy}\ncx = {i.cx}\ncy = {i.cy}\nbaseline_m = 0.05\ndepth_unit_m = 0.0001\n"
        f"projector_on = true\nstop_distance_from_name = '([0-9.]+)m'\n")
    return folder


def demo_recording(workdir: Path) -> Path:
    """The demo's hidden-effect recording as `rig demo` makes it (106x60 px, 11 stops of 100 frames, a 0.05 mm
    depth unit, a disparity noise floor the paper's model lacks): what issue 30's operator waits on."""
    path = workdir / "demo-106x60-unknown.h5"
    if not path.exists():
        from rig.simulation.demo import record_unknown

        record_unknown(path, seed=0)  # the fake camera's seed 7, as the benchmark has used
    return path
