"""A RealSense camera's identity and calibration, read once when it is opened.

Intrinsics of the depth stream, the depth unit, the stereo baseline (from the IR imagers'
extrinsics, else the camera's own option), and everything else worth keeping with a
recording: SDK version, USB link, every option's value, the visual preset and advanced mode.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from ..camera import CameraInfo, Intrinsics
from ..errors import CameraError
from .sdk import device_info


def read_info(rs: Any, dev: Any, sensor: Any, depth_profile: Any, ir_profile: Any, *, name: str,
              playback_file: Path | None, record: Path | None, advanced_mode: bool) -> CameraInfo:
    """Identity and calibration of an open camera (or recording, or software device)."""
    s = sensor
    depth = depth_profile.as_video_stream_profile()
    intr = depth.get_intrinsics()
    intrinsics = Intrinsics(width=intr.width, height=intr.height, fx=float(intr.fx), fy=float(intr.fy),
                            cx=float(intr.ppx), cy=float(intr.ppy))
    if s.supports(rs.option.depth_units):
        depth_scale = float(s.get_option(rs.option.depth_units))
    else:
        depth_scale = float(s.as_depth_sensor().get_depth_scale())
    baseline, source = stereo_baseline(rs, s, depth_profile, name)
    extra: dict[str, Any] = {
        "sdk": "pyrealsense2 " + str(getattr(rs, "__version__", "?")),
        "source": f"playback of {playback_file}" if playback_file is not None else "device",
        "fps": depth.fps(),
        "depth_stream": f"{intr.width}x{intr.height} z16 @ {depth.fps()} fps",
        "ir_stream": "left y8" if ir_profile is not None else "off",
        "distortion": {"model": str(intr.model).split(".")[-1], "coeffs": [float(c) for c in intr.coeffs]},
        "baseline_source": source,
        # librealsense's post-processing blocks (rs.decimation_filter, spatial, temporal, hole filling) run on the
        # host only when a program applies them; the driver applies none: depth is the camera's raw Z16 (issue 31)
        "post_processing": "none: no librealsense processing block applied (raw Z16 depth)",
    }
    for key in ("usb_type_descriptor", "product_line", "product_id", "camera_locked", "firmware_update_id",
                "asic_serial_number", "physical_port"):
        v = device_info(rs, dev, key)
        if v:
            extra["usb_type" if key == "usb_type_descriptor" else key] = v
    if record is not None:
        extra["recording_to"] = str(record)
    extra["options"] = all_options(s)
    if s.supports(rs.option.visual_preset):
        v = s.get_option(rs.option.visual_preset)
        try:
            extra["visual_preset"] = s.get_option_value_description(rs.option.visual_preset, v)
        except RuntimeError:
            extra["visual_preset"] = v
    adv = advanced_mode_json(rs, dev) if advanced_mode else None
    if adv is not None:
        extra["advanced_mode_json"] = adv
    return CameraInfo(
        model=device_info(rs, dev, "name") or "Intel RealSense",
        serial=device_info(rs, dev, "serial_number") or "",
        firmware=device_info(rs, dev, "firmware_version") or "",
        intrinsics=intrinsics,
        baseline_m=baseline,
        depth_scale_m=depth_scale,
        extra=extra,
    )


def stereo_baseline(rs: Any, sensor: Any, depth_profile: Any, name: str) -> tuple[float, str]:
    """Baseline in m: extrinsics between the IR imagers, else depth -> right IR, else the option."""
    profiles = list(sensor.get_stream_profiles())
    ir1 = [p for p in profiles if p.stream_type() == rs.stream.infrared and p.stream_index() == 1]
    ir2 = [p for p in profiles if p.stream_type() == rs.stream.infrared and p.stream_index() == 2]
    for source, a, b in (("extrinsics left IR -> right IR", ir1, ir2), ("extrinsics depth -> right IR", [depth_profile], ir2)):
        if a and b:
            try:
                t = a[0].get_extrinsics_to(b[0]).translation
            except RuntimeError:
                continue
            b_m = math.sqrt(sum(float(x) ** 2 for x in t))
            if b_m > 1e-4:
                return b_m, source
    if sensor.supports(rs.option.stereo_baseline):
        return float(sensor.get_option(rs.option.stereo_baseline)) / 1000.0, "option stereo_baseline (mm)"
    raise CameraError(f"{name}: the camera reports no baseline (no right-IR extrinsics and no stereo_baseline "
                      "option); record the right IR stream too, or use a D4xx camera")


def all_options(sensor: Any) -> dict[str, float]:
    """Every option the sensor supports, with its current value."""
    out: dict[str, float] = {}
    for opt in sensor.get_supported_options():
        try:
            out[str(opt).split(".")[-1]] = float(sensor.get_option(opt))
        except RuntimeError:
            pass
    return out


def advanced_mode_json(rs: Any, dev: Any) -> str | None:
    """The D4xx advanced-mode settings as JSON, when advanced mode is on."""
    try:
        adv = rs.rs400_advanced_mode(dev)
        return adv.serialize_json() if adv.is_enabled() else None
    except (RuntimeError, TypeError):
        return None
