"""The `rig` command line: one parser builds every command.

The commands live by what they do: `acquire` (demo, run, simulate, import), `analyse` (fit,
compare, diagnose) and `tools` (devices, tui, paper-windows, validate-diagnosis, stage-sim).
Each module's `register` adds its sub-commands; a new command goes into one of them (or a new
module registered here) with its arguments and a `cmd_*` function.
"""

from __future__ import annotations

import argparse
import sys

from drivers.errors import DeviceError, FolderImportError

from . import acquire, analyse, tools
from .usage import UsageError

__all__ = ["main", "build_parser", "run_command", "UsageError"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rig", description="Depth-camera range-error rig: acquire, fit, diagnose.")
    sub = parser.add_subparsers(dest="command", required=True)
    acquire.register(sub)
    analyse.register(sub)
    tools.register(sub)
    return parser


def run_command(argv: list[str]) -> int:
    """Parse `argv` with the `rig` parser and run the command; errors propagate (for callers in Python)."""
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


def main(argv: list[str] | None = None) -> int:
    from protocols.experiment_file import ExperimentFileError
    from protocols.recording import RecordingError
    from protocols.runner import RunError

    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        return run_command(argv)
    except (UsageError, RunError, RecordingError, DeviceError, ExperimentFileError, FolderImportError) as e:
        print(f"rig: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rig: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
