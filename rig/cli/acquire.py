"""Commands that record: `rig demo`, `rig run`, `rig simulate`, `rig import`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .options import QUIET, verbosity
from .usage import UsageError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the recording commands to the `rig` parser."""
    p = sub.add_parser("demo", help="simulated perpendicular experiments (projector on and off), fitted and plotted")
    p.add_argument("--out", default="rig-output", help="output folder (default rig-output/)")
    p.add_argument("--frames", type=int, default=300, help="frames per stop (default 300)")
    p.add_argument("--width", type=int, default=424, help="simulated image width in px (default 424, half of 848)")
    p.add_argument("--full-resolution", action="store_true", help="simulate the full 848x480 image (slower)")
    p.add_argument("--depth-unit-mm", type=float, default=0.1, help="depth unit of the simulated camera (default 0.1 mm)")
    p.add_argument("--seed", type=int, default=1)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("run", help="run an experiment (TOML file or options) and record it")
    p.add_argument("experiment", nargs="?", help="experiment file (TOML); or give --protocol and options")
    p.add_argument("--protocol", choices=["perpendicular", "tilted"], help="protocol when no file is given")
    p.add_argument("--camera", help="camera device string (default fake:)")
    p.add_argument("--stage", help="stage device string (default fake: for perpendicular, none: for tilted)")
    p.add_argument("-o", "--output", help="recording to write (.h5)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted recording")
    p.add_argument("--frames", type=int, help="frames per stop")
    p.add_argument("--projector", choices=["on", "off"], help="IR projector")
    p.add_argument("--exposure-us", type=float)
    p.add_argument("--gain", type=float)
    p.add_argument("--stops", help="comma-separated distances in m (perpendicular)")
    p.add_argument("--tilt-deg", type=float, help="wall tilt (tilted)")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("simulate", help="record a simulated experiment with a hidden effect (answer in OUT.answer.json)")
    p.add_argument("output")
    p.add_argument("--scenario", default="hidden")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--effect", help="hide this effect instead of the seed's choice (for validation)")
    p.add_argument("--width", type=int, default=106)
    p.add_argument("--frames", type=int, default=100)
    p.set_defaults(func=cmd_simulate)

    from drivers.folder.manifest import MANIFEST_NAME

    p = sub.add_parser("import", help="turn folders of depth frames (16-bit PNG or .npy) into a recording (docs/import.md)",
                       description="Turn folders of depth frames (16-bit PNG or .npy) into a recording; see docs/import.md.")
    p.add_argument("folder", metavar="DIR", help=f"folder with one sub-folder per stop and {MANIFEST_NAME}")
    p.add_argument("-o", "--output", required=True, metavar="OUT.h5", help="recording to write")
    p.add_argument("--fx", type=float, help="focal length, px (overrides the manifest)")
    p.add_argument("--fy", type=float, help="focal length, px")
    p.add_argument("--cx", type=float, help="principal point column, px")
    p.add_argument("--cy", type=float, help="principal point row, px")
    p.add_argument("--baseline-m", type=float, help="stereo baseline, m")
    p.add_argument("--depth-unit-m", type=float, help="metres per depth count (0.001 for 1 mm)")
    p.add_argument("--projector", choices=["on", "off"], help="was the IR projector on")
    p.add_argument("--exposure-us", type=float)
    p.add_argument("--gain", type=float)
    p.add_argument("--stop-distance-from-name", metavar="REGEX", help='read distances from folder names, e.g. "(?P<m>[0-9.]+)m"')
    p.set_defaults(func=cmd_import)


def cmd_demo(args: argparse.Namespace) -> int:
    from ..simulation.demo import run_demo

    return run_demo(out_dir=Path(args.out), frames=args.frames, width=848 if args.full_resolution else args.width,
                    seed=args.seed, depth_unit_mm=args.depth_unit_mm, verbosity=verbosity(args))


def cmd_run(args: argparse.Namespace) -> int:
    from protocols.experiment_file import Experiment, build_plan, load_experiment
    from protocols.runner import Runner

    from ..devices import open_devices
    from ..reports.progress import TerminalProgress

    overrides: dict[str, Any] = {}
    if args.frames is not None:
        overrides["frames_per_stop" if (args.protocol or "perpendicular") == "perpendicular" else "frames"] = args.frames
    if args.projector:
        overrides["projector_on"] = args.projector == "on"
    if args.exposure_us is not None:
        overrides["exposure_us"] = args.exposure_us
    if args.gain is not None:
        overrides["gain"] = args.gain
    if args.stops:
        try:
            overrides["stops_m"] = [float(x) for x in args.stops.split(",")]
        except ValueError:
            raise UsageError(f"--stops {args.stops!r}: write distances in m separated by commas, e.g. 0.5,1.0,1.5") from None
    if args.tilt_deg is not None:
        overrides["tilt_deg"] = args.tilt_deg
    if args.experiment:
        exp = load_experiment(args.experiment)
        if overrides:
            params = {**exp.plan.params, **overrides}
            if exp.plan.name == "tilted" and "frames_per_stop" in params:
                params["frames"] = params.pop("frames_per_stop")
            exp.plan = build_plan(exp.plan.name, params)
    else:
        if not args.protocol:
            raise UsageError("give an experiment file (rig run FILE.toml) or --protocol perpendicular|tilted")
        exp = Experiment(build_plan(args.protocol, overrides), "fake:", "fake:" if args.protocol == "perpendicular" else "none:", None)
    camera = args.camera or exp.camera
    stage = args.stage or exp.stage
    output = Path(args.output) if args.output else exp.output
    if output is None:
        raise UsageError("no output file; pass -o FILE.h5 (or set output in the experiment file)")
    p = exp.plan.params
    devices = open_devices(camera, stage, tilt_deg=p.get("tilt_deg", 0.0), distance_m=p.get("distance_m", 1.0))
    quiet = verbosity(args) == QUIET
    if not quiet:
        print(f"rig: {exp.plan.name} experiment, camera {camera}, stage {stage} -> {output}", file=sys.stderr)
    result = Runner(devices.camera, devices.stage, progress=None if quiet else TerminalProgress(), sleep=devices.sleep).run(
        exp.plan, output, resume=args.resume)
    print(f"recorded {len(result.recorded)} stops ({len(result.skipped)} already there) in {result.path}")
    return 0


def cmd_simulate(args: argparse.Namespace) -> int:
    from ..simulation.scenarios import answer_path, hidden_scenario, record_scenario

    if args.scenario != "hidden":
        raise UsageError(f"unknown scenario {args.scenario!r}; the one scenario is 'hidden'")
    try:
        sc = hidden_scenario(args.seed, args.effect, width=args.width, frames=args.frames)
    except ValueError as e:
        raise UsageError(str(e)) from None
    out = record_scenario(sc, args.output)
    print(f"recorded {out} (seed {args.seed}); the hidden effect is written only to {answer_path(out)}")
    return 0


def import_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """Manifest keys set on the command line (the flags that were given)."""
    o = {k: getattr(args, k) for k in ("fx", "fy", "cx", "cy", "baseline_m", "depth_unit_m", "exposure_us", "gain",
                                        "stop_distance_from_name")}
    o["projector_on"] = None if args.projector is None else args.projector == "on"
    return {k: v for k, v in o.items() if v is not None}


def cmd_import(args: argparse.Namespace) -> int:
    """`rig import` once its arguments are parsed; errors raise FolderImportError."""
    from protocols.folder_import import import_folder

    from ..reports.progress import TerminalProgress

    progress = None if verbosity(args) == QUIET else TerminalProgress()
    out = import_folder(args.folder, args.output, import_overrides(args), progress=progress)
    print(f"imported {args.folder} -> {out} (rig fit {out}; rig diagnose {out})")
    return 0

