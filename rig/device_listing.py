"""`rig devices`: what is attached, and a quick check of a camera.

    rig devices                      connected cameras (RealSense, OAK) and serial ports, in under 5 s
    rig devices --check CAMERA       capture with the projector on, then off: fill rate, centre range,
                                     exposure and gain read back, whether the IR pattern contrast
                                     changed, and the Depth Quality Tool's figures (rig.depth_quality)

Each probe runs in its own thread with a deadline, so a driver that hangs cannot stall the listing.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable, TextIO

import numpy as np

from drivers.camera import CameraSettings, DepthCamera, Frame
from drivers.errors import DeviceError

from .depth_quality import DepthQuality, depth_quality
from .image_regions import center_box

LIST_DEADLINE_S = 4.0

#: (vendor id, product id or None, likely stage protocol, what the adapter usually is)
USB_SERIAL_HINTS = [
    (0x2341, None, "grbl", "Arduino (GRBL controllers are usually Arduino-based)"),
    (0x2A03, None, "grbl", "Arduino"),
    (0x1A86, 0x7523, "grbl", "CH340 USB-serial (Arduino clones, CNC boards running GRBL)"),
    (0x10C4, 0xEA60, "grbl", "CP210x USB-serial (CNC boards running GRBL)"),
    (0x0403, None, "zaber or grbl", "FTDI USB-serial (Zaber controllers and some CNC boards)"),
]


# -- listing ------------------------------------------------------------------------------------

def list_serial_ports() -> list[dict[str, str]]:
    """USB serial ports with their ids and the stage protocol they most likely speak."""
    from serial.tools import list_ports

    out = []
    for p in sorted(list_ports.comports(), key=lambda p: p.device):
        if p.vid is None:  # a built-in port (/dev/ttyS*), not something plugged in
            continue
        text = " ".join(str(x) for x in (p.description, p.manufacturer, p.product) if x).lower()
        protocol, what = "unknown", ""
        if "zaber" in text:
            protocol, what = "zaber", "Zaber controller"
        else:
            for vid, pid, proto, desc in USB_SERIAL_HINTS:
                if p.vid == vid and (pid is None or p.pid == pid):
                    protocol, what = proto, desc
                    break
        kind = protocol if protocol in ("grbl", "zaber") else "grbl"
        out.append({"port": p.device, "description": p.description or "", "usb": f"{p.vid:04x}:{p.pid or 0:04x}",
                    "serial": p.serial_number or "", "protocol": protocol, "adapter": what,
                    "string": f"{kind}://{p.device}"})
    return out


def _realsense() -> list[dict[str, str]]:
    from drivers.realsense import list_realsense

    return list_realsense()


def _oak() -> list[dict[str, str]]:
    from drivers.oak import list_oak

    return list_oak()


PROBES: dict[str, Callable[[], list[dict[str, str]]]] = {"realsense": _realsense, "oak": _oak, "serial": list_serial_ports}


def probe_all(deadline_s: float = LIST_DEADLINE_S) -> tuple[dict[str, list[dict[str, str]]], list[str]]:
    """Run every probe at once; return what answered by the deadline, and one note per probe that did not."""
    results: dict[str, list[dict[str, str]]] = {}
    notes: dict[str, str] = {}

    def run(name: str, probe: Callable[[], list[dict[str, str]]]) -> None:
        try:
            results[name] = probe()
        except DeviceError as e:
            notes[name] = str(e)
        except Exception as e:  # a driver's own failure must not hide the other probes
            notes[name] = f"{name}: the probe failed ({(str(e).splitlines() or [type(e).__name__])[0]})"

    threads = [threading.Thread(target=run, args=(n, p), daemon=True) for n, p in PROBES.items()]
    t0 = time.monotonic()
    for t in threads:
        t.start()
    for t in threads:
        t.join(max(0.0, deadline_s - (time.monotonic() - t0)))
    for name in PROBES:
        if name not in results and name not in notes:
            notes[name] = f"{name}: no answer within {deadline_s:g} s (the SDK may be searching the network); skipped"
    return results, [notes[n] for n in PROBES if n in notes]


def print_listing(out: TextIO, deadline_s: float = LIST_DEADLINE_S) -> int:
    results, notes = probe_all(deadline_s)
    cameras = results.get("realsense", []) + results.get("oak", [])
    ports = results.get("serial", [])
    print("cameras:", file=out)
    for c in cameras:
        print(f"  {c['kind']:<9} {c['model']:<32} id {c['serial']:<20} firmware {c['firmware']:<16} USB {c['usb']:<10} "
              f"-> --camera {c['string']}", file=out)
    if not cameras:
        print("  none found", file=out)
    print("serial ports:", file=out)
    for p in ports:
        adapter = f", {p['adapter']}" if p["adapter"] else ""
        print(f"  {p['port']:<14} {p['description']:<30} USB {p['usb']} serial {p['serial'] or '-'}: likely "
              f"{p['protocol']}{adapter} -> --stage {p['string']}", file=out)
    if not ports:
        print("  none found", file=out)
    for n in notes:
        print(f"note: {n}", file=out)
    if not cameras and not ports:
        print("nothing is attached: no RealSense or OAK camera and no USB serial port found; "
              "simulate a rig with --camera fake: --stage fake:", file=out)
    return 0


# -- the check -----------------------------------------------------------------------------------

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
    from protocols.runner import MAX_STALE_FRAMES, settings_mismatch

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
    from .devices import _load_plugins, open_devices

    _load_plugins()
    for module in ("drivers.realsense", "drivers.oak"):  # the camera kinds of this change
        __import__(module)
    devices = open_devices(camera, "none:")
    cam = devices.camera
    if gain is None:
        gain = 100.0 if camera.split(":", 1)[0].strip().lower() == "oak" else 16.0
    if truth_m is None and camera.split(":", 1)[0].strip().lower() == "fake":
        truth_m = devices.world.wall.distance_m
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


def devices_main(argv: list[str] | None = None, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    p = argparse.ArgumentParser(prog="rig devices", description="List attached cameras and serial ports, or check a camera.")
    p.add_argument("--check", metavar="CAMERA", help="capture with the projector on and off, e.g. realsense: or fake:")
    p.add_argument("--seconds", type=float, default=4.0, help="capture time for --check, split between on and off (default 4)")
    p.add_argument("--exposure-us", type=float, default=8500.0, help="exposure for --check (default 8500 us)")
    p.add_argument("--gain", type=float, help="gain for --check (default 16 on a RealSense, ISO 100 on an OAK)")
    p.add_argument("--distance", type=float, help="true camera-to-wall distance in m, for the range error")
    args = p.parse_args(argv)
    if args.check is None:
        return print_listing(out)
    try:
        return run_check(args.check, seconds=args.seconds, exposure_us=args.exposure_us, gain=args.gain,
                         truth_m=args.distance, out=out)
    except DeviceError as e:
        print(f"rig devices: error: {e}", file=sys.stderr)
        return 2
