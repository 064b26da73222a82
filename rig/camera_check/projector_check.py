"""`rig devices --check CAMERA`: does the camera hold its settings, and does the projector switch?

Captures with the projector on, then off, and reports per capture: fill rate, centre range,
exposure and gain as the frames report them and as read back, the IR pattern contrast, and
the Depth Quality Tool's figures (`rig.camera_check.depth_quality`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TextIO

import numpy as np

from drivers.camera import CameraSettings, DepthCamera, Frame
from drivers.errors import DeviceError
from drivers.image_regions import center_box
from protocols.runner import MAX_STALE_FRAMES, settings_mismatch

from ..devices import open_devices
from .depth_quality import DepthQuality, depth_quality


@dataclass
class ProjectorCheck:
    """What one capture with the projector on or off showed."""

    projector_on: bool
    frames: int
    fill_rate: float
    centre_range_m: float
    exposure_us: float  # median of the frames' metadata
    gain: float
    read_back: CameraSettings
    ir_contrast: float  # std / mean of the mean IR image's central region; 0 when dark
    ir_mean_dn: float
    mean_depth_m: np.ndarray

    def line(self) -> str:
        centre = f"{self.centre_range_m:.3f} m" if math.isfinite(self.centre_range_m) else "n/a"
        ir = "no IR image" if math.isnan(self.ir_contrast) else (
            f"IR pattern contrast {self.ir_contrast:.2f}" + (" (dark)" if self.ir_mean_dn < 1 else ""))
        rb = self.read_back
        return (f"projector {'on ' if self.projector_on else 'off'}: fill rate {100 * self.fill_rate:5.1f} %, "
                f"centre range {centre}, frames report exposure {self.exposure_us:g} us and gain {self.gain:g} "
                f"(read back {rb.exposure_us:g} us, gain {rb.gain:g}, auto-exposure {'on' if rb.auto_exposure else 'off'}), {ir}")


def _settled_frames(cam: DepthCamera, asked: CameraSettings, n: int) -> list[Frame]:
    """n frames whose metadata match the request, after at most 30 stale ones."""
    out: list[Frame] = []
    stale = 0
    while len(out) < n:
        for f in cam.frames(n - len(out), ir=True):
            bad = settings_mismatch(asked, f.metadata)
            if bad and not out and stale < MAX_STALE_FRAMES:
                stale += 1
                continue
            if bad:
                raise DeviceError(f"{cam.name}: frames report {', '.join(bad)}; the camera does not hold the settings")
            out.append(f)
    return out


def capture_check(cam: DepthCamera, asked: CameraSettings, n: int) -> ProjectorCheck:
    read_back = cam.configure(asked)
    frames = _settled_frames(cam, asked, n)
    scale = cam.info().depth_scale_m
    shape = frames[0].depth.shape
    cy, cx = center_box(shape)
    total = np.zeros(shape)
    count = np.zeros(shape)
    centre = []
    ir_sum = None
    for f in frames:
        valid = f.depth > 0
        total += np.where(valid, f.depth * scale, 0.0)
        count += valid
        c = f.depth[cy, cx]
        if (c > 0).any():
            centre.append(float(np.median(c[c > 0])) * scale)
        if f.ir is not None:
            ir_sum = f.ir.astype(np.float64) if ir_sum is None else ir_sum + f.ir
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_depth = np.where(count > 0, total / count, np.nan)
    contrast = mean_dn = float("nan")
    if ir_sum is not None:
        ir = (ir_sum / len(frames))[cy, cx]
        mean_dn = float(ir.mean())
        contrast = float(ir.std() / mean_dn) if mean_dn >= 1 else 0.0
    return ProjectorCheck(
        projector_on=asked.projector_on,
        frames=len(frames),
        fill_rate=float(np.mean([np.count_nonzero(f.depth) / f.depth.size for f in frames])),
        centre_range_m=float(np.median(centre)) if centre else float("nan"),
        exposure_us=float(np.median([f.metadata.exposure_us for f in frames])),
        gain=float(np.median([f.metadata.gain for f in frames])),
        read_back=read_back,
        ir_contrast=contrast,
        ir_mean_dn=mean_dn,
        mean_depth_m=mean_depth,
    )


def contrast_changed(on: ProjectorCheck, off: ProjectorCheck) -> bool:
    """Did switching the projector change the IR image's pattern contrast (by a half and by 0.05)?"""
    if math.isnan(on.ir_contrast) or math.isnan(off.ir_contrast):
        return False
    hi, lo = max(on.ir_contrast, off.ir_contrast), min(on.ir_contrast, off.ir_contrast)
    return hi - lo > 0.05 and hi > 1.5 * lo


def run_check(camera: str, *, seconds: float, exposure_us: float, gain: float | None, truth_m: float | None,
              out: TextIO) -> int:
    """gain: in rig's unit, the same on every camera (16 = x1, the default); truth_m: the true distance, which a
    simulated camera knows itself."""
    devices = open_devices(camera, "none:")
    cam = devices.camera
    if gain is None:
        gain = CameraSettings().gain
    if truth_m is None:
        truth_m = cam.true_distance_m()
    with cam:
        info = cam.info()
        fps = float(info.extra.get("fps", 30.0))
        n = max(5, int(round(seconds * fps / 2)))
        print(f"checking {camera}: {info.model}, serial {info.serial}, firmware {info.firmware}; "
              f"{n} frames with the projector on, then {n} with it off", file=out)
        on = capture_check(cam, CameraSettings(projector_on=True, exposure_us=exposure_us, gain=gain), n)
        off = capture_check(cam, CameraSettings(projector_on=False, exposure_us=exposure_us, gain=gain), n)
    print(on.line(), file=out)
    print(off.line(), file=out)
    changed = contrast_changed(on, off)
    if math.isnan(on.ir_contrast):
        print("IR pattern contrast: the camera gave no IR image; cannot tell whether the projector switched", file=out)
    else:
        print(f"IR pattern contrast changed when the projector was switched: {'yes' if changed else 'NO'} "
              f"({on.ir_contrast:.2f} on, {off.ir_contrast:.2f} off)" + (
                  "" if changed else "; the projector may not be switching: check the emitter control"), file=out)
    i = info.intrinsics
    for check in (on, off):
        q: DepthQuality = depth_quality(check.mean_depth_m, fx=i.fx, fy=i.fy, cx=i.cx, cy=i.cy,
                                        baseline_m=info.baseline_m, truth_m=truth_m)
        print(f"depth quality, projector {'on ' if check.projector_on else 'off'} (central {100 * q.roi:.0f} %): "
              f"{q.summary()}", file=out)
    return 0
