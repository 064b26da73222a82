"""Commands that record: `rig demo`, `rig run`, `rig simulate`, `rig import`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .options import QUIET, at_least, refuse_suffix, refuse_unwritable, verbosity
from .usage import UsageError, say_done


def register(sub: argparse._SubParsersAction) -> None:
    """Add the recording commands to the `rig` parser."""
    p = sub.add_parser("demo", help="simulated perpendicular experiments (projector on and off), fitted and plotted")
    p.add_argument("--out", default="rig-output", help="output folder (default rig-output/)")
    p.add_argument("--frames", type=at_least(2, "frames a stop"), default=300, help="frames per stop (default 300)")
    p.add_argument("--width", type=int, default=424, help="simulated image width in px (default 424, half of 848)")
    p.add_argument("--full-resolution", action="store_true", help="simulate the full 848x480 image (slower)")
    p.add_argument("--depth-unit-mm", type=float, default=0.1, help="depth unit of the simulated camera (default 0.1 mm)")
    p.add_argument("--seed", type=int, default=1)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("run", help="run an experiment (TOML file or options) and record it",
                       description="Run an experiment and record it: an experiment file (TOML), or --protocol and "
                                   "its parameters as options (every protocol of the catalogue, protocols/catalogue.py).")
    p.add_argument("experiment", nargs="?", help="experiment file (TOML); or give --protocol and options")
    p.add_argument("--protocol", choices=protocol_names(), help="protocol when no file is given")
    p.add_argument("--camera", help="camera device string (default fake:)")
    p.add_argument("--stage", help="stage device string (default: the protocol's, fake: for a moving stage)")
    p.add_argument("-o", "--output", help="recording to write (.h5)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted recording")
    add_protocol_options(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("simulate", help="record a simulated experiment with a hidden effect (answer in OUT.answer.json)")
    p.add_argument("output")
    p.add_argument("--scenario", default="hidden")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--effect", help="hide this effect instead of the seed's choice (for validation)")
    p.add_argument("--width", type=int, default=106)
    p.add_argument("--frames", type=at_least(2, "frames a stop"), default=100)
    p.set_defaults(func=cmd_simulate)

    from drivers.folder.manifest import MANIFEST_NAME

    p = sub.add_parser("import", help="turn bags or folders of depth frames into a recording (docs/import.md)",
                       description="Turn a RealSense or ROS 1/ROS 2 bag (.bag, .db3, .mcap), a folder of bags (one per "
                                   "stop), or folders of depth frames (16-bit PNG or .npy) into a recording; see docs/import.md.")
    p.add_argument("folder", metavar="SOURCE", help=f"a bag, a folder of bags, or a folder with one sub-folder per stop and {MANIFEST_NAME}")
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
    p.add_argument("--stop-distance-from-name", metavar="REGEX", help='read distances from folder (or bag) names, e.g. "(?P<m>[0-9.]+)m"')
    p.add_argument("--distance-m", type=float, metavar="Z", help="a single bag's camera-to-wall distance, m")
    p.add_argument("--topic", help="a bag's depth image topic, when it has several (e.g. /camera/depth/image_rect_raw)")
    p.add_argument("--stops-in-time", metavar="Z@T0-T1,...", help="one bag holding several stops: each stop's distance "
                   "(m) and its span in s from the bag's first frame, e.g. 0.5@0-12,1.0@20-32")
    p.add_argument("--stops-at-gaps", metavar="Z1,Z2,...", help="one bag holding several stops, the recorder paused "
                   "between them: the distances (m) of the runs of frames between pauses, in order")
    p.set_defaults(func=cmd_import)


def cmd_demo(args: argparse.Namespace) -> int:
    from ..simulation.demo import run_demo

    return run_demo(out_dir=Path(args.out), frames=args.frames, width=848 if args.full_resolution else args.width,
                    seed=args.seed, depth_unit_mm=args.depth_unit_mm, verbosity=verbosity(args))


#: where rig run keeps a protocol parameter's option (its value as typed) in the parsed arguments
OPTION_DEST = "protocol parameter "


def add_protocol_options(p: argparse.ArgumentParser) -> None:
    """One option for each parameter name of the catalogue, saying which protocols take it and their defaults."""
    from protocols.catalogue import catalogue_params

    group = p.add_argument_group("protocol parameters", "override the experiment file's or the protocol's defaults; "
                                 "lists are 0.5,1.0,1.5 or a range START:STOP:STEP, e.g. 0.5:3.0:0.25")
    for name, uses in catalogue_params().items():
        param = uses[0][1]
        defaults = {spec.name: q.text(q.default) for spec, q in uses}
        default = next(iter(defaults.values())) if len(set(defaults.values())) == 1 else \
            ", ".join(f"{v} ({k})" for k, v in defaults.items())
        takers = "every protocol" if len(uses) == len(protocol_names()) else ", ".join(defaults)
        unit = f", {param.unit}" if param.unit and param.type is not bool else ""
        kw: dict[str, Any] = {"choices": ["on", "off"]} if param.type is bool else \
            {"metavar": {list: "LIST", int: "N"}.get(param.type, "X")}
        try:
            group.add_argument(param.cli_option, dest=OPTION_DEST + name,
                               help=f"{param.help}{unit} [{name}; {takers}; default {default or 'none'}]", **kw)
        except argparse.ArgumentError:
            raise UsageError(f"the protocol parameter {name} ({', '.join(s.name for s, _ in uses)}) has the option "
                             f"{param.cli_option}, which is rig run's own; give the parameter another option") from None


def protocol_names() -> list[str]:
    from protocols.catalogue import protocol_names as names

    return names()


def protocol_options(args: argparse.Namespace, spec: Any) -> dict[str, Any]:
    """The protocol parameters given as options, read by `spec`'s types; UsageError for an option the protocol
    does not take or a value that is not what its parameter takes."""
    given = {k[len(OPTION_DEST):]: v for k, v in vars(args).items() if k.startswith(OPTION_DEST) and v is not None}
    values = {}
    for name, text in given.items():
        param = spec.param(name)
        if param is None:
            from protocols.catalogue import catalogue_params

            option = catalogue_params()[name][0][1].cli_option
            takes = ", ".join(q.cli_option for q in spec.all_params())
            raise UsageError(f"{option} is not a parameter of {spec.name}; {spec.name} takes {takes}")
        try:
            values[name] = param.parse(text)
        except ValueError as e:
            raise UsageError(f"{param.cli_option} {e}") from None
    return values


def cmd_run(args: argparse.Namespace) -> int:
    from protocols.catalogue import protocol_spec
    from protocols.experiment_file import Experiment, ExperimentFileError, build_plan, load_experiment
    from protocols.runner import Runner

    from ..devices import open_devices
    from ..reports.progress import TerminalProgress

    if args.experiment:
        exp = load_experiment(args.experiment)
        if args.protocol and args.protocol != exp.plan.name:
            raise UsageError(f"--protocol {args.protocol}, but {args.experiment} is a {exp.plan.name} experiment; "
                             "leave out --protocol, or give no file")
        spec = protocol_spec(exp.plan.name)
        overrides = protocol_options(args, spec)
        if overrides:
            exp.plan = build_plan(spec.name, {**exp.plan.params, **overrides})
    else:
        if not args.protocol:
            raise UsageError(f"give an experiment file (rig run FILE.toml) or --protocol {'|'.join(protocol_names())}")
        spec = protocol_spec(args.protocol)
        exp = Experiment(build_plan(spec.name, protocol_options(args, spec)), "fake:", spec.default_stage, None)
    camera = args.camera or exp.camera
    stage = args.stage or exp.stage
    output = Path(args.output) if args.output else exp.output
    if output is None:
        raise UsageError("no output file; pass -o FILE.h5 (or set output in the experiment file)")
    refuse_suffix(output, "-o", (".h5", ".hdf5"), "a recording (HDF5)")
    devices = open_devices(camera, stage, **spec.wall_of(exp.plan.params))
    if devices.camera.true_distance_m() is None:  # a simulated camera's wall follows the plan: nobody moves it
        _ask_to_move(getattr(devices.stage, "inner", devices.stage), exp.plan, stage)
    quiet = verbosity(args) == QUIET
    if not quiet:
        print(f"rig: {exp.plan.name} experiment, camera {camera}, stage {stage} -> {output}", file=sys.stderr)
    result = Runner(devices.camera, devices.stage, progress=None if quiet else TerminalProgress(), sleep=devices.sleep).run(
        exp.plan, output, resume=args.resume)
    say_done(f"recorded {len(result.recorded)} stops ({len(result.skipped)} already there) in {result.path}",
             f"{result.path} is")
    return 0


def _ask_to_move(stage, plan, spec: str) -> None:
    """Without a stage (`none:`) someone moves the camera: at a terminal rig asks before each stop of a plan of
    several; elsewhere such a plan is refused, since nobody would be asked."""
    from drivers.stage import NoStage
    from protocols.plan import Move

    moves = sum(isinstance(s, Move) for s in plan.steps())
    if not isinstance(stage, NoStage) or moves <= 1:
        return
    if not sys.stdin.isatty():
        raise UsageError(f"--stage {spec} with {moves} stops needs someone to move the camera between them, and "
                         "rig is not at a terminal to ask; run it at a terminal, give a stage (e.g. --stage fake: or "
                         "grbl:///dev/ttyUSB0), or record one stop a run (--stops D)")

    def ask(text: str) -> None:
        print(f"rig: {text}, then press Enter (Ctrl-C stops; completed stops are kept)", file=sys.stderr)
        try:
            input()
        except EOFError:
            raise KeyboardInterrupt from None

    stage.ask = ask


def cmd_simulate(args: argparse.Namespace) -> int:
    from ..simulation.scenarios import answer_path, hidden_scenario, record_scenario

    if args.scenario != "hidden":
        raise UsageError(f"unknown scenario {args.scenario!r}; the one scenario is 'hidden'")
    out = Path(args.output)
    if out.is_dir():
        raise UsageError(f"{out} is a folder; give the recording's file name, e.g. {out / 'hidden.h5'}")
    if out.exists():  # as rig run: a recording is never overwritten
        raise UsageError(f"{out} exists; remove it or give another file name (rig simulate does not overwrite)")
    refuse_unwritable(out, "OUTPUT")
    refuse_suffix(out, "OUTPUT", (".h5", ".hdf5"), "a recording (HDF5)")
    try:
        sc = hidden_scenario(args.seed, args.effect, width=args.width, frames=args.frames)
    except ValueError as e:
        raise UsageError(str(e)) from None
    out = record_scenario(sc, args.output)
    say_done(f"recorded {out} (seed {args.seed}); the hidden effect is written only to {answer_path(out)}",
             f"{out} and {answer_path(out)} are")
    return 0


def import_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """Manifest keys set on the command line (the flags that were given)."""
    o = {k: getattr(args, k) for k in ("fx", "fy", "cx", "cy", "baseline_m", "depth_unit_m", "exposure_us", "gain",
                                        "stop_distance_from_name")}
    o["projector_on"] = None if args.projector is None else args.projector == "on"
    return {k: v for k, v in o.items() if v is not None}


def bag_source(path: Path) -> bool:
    """A bag, or a folder of bags without sub-folders of frames, is imported as bags (protocols.bag_import)."""
    from drivers.bag import is_bag

    if is_bag(path):
        return True
    if not path.is_dir():
        return path.suffix.lower() in (".bag", ".db3", ".mcap")
    entries = [p for p in path.iterdir() if not p.name.startswith(".")]
    return any(is_bag(p) for p in entries) and not any(p.is_dir() and not is_bag(p) for p in entries)


def cmd_import(args: argparse.Namespace) -> int:
    """`rig import` once its arguments are parsed; errors raise FolderImportError."""
    from protocols.folder_import import import_folder

    from ..reports.progress import TerminalProgress

    refuse_suffix(args.output, "-o", (".h5", ".hdf5"), "a recording (HDF5)")
    refuse_unwritable(args.output, "-o")
    source = Path(args.folder)
    if source.is_dir() and not any(p for p in source.iterdir() if not p.name.startswith(".") and p.is_dir()
                                   or p.suffix.lower() in (".bag", ".db3", ".mcap")):
        # before the manifest's questions: without frames its intrinsics are of nothing
        raise UsageError(f"{source} holds no stop folders of depth frames and no bags; put one folder of frames per "
                         "stop in it (0.500m/, 1.000m/, ...) or give a bag (docs/import.md)")
    progress = None if verbosity(args) == QUIET else TerminalProgress()
    notes: list[str] = []
    if bag_source(Path(args.folder)):
        from protocols.bag_import import import_bags, recorded_notes

        out = import_bags(args.folder, args.output, import_overrides(args), progress=progress, topic=args.topic,
                          distance_m=args.distance_m, stops_in_time=args.stops_in_time, stops_at_gaps=args.stops_at_gaps)
        notes = recorded_notes(out)
    elif any(v is not None for v in (args.distance_m, args.topic, args.stops_in_time, args.stops_at_gaps)):
        from drivers.errors import FolderImportError
        from drivers.folder.manifest import MANIFEST_NAME

        raise FolderImportError(f"{args.folder}: --distance-m, --topic and --stops-* are for bags; a folder of frames names its "
                                f"stops' distances in {MANIFEST_NAME} (see docs/import.md)")
    else:
        out = import_folder(args.folder, args.output, import_overrides(args), progress=progress)
    say_done(f"imported {args.folder} -> {out} (rig fit {out}; rig diagnose {out})" + "".join(f"; note: {n}" for n in notes),
             f"{out} is")
    return 0

