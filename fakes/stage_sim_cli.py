"""`rig stage-sim grbl|zaber`: serve a simulated stage controller on a pseudo-terminal until Ctrl-C,
so the serial drivers (and a whole run) can be tried without hardware."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from .grbl_sim import GrblSim
from .pty_controller import PtyController
from .zaber_sim import ZaberSim


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="rig stage-sim",
        description="Run a simulated GRBL or Zaber stage controller on a pseudo-terminal until Ctrl-C.",
    )
    p.add_argument("kind", choices=("grbl", "zaber"), help="which controller to simulate")
    p.add_argument("--travel-mm", type=float, default=3000.0, help="rail length (default 3000)")
    p.add_argument("--speed-mm-s", type=float, default=250.0, help="carriage speed (default 250)")
    p.add_argument("--no-soft-limits", action="store_true", help="grbl: run into the end switches (ALARM:1) instead")
    p.add_argument("--no-homing", action="store_true", help="grbl: homing disabled ($22=0); start unlocked")
    p.add_argument("--microstep-um", type=float, default=0.1905, help="zaber: microstep size (default 0.1905)")
    p.add_argument("-v", "--verbose", action="store_true", help="print every command and reply")
    return p


def _build(args: argparse.Namespace) -> tuple[PtyController, str]:
    if args.kind == "grbl":
        sim: PtyController = GrblSim(
            travel_mm=args.travel_mm, speed_mm_s=args.speed_mm_s,
            soft_limits=not args.no_soft_limits, homing=not args.no_homing,
        )
        return sim, "offset_m=0.3&travel_mm={travel:g}" + ("&homing=0" if args.no_homing else "")
    sim = ZaberSim(travel_mm=args.travel_mm, speed_mm_s=args.speed_mm_s, microstep_um=args.microstep_um)
    return sim, "offset_m=0.3&microstep_um={microstep:g}"


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


def stage_sim_main(argv: list[str]) -> int:
    """Start the simulator, print its port and an example run line, serve until Ctrl-C.
    Typing a fault name (e.g. `noise`, `unplug`, `position_error mm=3`) injects it."""
    args = _parser().parse_args(argv)
    sim, options = _build(args)
    # stop cleanly on SIGTERM as on Ctrl-C (a process started in the background by a
    # non-interactive shell ignores SIGINT, so a supervisor stops it with SIGTERM)
    signal.signal(signal.SIGTERM, _raise_interrupt)
    with sim:
        device = f"{args.kind}://{sim.port}?" + options.format(travel=args.travel_mm, microstep=args.microstep_um)
        print(f"simulated {args.kind} controller on {sim.port}")
        print(f"try:  rig run --stage '{device}' ...")
        print("(quote the device string: it contains ? and &)  Ctrl-C to stop")
        print(f"type a fault and Enter to inject it: {', '.join(sim.faults)}", flush=True)
        threading.Thread(target=_read_faults, args=(sim,), daemon=True).start()
        shown_commands = shown_replies = 0
        try:
            while sim.running:
                time.sleep(0.1)
                if args.verbose:
                    for text in sim.commands[shown_commands:]:
                        print(f"-> {text}")
                    for text in sim.replies[shown_replies:]:
                        print(f"<- {text}")
                    shown_commands, shown_replies = len(sim.commands), len(sim.replies)
                    sys.stdout.flush()
        except KeyboardInterrupt:
            print("\nstopped")
    return 0


if __name__ == "__main__":
    raise SystemExit(stage_sim_main(sys.argv[1:]))
