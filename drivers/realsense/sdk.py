"""pyrealsense2, imported on demand, and what it tells about attached cameras.

Importing this module never imports pyrealsense2; `sdk()` does, and turns a missing package
or a missing system libusb into a one-line `CameraError` naming what to install.
"""

from __future__ import annotations

from typing import Any

from ..errors import CameraError

INSTALL_SDK = "pip install pyrealsense2"
INSTALL_LIBUSB = "apt-get install libusb-1.0-0"


def sdk() -> Any:
    """Import pyrealsense2, or raise a one-line CameraError saying what is missing and how to install it."""
    try:
        import pyrealsense2 as rs
    except ImportError as e:
        raise CameraError(import_problem(e)) from None
    if not hasattr(rs, "context"):  # the package is there but its compiled module did not load
        raise CameraError(f"realsense: pyrealsense2 is installed but incomplete; reinstall it with "
                          f"'pip install --force-reinstall pyrealsense2' and '{INSTALL_LIBUSB}'")
    return rs


def import_problem(e: ImportError) -> str:
    """The one-line message for a failed `import pyrealsense2`."""
    text = (str(e).splitlines() or [""])[0]
    if "libusb" in text:
        return (f"realsense: the system library libusb-1.0 that pyrealsense2 needs is missing ({text}); "
                f"install it with '{INSTALL_LIBUSB}', or simulate a camera with --camera fake:")
    if getattr(e, "name", None) == "pyrealsense2" or isinstance(e, ModuleNotFoundError):
        return (f"realsense: the Python package pyrealsense2 is not installed; install it with '{INSTALL_SDK}' "
                f"(it also needs '{INSTALL_LIBUSB}'), or simulate a camera with --camera fake:")
    return (f"realsense: pyrealsense2 failed to import ({text}); reinstall it with '{INSTALL_SDK}' "
            f"and '{INSTALL_LIBUSB}', or simulate a camera with --camera fake:")


def one_line(e: BaseException) -> str:
    return (str(e).strip().splitlines() or [type(e).__name__])[0]


def device_info(rs: Any, dev: Any, key: str) -> str:
    ci = getattr(rs.camera_info, key, None)
    try:
        return str(dev.get_info(ci)) if ci is not None and dev.supports(ci) else ""
    except RuntimeError:
        return ""


def list_realsense() -> list[dict[str, str]]:
    """Connected RealSense cameras as plain data (for `rig devices`); raises CameraError without the SDK."""
    rs = sdk()
    out = []
    for d in rs.context().query_devices():
        out.append({"kind": "realsense", "model": device_info(rs, d, "name"), "serial": device_info(rs, d, "serial_number"),
                    "firmware": device_info(rs, d, "firmware_version"), "usb": device_info(rs, d, "usb_type_descriptor"),
                    "string": f"realsense:serial={device_info(rs, d, 'serial_number')}"})
    return out
