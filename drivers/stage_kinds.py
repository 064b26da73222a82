"""The stage kinds of rig's real stages, as registry entries (`DeviceKind`), named by the entry points
`rig.stages` in pyproject.toml: `none:` (drivers.stage), `grbl:` and `zaber:` (drivers.serial).

The two serial stages share one probe: the USB serial ports, with the protocol each most likely speaks
(`drivers.listing.list_serial_ports`). Factories, tables and the probe are named as "module:attr", so
listing the kinds imports no driver.
"""

from __future__ import annotations

from .registry import DeviceKind, Probe

#: the USB serial ports, for every stage kind that talks over one
SERIAL_PORTS = Probe("serial", "drivers.listing:list_serial_ports")

NONE = DeviceKind("none", "stage", "drivers.stage:no_stage", "drivers.stage:NO_STAGE_OPTIONS",
                  summary="no stage: the distance is set by hand or fixed")
GRBL = DeviceKind("grbl", "stage", "drivers.serial.grbl:open_grbl", "drivers.serial.rail:GRBL_OPTIONS", SERIAL_PORTS,
                  summary="a GRBL controller on a serial port")
ZABER = DeviceKind("zaber", "stage", "drivers.serial.zaber:open_zaber", "drivers.serial.rail:ZABER_OPTIONS",
                   SERIAL_PORTS, summary="a Zaber controller (ASCII protocol) on a serial port")
