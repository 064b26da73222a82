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
    app.run()
    return 0
