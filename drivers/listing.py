"""What is attached: every kind's probe (drivers.registry), and the USB serial ports with the stage protocol
they likely speak (the probe of the serial stage kinds).

Each probe runs in its own thread with a deadline, so a driver that hangs cannot stall the listing, and with
the process's standard output pointed at standard error, so an SDK's chatter never mixes into the listing
(drivers.console).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

from .console import sdk_chatter_to_stderr
from .errors import DeviceError
from .registry import Found, kind, kind_names

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


@dataclass(frozen=True)
class ProbeSet:
    """The probes to run, by name, and which of them list cameras (the others list stage connections)."""

    probes: dict[str, Callable[[], list[Found]]]
    cameras: frozenset[str]


def probes() -> ProbeSet:
    """Every distinct probe of every installed kind (kinds that share one, as the serial stages do, run it once).
    A kind that cannot be loaded (a broken plugin) becomes a probe that says so, in the listing's notes."""
    table: dict[str, Callable[[], list[Found]]] = {}
    cameras: set[str] = set()
    for what in ("camera", "stage"):
        for name in kind_names(what):
            try:
                k = kind(what, name)
            except DeviceError as e:
                table.setdefault(name, _refusal(e))
                continue
            if k.probe is not None:
                table.setdefault(k.probe.name, k.probe)
                if what == "camera":
                    cameras.add(k.probe.name)
    return ProbeSet(table, frozenset(cameras))


def _refusal(error: DeviceError) -> Callable[[], list[Found]]:
    def probe() -> list[Found]:
        raise error

    return probe


def probe_all(deadline_s: float = LIST_DEADLINE_S, which: ProbeSet | None = None
              ) -> tuple[dict[str, list[Found]], list[str]]:
    """Run every probe at once; return what answered by the deadline, and one note per probe that did not."""
    run_these = (which or probes()).probes
    results: dict[str, list[Found]] = {}
    notes: dict[str, str] = {}

    def run(name: str, probe: Callable[[], list[Found]]) -> None:
        try:
            results[name] = probe()
        except DeviceError as e:
            notes[name] = str(e)
        except Exception as e:  # a driver's own failure must not hide the other probes
            notes[name] = f"{name}: the probe failed ({(str(e).splitlines() or [type(e).__name__])[0]})"

    threads = [threading.Thread(target=run, args=(n, p), daemon=True) for n, p in run_these.items()]
    t0 = time.monotonic()
    with sdk_chatter_to_stderr():
        for t in threads:
            t.start()
        for t in threads:
            t.join(max(0.0, deadline_s - (time.monotonic() - t0)))
    for name in run_these:
        if name not in results and name not in notes:
            notes[name] = f"{name}: no answer within {deadline_s:g} s (the SDK may be searching the network); skipped"
    return results, [notes[n] for n in run_these if n in notes]
