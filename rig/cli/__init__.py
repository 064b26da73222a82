"""The `rig` command line: one parser builds every command.

The commands live by what they do: `acquire` (demo, run, simulate, import), `analyse` (fit,
compare, diagnose), `export` (export, sigma-bag), `recordings` (repeatability; compare of several recordings), `check` (a spec's pass or fail) and `tools` (devices, tui, paper-windows, validate-diagnosis, stage-sim).
Each module's `register` adds its sub-commands; a new command goes into one of them (or a new
module registered here) with its arguments and a `cmd_*` function.
"""

from __future__ import annotations

import argparse
import codecs
import errno
import os
import signal
import sys
import threading
from typing import TextIO

from ..runtime.blas_threads import one_blas_thread
from ..runtime.process_gc import collect_less_often, freeze_before_exit

one_blas_thread()  # before anything imports numpy (rig/runtime/blas_threads.py says why)

from drivers.errors import DeviceError, FolderImportError
from protocols import interruption

from . import acquire, analyse, check, export, recordings, tools
from .options import add_verbosity
from .usage import UsageError

__all__ = ["main", "entry", "build_parser", "run_command", "UsageError", "import_main", "devices_main", "paper_windows_main"]


def build_parser() -> argparse.ArgumentParser:
    from .. import package_version

    parser = argparse.ArgumentParser(prog="rig", description="Depth-camera range-error rig: acquire, fit, diagnose.",
                                     epilog="Exit status: 0 done; 2 bad input or a device error (one line on stderr); "
                                            "3 done, but lambda is not determined by the data (the output says why); "
                                            "130 interrupted.")
    parser.add_argument("--version", action="version", version=f"rig {package_version()}")
    add_verbosity(parser, top=True)
    sub = parser.add_subparsers(dest="command", required=True)
    acquire.register(sub)
    analyse.register(sub)
    export.register(sub)
    recordings.register(sub)
    check.register(sub)
    tools.register(sub)
    for command in sub.choices.values():
        add_verbosity(command, top=False)
    return parser


def run_command(argv: list[str]) -> int:
    """Parse `argv` with the `rig` parser and run the command; errors propagate (for callers in Python)."""
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


def import_main(argv: list[str]) -> int:
    """`rig import DIR -o OUT.h5 [--fx ...]` from Python; raises FolderImportError on bad input."""
    return run_command(["import", *argv])


def devices_main(argv: list[str] | None = None, out: TextIO | None = None) -> int:
    """`rig devices ...` from Python, printing to `out`."""
    return tools.cmd_devices(build_parser().parse_args(["devices", *(argv or [])]), out)


def paper_windows_main(argv: list[str]) -> int:
    """`rig paper-windows ...` from Python."""
    return run_command(["paper-windows", *argv])


def entry() -> int:
    """The `rig` program (pyproject.toml's [project.scripts]): `main` on the process's own arguments, with Python's
    collector set for a process that ends when the command does (`rig.runtime.process_gc`: collected less often, and
    frozen before the interpreter's shutdown, whose collections over numba's objects cost 0.4-0.6 s of CPU)."""
    collect_less_often()
    try:
        return main()
    finally:
        freeze_before_exit()


def main(argv: list[str] | None = None) -> int:
    from protocols.experiment_file import ExperimentFileError
    from protocols.recording_errors import RecordingError
    from protocols.run_errors import RunError

    from ..runtime.effect_errors import EffectFileError

    from protocols.disk_space import is_disk_full, is_storage_failure

    argv = sys.argv[1:] if argv is None else list(argv)
    codecs.register_error("rig-shown", _shown_bytes)
    for stream in (sys.stdout, sys.stderr):  # a file name's undecodable byte printed as \xNN, not a traceback
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="rig-shown")
    previous = _terminate_like_interrupt()
    unraisable_hook, sys.unraisablehook = sys.unraisablehook, _quiet_swallowed_interrupt
    try:
        return run_command(argv)
    except (UsageError, RunError, RecordingError, DeviceError, ExperimentFileError, FolderImportError, EffectFileError) as e:
        print(f"rig: error: {e}", file=sys.stderr)
        # the runner turns Ctrl-C into a RunError saying what was saved: still an interruption (130)
        return 130 if isinstance(e.__context__, KeyboardInterrupt) else 2
    except KeyboardInterrupt:
        print("rig: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader went away (`rig fit --many --json | head`): stop quietly, as cat does; point stdout at
        # /dev/null so that the interpreter's own flush at exit does not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as e:
        where = f" writing {e.filename}" if getattr(e, "filename", None) else ""
        if is_disk_full(e):
            print(f"rig: error: disk full{where}; free some space and run the command again", file=sys.stderr)
            return 2
        if e.errno == errno.EROFS:
            print(f"rig: error: the file system is read-only{where}; write to a folder on another disk (if it went "
                  "read-only by itself, check the disk: dmesg)", file=sys.stderr)
            return 2
        if isinstance(e, PermissionError):
            print(f"rig: error: permission denied{where}; write to a folder you may write to, or change its "
                  "permissions", file=sys.stderr)
            return 2
        if is_storage_failure(e):
            print(f"rig: error: the disk failed{where} ({e.strerror}); check the disk (dmesg) and run the command "
                  "again", file=sys.stderr)
            return 2
        raise
    finally:
        sys.unraisablehook = unraisable_hook
        for signum, handler in (previous or {}).items():
            signal.signal(signum, handler)


def _shown_bytes(e: UnicodeError) -> tuple[str, int]:
    """The `rig-shown` codec error handler: a file name's undecodable byte (a lone surrogate, PEP 383) as \\xNN, as
    rig.reports.output_file.shown writes it; any other character the stream cannot take as \\uNNNN."""
    if not isinstance(e, UnicodeEncodeError):
        raise e
    bad = e.object[e.start:e.end]
    return "".join(f"\\x{ord(c) - 0xDC00:02x}" if 0xDC80 <= ord(c) <= 0xDCFF else f"\\u{ord(c):04x}" for c in bad), e.end


def _raise_interrupt(signum: int, frame: object) -> None:
    interruption.request()  # kept if Python swallows the exception (raised inside a weakref callback or __del__)
    raise KeyboardInterrupt


def _quiet_swallowed_interrupt(unraisable: object) -> None:
    """sys.unraisablehook: an interrupt raised where Python cannot raise it (a weakref callback or __del__ that ran
    when the signal came) is printed by Python as "Exception ignored ... Traceback" on stderr; it is not lost
    (`_raise_interrupt` requested the stop first), so it is not shown. Anything else goes to Python's own hook."""
    if isinstance(getattr(unraisable, "exc_value", None), KeyboardInterrupt) and interruption.REQUESTED.is_set():
        return
    sys.__unraisablehook__(unraisable)


def _terminate_like_interrupt():
    """SIGTERM (a service manager, `kill`) ends a command as Ctrl-C does: completed stops saved, a resume hint;
    Ctrl-C's own handler, if it is Python's, is replaced by the same one, so neither is lost
    (`protocols.interruption`). Returns the handlers to put back."""
    interruption.forget()
    if threading.current_thread() is not threading.main_thread():
        return None
    previous = {signal.SIGTERM: signal.signal(signal.SIGTERM, _raise_interrupt)}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, _raise_interrupt)
    return previous


if __name__ == "__main__":
    sys.exit(main())
