"""Small simulated experiments for tests: the real runner, real files, the fake devices."""

from __future__ import annotations

from pathlib import Path

from drivers.camera import CameraSettings
from protocols import Runner, perpendicular
from rig.devices import open_devices


def record_perpendicular(path: Path, *, seed: int = 0, width: int = 32, frames: int = 100, projector_on: bool = True,
                         depth_unit_mm: float = 0.05, effects: str = "", stops_m=None, resume: bool = False,
                         camera_options: str = "", **plan_kw):
    """Record a small perpendicular experiment; return (path, (k_true, lambda_true), devices). `camera_options`: more of
    the fake camera's device-string options, e.g. "warmup_sd=0.1,light=day"."""
    height = max(2, round(width * 480 / 848))
    cam = f"fake:width={width},height={height},depth_unit_mm={depth_unit_mm},seed={seed}"
    if camera_options:
        cam += f",{camera_options}"
    if effects:
        cam += f",effects={effects}"
    devices = open_devices(cam, "fake:")
    kw = dict(frames_per_stop=frames, projector_on=projector_on, **plan_kw)
    if stops_m is not None:
        kw["stops_m"] = stops_m
    plan = perpendicular(**kw)
    Runner(devices.camera, devices.stage, sleep=devices.sleep).run(plan, path, resume=resume)
    truth = devices.camera.base_truth(CameraSettings(projector_on=projector_on, exposure_us=plan.params["exposure_us"],
                                                     gain=plan.params["gain"]))
    return path, truth, devices
