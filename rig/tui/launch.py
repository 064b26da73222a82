"""Starting the terminal UI: its command-line arguments (`rig tui ...`) and how they become an app.

Importing this module does not import Textual; `run` does.
"""

from __future__ import annotations

import argparse
import sys

from .form import DEFAULT_CAMERA, DEFAULT_STAGE


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of `rig tui`."""
    p.add_argument("recording", nargs="?", help="a recording (.h5) to open on the Results screen")
    p.add_argument("--camera", help=f"camera device string (default {DEFAULT_CAMERA}, or the experiment file's)")
    p.add_argument("--stage", help=f"stage device string (default {DEFAULT_STAGE}, or the experiment file's)")
    p.add_argument("--experiment", help="experiment file (TOML, as rig run takes) to load into the Experiment screen")
    p.add_argument("--no-connect", action="store_true", help="do not connect the devices at start")


def run(args: argparse.Namespace) -> int:
    """Run the app until the operator quits; 2 for an experiment file that cannot be read."""
    if not (sys.stdin.isatty() and sys.stdout.isatty()):  # else it draws escape codes into a file until killed
        # said before the app is imported (Textual, scipy, matplotlib: 3.7 s of CPU)
        print("rig tui: error: the terminal UI needs a terminal, and standard input or output is a file or a pipe; "
              "run it in a terminal (rig run, rig fit and rig accuracy are the commands for scripts)", file=sys.stderr)
        return 2
    from protocols.experiment_file import ExperimentFileError

    from .app import RigApp
    from .form import ExperimentSettings
    camera, stage = args.camera or DEFAULT_CAMERA, args.stage or DEFAULT_STAGE
    settings = None
    if args.experiment:
        try:
            settings, file_camera, file_stage = ExperimentSettings.load(args.experiment)
        except ExperimentFileError as e:
            print(f"rig tui: error: {e}", file=sys.stderr)
            return 2
        camera, stage = args.camera or file_camera, args.stage or file_stage
    app = RigApp(camera, stage, recording=args.recording, experiment=settings,
                 experiment_file=args.experiment or "experiment.toml", connect=not args.no_connect)
    return run_app(app)


def run_app(app, **run_options) -> int:
    """Run the app until it ends: 0 when the operator quits; when something unexpected ended it, 1, and one
    line on stderr saying what (under the traceback Textual prints)."""
    app.run(**run_options)
    code = app.return_code or 0
    if code or app.crash is not None:
        e = app.crash
        what = f"{type(e).__name__}: {e}" if e is not None else f"exit status {code}"
        print(f"rig tui: error: the UI stopped on an unexpected error ({what}); the traceback above says where; "
              "completed stops of a run are kept (rig run ... --resume records the rest)", file=sys.stderr)
        return code or 1
    return 0
