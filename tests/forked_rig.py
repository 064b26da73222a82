"""`rig` commands in forked children of one process that has imported rig, each under `strace -p` if asked: the
fault-injection tests' trials without an interpreter's start-up (~1.5 s of CPU) each.

Two ways to use it:

- In a process of its own (tests/output_fault_matrix.py): `run(args, cwd, strace_args)` forks the command.
- From a test (`ForkServer`): `python -m tests.forked_rig` is started once, single-threaded, and serves requests
  on its stdin (JSON lines): `warm` runs a command in the server itself (its first-time work: imports, numba's kernels
  from their cache, done once, before any fork), `run` forks it and answers its exit status and output. A forked
  command must start from one thread (fork copies only the calling one): pytest's workers have more, the server
  has one (OpenBLAS is held to one thread before numpy is imported).

A child waits until strace is attached (its TracerPid in /proc), runs `rig.cli.main` with its output block-buffered
(the same write calls whether or not a terminal is there), and leaves with os._exit whatever happens in it.
"""

from __future__ import annotations

import gc
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path



def for_forking() -> None:
    """Settings of a process that forks commands, made before numpy is imported: OpenBLAS with one thread (a fork
    copies only the calling one), and no .pyc written (a module a command imports late must not add writes to the
    ones counted). Only in such a process of its own: a test's process keeps its own."""
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    sys.dont_write_bytecode = True


def allow_tracing_by_any() -> None:
    """Let strace, this child's sibling, attach: with Yama's ptrace_scope 1 (Ubuntu's default) only an ancestor may
    trace a process that has not said otherwise, and root's CAP_SYS_PTRACE is what lets CI attach without this.
    prctl(PR_SET_PTRACER, PR_SET_PTRACER_ANY); a kernel without Yama ignores it."""
    import ctypes

    pr_set_ptracer, any_tracer = 0x59616D61, ctypes.c_ulong(-1)
    try:
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_ptracer, any_tracer, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def run(args: list[str], cwd: Path, strace_args: list[str] | None, output: Path | None = None) -> int:
    """`rig *args` in a forked child in `cwd`, under `strace -f -p` with `strace_args` (None: untraced); its wait
    status. Its stdout and stderr go to `output`.out and `output`.err (None: to /dev/null)."""
    from rig.cli import main

    ready_r, ready_w = os.pipe()
    gc.freeze()  # this process's objects out of the child's collections: else they touch, and so copy, every page
    pid = os.fork()
    if pid == 0:  # the child: whatever happens in it (a flush failing with the injected ENOSPC), it ends here
        code = 1
        try:
            allow_tracing_by_any()
            os.close(ready_w)
            os.read(ready_r, 1)
            os.chdir(cwd)
            for fd, suffix in ((1, ".out"), (2, ".err")):
                target = os.open(f"{output}{suffix}" if output else os.devnull, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
                os.dup2(target, fd)
            # block-buffered, as on a pipe or a file: the same writes whether this process is on a terminal or not
            sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115
            sys.stderr = open(2, "w", closefd=False)  # noqa: SIM115
            try:
                code = main(args)
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else 1
            sys.stdout.flush()
            sys.stderr.flush()
        except BaseException:  # noqa: BLE001
            code = 70
        finally:
            os._exit(code)
    os.close(ready_r)
    tracer = None
    if strace_args is not None:
        tracer = subprocess.Popen(["strace", "-f", *strace_args, "-p", str(pid)], stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 30
        while "TracerPid:\t0\n" in Path(f"/proc/{pid}/status").read_text():
            if time.monotonic() > deadline or tracer.poll() is not None:
                os.kill(pid, 9)
                raise RuntimeError("strace did not attach to the forked command (is ptrace allowed here?)")
            time.sleep(0.002)
    os.write(ready_w, b"go")
    os.close(ready_w)
    _, status = os.waitpid(pid, 0)
    if tracer is not None:
        tracer.wait(timeout=30)
    return status


def fonts_in_memory() -> None:
    """matplotlib's FreeType reads its font files through Python, a seek and a read for each glyph it draws: 17,000
    system calls in one `rig fit --report`, and under `strace -p` each stops the child twice (3-4x the command's
    CPU). Fonts opened from memory (FT2Font takes a file object) draw the same glyphs with none. This changes what
    matplotlib reads, not what rig writes."""
    import io

    from matplotlib import font_manager, ft2font

    class FromMemory:
        def __getattr__(self, name: str) -> object:
            return getattr(ft2font, name)

        @staticmethod
        def FT2Font(path: object, *args: object, **kwargs: object) -> object:  # noqa: N802 (ft2font's name)
            if isinstance(path, (str, os.PathLike)):
                path = io.BytesIO(Path(path).read_bytes())
            return ft2font.FT2Font(path, *args, **kwargs)

    font_manager.ft2font = FromMemory()


def call_counts(log_lines: list[str], calls: tuple[str, ...]) -> dict[str, int]:
    """How many times each system call in `calls` appears in a `strace -f -o` log (its lines prefixed with a PID)."""
    return {call: sum(re.match(rf"(\d+ +)?{call}\(", line) is not None for line in log_lines) for call in calls}


def warm(args: list[str], cwd: Path, *, copy: bool = False) -> None:
    """The command once in this process, in `cwd` (with `copy`, in a copy of it, which is then removed), its output
    dropped: its first-time work is then done before the forks (else every trial pays it: 1.7 s of CPU against 0.08 s
    for `rig fit`), and each child makes the same calls."""
    import contextlib
    import io
    import shutil

    from rig.cli import main

    if copy:
        with tempfile.TemporaryDirectory(prefix="forked-rig-warm-") as t:
            shutil.copytree(cwd, Path(t, "here"))
            warm(args, Path(t, "here"))
        return
    here = os.getcwd()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        os.chdir(cwd)
        try:
            main(args)
        except SystemExit:
            pass
        finally:
            os.chdir(here)


def serve() -> None:
    """Answer requests on stdin, one JSON line each, until it closes (see the module's docstring)."""
    import matplotlib

    import rig.cli  # noqa: F401 - imported once, here

    matplotlib.use("Agg")
    fonts_in_memory()

    for line in sys.stdin:
        request = json.loads(line)
        if request["op"] == "warm":
            warm(request["args"], Path(request["cwd"]), copy=request.get("copy", False))
            answer: dict = {}
        else:
            with tempfile.TemporaryDirectory(prefix="forked-rig-") as t:
                output = Path(t, "command")
                status = run(request["args"], Path(request["cwd"]), request.get("strace"), output)
                answer = {"returncode": os.waitstatus_to_exitcode(status),
                          "stdout": Path(f"{output}.out").read_text(errors="replace"),
                          "stderr": Path(f"{output}.err").read_text(errors="replace")}
        print(json.dumps(answer), flush=True)


class ForkServer:
    """A `python -m tests.forked_rig` process to run rig commands in, forked (see the module's docstring)."""

    def __init__(self) -> None:
        root = Path(__file__).resolve().parents[1]
        self.process = subprocess.Popen([sys.executable, "-m", "tests.forked_rig"], cwd=root, text=True,
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.warmed: set[str] = set()

    def _ask(self, request: dict) -> dict:
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(json.dumps(request) + "\n")
        self.process.stdin.flush()
        line = self.process.stdout.readline()
        assert line, f"the fork server ended (exit {self.process.wait()})"
        return json.loads(line)

    def warm(self, args: list[str], cwd: Path) -> None:
        """Run the command in the server itself, in a copy of `cwd` (its first-time work, before any fork)."""
        self._ask({"op": "warm", "args": [str(a) for a in args], "cwd": str(cwd), "copy": True})

    def warm_once(self, args: list[str], cwd: Path) -> None:
        """`warm`, the first time a command (`args[0]`) is asked for."""
        if args[0] not in self.warmed:
            self.warm(args, cwd)
            self.warmed.add(args[0])

    def run(self, args: list[str], cwd: Path, strace: list[str] | None = None) -> subprocess.CompletedProcess:
        a = self._ask({"op": "run", "args": [str(x) for x in args], "cwd": str(cwd), "strace": strace})
        return subprocess.CompletedProcess(["rig", *args], a["returncode"], a["stdout"], a["stderr"])

    def close(self) -> None:
        if self.process.stdin:
            self.process.stdin.close()
        self.process.wait(timeout=60)


if __name__ == "__main__":
    for_forking()
    serve()
