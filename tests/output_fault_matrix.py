"""The outputs' fault matrix (issue 52): every write, fsync, rename, unlink, linkat and renameat2 of rig export, rig fit
--table/--plot/--report, rig compare --report and rig export --sigma-map, killed (SIGKILL) or failed with ENOSPC by the
kernel through strace, with an old output in place. For each trial: is every output the old one, a whole new one or
absent (never a part), and what else is left in the folder, and after the next run.

    .venv/bin/python -m tests.output_fault_matrix                  # every command: the table of docs/reliability.md
    .venv/bin/python -m tests.output_fault_matrix "fit --table"    # one
    .venv/bin/python -m tests.output_fault_matrix --json           # the trials and findings, as JSON
    .venv/bin/python -m tests.output_fault_matrix --calls write,fsync,rename,unlink ...   # only these calls

One process imports rig once and forks a child for each trial; strace attaches to the child (`strace -p`) before it
starts the command, so the N-th traced call is the command's own and each trial costs the command, not a new
interpreter's ~1.5 s of imports. The process runs single-threaded (OpenBLAS with one thread), as a forked command
must.
"""

from __future__ import annotations

import gc
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ["OPENBLAS_NUM_THREADS"] = "1"  # before numpy: a fork copies only the calling thread

CALLS = ("write", "fsync", "rename", "unlink", "linkat", "renameat2")
FAULTS = ("signal=KILL", "error=ENOSPC")
#: command (a.h5 and b.h5 are the recordings) and the outputs it writes
COMMANDS = {
    "export": (["export", "a.h5", "-o", "m.json"], ["m.json"]),
    "fit --table": (["fit", "a.h5", "--table", "t.csv"], ["t.csv"]),
    "fit --plot": (["fit", "a.h5", "--plot", "p.png"], ["p.png"]),
    "fit --report": (["fit", "a.h5", "--report", "rep"], ["rep/fit.html", "rep/fit-sigma.png",
                                                          "rep/fit-measured-predicted.png"]),
    "compare --report": (["compare", "a.h5", "b.h5", "--report", "cmp", "--jobs", "1"],  # no pool: its own calls
                         ["cmp/compare.html", "cmp/compare-overlay.png"]),
    "export --sigma-map": (["export", "a.h5", "-o", "m.json", "--sigma-map", "1,2"],
                           ["m.json", "m.sigma-map.npy", "m.sigma-map.tif", "m.sigma-map.png"]),
}


def whole(name: str, content: bytes, reference: bytes) -> bool:
    """A whole new output (its timestamps may differ from `reference`, a clean run's)."""
    if name.endswith(".json"):
        try:
            return json.loads(content)["schema"] == "rig.noise-model/1"
        except (ValueError, KeyError):
            return False
    if name.endswith(".png"):
        return content.startswith(b"\x89PNG") and content.endswith(b"IEND\xaeB`\x82")
    if name.endswith(".html"):
        return content.rstrip().endswith(b"</html>")
    return len(content) == len(reference) if name.endswith((".npy", ".tif")) else content == reference


def folder(tmp: Path, recordings: tuple[Path, Path], outputs: list[str]) -> Path:
    shutil.copy(recordings[0], tmp / "a.h5")
    shutil.copy(recordings[1], tmp / "b.h5")
    for o in outputs:
        (tmp / o).parent.mkdir(exist_ok=True)
        (tmp / o).write_bytes(b"OLD")
    return tmp


def others(d: Path, outputs: list[str]) -> list[str]:
    return sorted(str(p.relative_to(d)) for p in d.rglob("*")
                  if p.is_file() and p.name not in ("a.h5", "b.h5", ".log") and str(p.relative_to(d)) not in outputs)


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


def run(args: list[str], cwd: Path, strace_args: list[str] | None) -> int:
    """`rig *args` in a forked child in `cwd`, under `strace -p` with `strace_args` (None: untraced); its wait status.
    The child waits on a pipe until strace is attached (its TracerPid in /proc), then runs the command and leaves
    with os._exit: nothing of this process (its buffers, its temporary folders) is flushed or removed twice."""
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
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.dup2(null, 2)
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
        tracer = subprocess.Popen(["strace", *strace_args, "-p", str(pid)], stdout=subprocess.DEVNULL,
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


def warm(args: list[str], recordings: tuple[Path, Path], outputs: list[str]) -> None:
    """The command once in this process, so that its first-time work (the imports it makes, numba's kernels loaded from
    their cache) is done before the forks: else every trial pays it (1.7 s of CPU against 0.08 s for `rig fit`), and
    the children's calls are the same in each, as the counting run's."""
    import contextlib
    import io

    from rig.cli import main

    here = os.getcwd()
    with tempfile.TemporaryDirectory() as t, contextlib.redirect_stdout(io.StringIO()), \
            contextlib.redirect_stderr(io.StringIO()):
        os.chdir(folder(Path(t), recordings, outputs))
        try:
            main(args)
        finally:
            os.chdir(here)


def sweep(name: str, recordings: tuple[Path, Path], calls: tuple[str, ...] = CALLS) -> dict:
    """Every traced call of one command, killed and failed; the trials by call and what went wrong in any."""
    args, outputs = COMMANDS[name]
    warm(args, recordings, outputs)
    with tempfile.TemporaryDirectory() as t:
        d = folder(Path(t), recordings, outputs)
        run(args, d, ["-o", str(d / ".log"), "-e", "trace=" + ",".join(calls)])
        log = (d / ".log").read_text().splitlines()
        reference = {o: (d / o).read_bytes() for o in outputs}
        clean_left = others(d, outputs)
    counts = {call: sum(line.startswith(f"{call}(") for line in log) for call in calls}
    findings = [f"a clean run left {clean_left}"] if clean_left else []
    findings += [f"a clean run did not write {o}" for o in outputs if reference[o] == b"OLD"]
    trials = 0
    for call in calls:
        for n in range(1, counts[call] + 1):
            for fault in FAULTS:
                with tempfile.TemporaryDirectory() as t:
                    d = folder(Path(t), recordings, outputs)
                    run(args, d, ["-o", "/dev/null", "-e", f"trace={call}", "-e", f"inject={call}:{fault}:when={n}"])
                    trials += 1
                    for o in outputs:
                        c = (d / o).read_bytes() if (d / o).exists() else None
                        if c not in (b"OLD", None) and not whole(o, c, reference[o]):
                            findings.append(f"{call} #{n} {fault}: {o} is a part ({len(c)} bytes)")
                    left = others(d, outputs)
                    if left:
                        kill_at_rename = fault == "signal=KILL" and call == "rename"
                        run(args, d, None)  # the next run of the command
                        after = others(d, outputs)
                        if after or not kill_at_rename:
                            findings.append(f"{call} #{n} {fault}: left {left}; after the next run: {after}")
    return {"command": name, "calls": counts, "trials": trials, "findings": findings}


def recordings(where: Path) -> tuple[Path, Path]:
    """Two small simulated perpendicular runs (32x18 px, 5 stops of 6 frames, seeds 1 and 2)."""
    from rig.cli import main as rig

    recs = (where / "a.h5", where / "b.h5")
    for seed, path in zip((1, 2), recs):
        rig(["run", "--protocol", "perpendicular", "--camera", f"fake:width=32,height=18,seed={seed}",
             "--stops", "0.5:2.5:0.5", "--frames", "6", "-o", str(path), "-q"])
    return recs


def _cpu() -> float:
    """CPU of this process and of its children (the forked commands, strace) so far, in s."""
    import resource

    return sum(getattr(resource.getrusage(w), f) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
               for f in ("ru_utime", "ru_stime"))


def main(argv: list[str]) -> int:
    as_json = "--json" in argv
    calls = CALLS
    if "--calls" in argv:
        i = argv.index("--calls")
        calls = tuple(argv[i + 1].split(","))
        argv = argv[:i] + argv[i + 2:]
    wanted = [a for a in argv if a != "--json"] or list(COMMANDS)
    import matplotlib

    matplotlib.use("Agg")
    fonts_in_memory()
    with tempfile.TemporaryDirectory() as t:
        recs = recordings(Path(t))
        rows = []
        for name in wanted:
            before = _cpu()
            rows.append(sweep(name, recs, calls) | {"cpu_s": 0.0})
            rows[-1]["cpu_s"] = round(_cpu() - before, 1)
            if not as_json:
                r = rows[-1]
                print(f"| {name} | {r['trials']} | {'; '.join(r['findings']) or 'old or whole, nothing left'} |"
                      f" ({r['cpu_s']} s of CPU)",
                      flush=True)
    if as_json:
        print(json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
