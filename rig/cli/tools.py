"""Commands around the measurement: `rig devices`, `rig tui`, `rig paper-windows`,
`rig validate-diagnosis`, `rig stage-sim`."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path
from typing import TextIO

from drivers.camera import CameraSettings

from .options import at_least, refuse_unwritable, verbosity
from .usage import UsageError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the tool commands to the `rig` parser."""
    p = sub.add_parser("devices", help="list attached cameras and serial ports; --check CAMERA checks one",
                       description="List attached cameras and serial ports, check a camera, or list a kind's "
                                   "device-string options.")
    p.add_argument("--options", metavar="KIND", nargs="?", const="",
                   help="print the device-string options of a kind (of every installed kind without KIND): defaults, "
                        "units, accepted values, and for a camera the settings it takes")
    p.add_argument("--check", metavar="CAMERA", help="capture with the projector on and off, e.g. realsense: or fake:")
    p.add_argument("--seconds", type=float, default=4.0, help="capture time for --check, split between on and off (default 4)")
    p.add_argument("--exposure-us", type=float, default=CameraSettings().exposure_us,
                   help="exposure for --check (default 8500 us)")
    p.add_argument("--gain", type=float, default=CameraSettings().gain,
                   help="gain for --check, in rig's unit: 16 = x1 on every camera, converted to the camera's own "
                        "scale (rig devices --options KIND shows it); default 16")
    p.add_argument("--distance", type=float, help="true camera-to-wall distance in m, for the range error")
    p.set_defaults(func=cmd_devices)

    from ..tui.launch import add_arguments as add_tui_arguments

    p = sub.add_parser("tui", help="the operator's terminal UI (docs/tui.md)",
                       description="The lab operator's terminal UI: devices, experiment, run, results.")
    add_tui_arguments(p)
    p.set_defaults(func=cmd_tui)

    p = sub.add_parser("paper-windows", help="the paper's k/lambda-per-window table on simulated data",
                       description="Simulate the paper's window-by-window fits: does a noise floor or censoring "
                                   "explain the fall of the active lambda towards 3 m?")
    p.add_argument("--out", default="rig-output", help="folder for the recordings (default rig-output/)")
    p.add_argument("--frames", type=at_least(2, "frames a stop"), default=100, help="frames per stop (default 100)")
    p.add_argument("--width", type=int, default=106, help="simulated image width in px (default 106, 848/8)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the first scenario (default 0)")
    p.set_defaults(func=cmd_paper_windows)

    p = sub.add_parser("validate-diagnosis", help="blind test of rig diagnose on hidden-effect simulations",
                       description="Does `rig diagnose` find effects nobody told it about? Records hidden-effect "
                                   "scenarios, diagnoses each blind and tabulates the results.")
    p.add_argument("--seeds", type=at_least(1, "seeds"), default=10, help="seeds per effect (default 10)")
    p.add_argument("--first-seed", type=int, default=1000)
    # the default is filled in by cmd_validate: the scenarios' module loads the fake camera and numba (0.4 s), which
    # building the parser for every command must not
    p.add_argument("--effects", default=None,
                   help="comma-separated scenarios (default: all: none, each catalogue effect, a coarse depth unit, "
                        "pairs, effects the catalogue lacks, frames not independent, IR saturated near the wall)")
    p.add_argument("--jobs", type=at_least(1, "processes"),
                   help="trials at a time, in parallel processes (default: one per core)")
    p.add_argument("--json", help="also write the trials here")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("stage-sim", help="run a simulated stage controller on a pseudo-terminal (grbl or zaber)",
                       description="Run a simulated GRBL or Zaber stage controller on a pseudo-terminal until Ctrl-C.")
    p.add_argument("kind", choices=("grbl", "zaber"), help="which controller to simulate")
    p.add_argument("--travel-mm", type=float, default=3000.0, help="rail length (default 3000)")
    p.add_argument("--speed-mm-s", type=float, default=250.0, help="carriage speed (default 250)")
    p.add_argument("--no-soft-limits", action="store_true", help="grbl: run into the end switches (ALARM:1) instead")
    p.add_argument("--no-homing", action="store_true", help="grbl: homing disabled ($22=0); start unlocked")
    p.add_argument("--microstep-um", type=float, default=0.1905, help="zaber: microstep size (default 0.1905)")
    # -v (every command's -v, rig.cli.options) prints every command and reply
    p.set_defaults(func=cmd_stage_sim)


# -- rig devices ---------------------------------------------------------------------------------

def print_listing(out: TextIO) -> int:
    """What every installed kind's probe finds: cameras, then the connections stages use (serial ports)."""
    from drivers.listing import probe_all, probes

    which = probes()
    results, notes = probe_all(which=which)
    cameras = [c for name in which.probes if name in which.cameras for c in results.get(name, [])]
    ports = [p for name in which.probes if name not in which.cameras for p in results.get(name, [])]
    print("cameras:", file=out)
    for c in cameras:
        kind, model, serial, firmware, usb, string = (c.get(k) or "-" for k in (  # a plugin's probe may leave some out
            "kind", "model", "serial", "firmware", "usb", "string"))
        print(f"  {kind:<9} {model:<32} id {serial:<20} firmware {firmware:<16} USB {usb:<10} -> --camera {string}",
              file=out)
    if not cameras:
        print("  none found", file=out)
    print("serial ports:", file=out)
    for p in ports:
        adapter = f", {p['adapter']}" if p.get("adapter") else ""
        print(f"  {p.get('port', '-'):<14} {p.get('description', ''):<30} USB {p.get('usb', '-')} serial "
              f"{p.get('serial') or '-'}: likely {p.get('protocol', 'unknown')}{adapter} -> --stage {p.get('string', '-')}",
              file=out)
    if not ports:
        print("  none found", file=out)
    for n in notes:
        print(f"note: {n}", file=out)
    if not cameras and not ports:
        camera_kinds, stage_kinds = _loadable("camera"), _loadable("stage")
        looked = ", ".join(k.summary or k.name for k in camera_kinds if k.probe is not None) or "none installed"
        fake = " ".join(f"--{k.what} {k.name}:" for k in camera_kinds + stage_kinds if k.simulated)
        print(f"nothing is attached: no camera ({looked}) and no USB serial port found"
              + (f"; simulate a rig with {fake}" if fake else ""), file=out)
    return 0


def _loadable(what: str) -> list:
    """The kinds of `what` that load (a broken plugin's is named in the listing's notes instead)."""
    from drivers.errors import DeviceError
    from drivers.registry import kind, kind_names

    out = []
    for name in kind_names(what):
        try:
            out.append(kind(what, name))
        except DeviceError:
            continue
    return out


def print_options(kind: str, out: TextIO) -> int:
    """The option tables of `kind` (a camera kind, a stage kind, or both, as `fake`); of every kind if it is ''.
    A camera's table is followed by the settings it takes, in rig's units."""
    from drivers.registry import kind_names
    from drivers.registry import kind as kind_entry

    kind = kind.strip().rstrip(":").lower()
    wanted = [(what, k) for what in ("camera", "stage") for k in kind_names(what) if k == kind or not kind]
    if not wanted:
        known = ", ".join(sorted(set(kind_names("camera")) | set(kind_names("stage"))))
        raise UsageError(f"--options {kind!r}: no such device kind; known kinds: {known}")
    for i, (what, k) in enumerate(wanted):
        entry = kind_entry(what, k)
        table = entry.option_table()
        if i:
            print(file=out)
        for line in table.lines() if table is not None else [f"{k} {what}: (its plugin declares no option table)"]:
            print(line, file=out)
        if entry.settings_text():
            print(f"  {entry.settings_text()}", file=out)
    return 0


def cmd_devices(args: argparse.Namespace, out: TextIO | None = None) -> int:
    out = out or sys.stdout
    if args.options is not None:
        return print_options(args.options, out)
    if args.check is None:
        return print_listing(out)
    from ..camera_check.projector_check import run_check

    return run_check(args.check, seconds=args.seconds, exposure_us=args.exposure_us, gain=args.gain,
                     truth_m=args.distance, out=out)


# -- rig tui -------------------------------------------------------------------------------------

def cmd_tui(args: argparse.Namespace) -> int:
    from ..tui.launch import run

    return run(args)


# -- rig paper-windows -----------------------------------------------------------------------------

def cmd_paper_windows(args: argparse.Namespace) -> int:
    from ..simulation.paper_windows import run_paper_windows

    if args.frames < 2:
        raise UsageError("--frames must be at least 2 (a variance needs two samples)")
    if args.width < 8:
        raise UsageError("--width must be at least 8 px")
    if Path(args.out).exists() and not Path(args.out).is_dir():  # it was a FileExistsError traceback
        raise UsageError(f"--out {args.out} is a file; --out is the folder the recordings go to: give a folder")
    refuse_unwritable(args.out, "--out", folder=True)
    t0 = time.monotonic()
    print(run_paper_windows(args.out, frames=args.frames, width=args.width, seed=args.seed))
    print(f"Done in {time.monotonic() - t0:.0f} s.", file=sys.stderr)
    return 0


# -- rig validate-diagnosis --------------------------------------------------------------------------

def cmd_validate(args: argparse.Namespace) -> int:
    from ..simulation.validation import summary, validate

    refuse_unwritable(args.json, "--json")
    from ..simulation.scenarios import ALL_SCENARIOS

    effects = [e.strip() for e in (args.effects or ",".join(ALL_SCENARIOS)).split(",") if e.strip()]
    unknown = [e for e in effects if e not in ALL_SCENARIOS]
    if unknown:  # before any trial: a worker's error would come back as a traceback from the pool
        raise UsageError(f"--effects: no scenario named {', '.join(unknown)}; the scenarios are {', '.join(ALL_SCENARIOS)}")
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    from ..reports.work_progress import WorkProgressLine

    with tempfile.TemporaryDirectory() as tmp, WorkProgressLine("rig validate-diagnosis", verbosity(args)) as progress:
        trials = validate(effects, seeds, Path(tmp), out=progress.above(sys.stdout), jobs=args.jobs, progress=progress)
    print()
    print(summary(trials))
    if args.json:
        Path(args.json).write_text(json.dumps([asdict(t) for t in trials], indent=1))
    return 0


# -- rig stage-sim ---------------------------------------------------------------------------------

def cmd_stage_sim(args: argparse.Namespace) -> int:
    from fakes.stage_sim import serve

    return serve(args.kind, verbose=bool(args.verbose), travel_mm=args.travel_mm, speed_mm_s=args.speed_mm_s,
                 soft_limits=not args.no_soft_limits, homing=not args.no_homing, microstep_um=args.microstep_um)
