"""`rig ...` in the test's own process: `rig.cli.main` with stdout and stderr captured, returned as a
`subprocess.CompletedProcess` (args, returncode, stdout, stderr), as a test of a new process would get it.

For tests of what a command prints, writes and returns: a new interpreter costs ~1.5 s of CPU before the command
starts (imports, numba's start-up), which this process has paid already. Tests of the process itself (its
stderr on a terminal or a pipe, signals, the installed console script, a full disk injected by strace) start one.

stdout and stderr are text streams over bytes, encoded as a process's are in a UTF-8 locale (stdout strict, stderr
backslashreplace): a file name's undecodable byte (a lone surrogate in Python) goes through rig's own handling of
it, as it would to a terminal, where a StringIO would take it as it is.
"""

from __future__ import annotations

import io
import subprocess
from contextlib import redirect_stderr, redirect_stdout

from rig.cli import main


def rig_in_process(*args: object) -> subprocess.CompletedProcess:
    """Run `rig *args` through rig.cli.main; argparse's own exit (a usage error, --help) gives its status."""
    argv = [str(a) for a in args]
    out, err = _process_stream("strict"), _process_stream("backslashreplace")
    with redirect_stdout(out), redirect_stderr(err):
        try:
            status = main(argv)
        except SystemExit as e:
            status = e.code if isinstance(e.code, int) else 0 if e.code is None else 1
    return subprocess.CompletedProcess(["rig", *argv], status, _text(out), _text(err))


def _process_stream(errors: str) -> io.TextIOWrapper:
    return io.TextIOWrapper(io.BytesIO(), encoding="utf-8", errors=errors)


def _text(stream: io.TextIOWrapper) -> str:
    stream.flush()
    return stream.buffer.getvalue().decode("utf-8")
