"""What `rig stage-sim grbl|zaber` runs: serve a simulated stage controller on a pseudo-terminal until Ctrl-C,
so the serial drivers (and a whole run) can be tried without hardware."""

from __future__ import annotations

import signal
import sys
import threading
import time

from .grbl_sim import GrblSim
from .pty_controller import PtyController
from .zaber_sim import ZaberSim


def build_simulator(kind: str, *, travel_mm: float = 3000.0, speed_mm_s: float = 250.0, soft_limits: bool = True,
                    homing: bool = True, microstep_um: float = 0.1905) -> tuple[PtyController, str]:
    """A simulated controller ("grbl" or "zaber"), and the device-string options that fit it."""
    if kind == "grbl":
        sim: PtyController = GrblSim(travel_mm=travel_mm, speed_mm_s=speed_mm_s,
                                      soft_limits=soft_limits and homing, homing=homing)  # $20 needs $22
        # the driver reads the travel ($130) and the feed cap ($110) from the controller
        return sim, f"offset_m=0.3&feed={speed_mm_s * 60:g}" + ("" if homing else "&homing=0")
    sim = ZaberSim(travel_mm=travel_mm, speed_mm_s=speed_mm_s, microstep_um=microstep_um)
    return sim, f"offset_m=0.3&microstep_um={microstep_um:g}"


def _read_faults(sim: PtyController) -> None:
    """Inject the faults typed on stdin, one name (and optional mm=N) a line, until EOF."""
    for line in sys.stdin:
        words = line.split()
        if not words:
            continue
        params = dict(w.split("=", 1) for w in words[1:] if "=" in w)
        try:
            sim.inject(words[0], **{k: float(v) for k, v in params.items()})
            print(f"injected {words[0]}", flush=True)
        except ValueError as e:
            print(e, flush=True)


def _raise_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def serve(kind: str, *, verbose: bool = False, **options: float | bool) -> int:
    """Start the simulator, print its port and an example run line, serve until Ctrl-C (or SIGTERM).
    Typing a fault name (e.g. `noise`, `unplug`, `position_error mm=3`) injects it."""
    sim, device_options = build_simulator(kind, **options)  # type: ignore[arg-type]
    # stop cleanly on SIGTERM as on Ctrl-C (a process started in the background by a
    # non-interactive shell ignores SIGINT, so a supervisor stops it with SIGTERM)
    signal.signal(signal.SIGTERM, _raise_interrupt)
    with sim:
        device = f"{kind}://{sim.port}?{device_options}"
        print(f"simulated {kind} controller on {sim.port}")
        print(f"try:  rig run --stage '{device}' ...")
        print("(quote the device string: it contains ? and &)  Ctrl-C to stop")
        print(f"type a fault and Enter to inject it: {', '.join(sim.faults)}", flush=True)
        threading.Thread(target=_read_faults, args=(sim,), daemon=True).start()
        shown_commands = shown_replies = 0
        try:
            while sim.running:
                time.sleep(0.1)
                if verbose:
                    for text in sim.commands[shown_commands:]:
                        print(f"-> {text}")
                    for text in sim.replies[shown_replies:]:
                        print(f"<- {text}")
                    shown_commands, shown_replies = len(sim.commands), len(sim.replies)
                    sys.stdout.flush()
        except KeyboardInterrupt:
            print("\nstopped")
    return 0
